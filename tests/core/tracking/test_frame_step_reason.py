"""A frame source's reason for a view without its image reaches the frame's flag
(core.tracking.frame_step.missing_flags, core.tracking.feed.MissingView): any source handed to
core.tracking.trial.track, not only the study's frame reader, whose reasons were written into the
flags afterwards by matching the flag's text."""

from __future__ import annotations

import numpy as np


def test_flags_name_the_views_and_the_reasons():
    from core.tracking.feed import MissingView as M
    from core.tracking.frame_step import missing_flags

    im = np.zeros((4, 4), np.float32)
    assert missing_flags([im, im]) == ()
    assert missing_flags([im, None]) == ("frame missing in view 2",)
    assert missing_flags([None, None]) == ("frame missing in view 1, 2",)
    assert missing_flags([M("a.tif: no page"), im]) == ("frame cannot be read: view 1: a.tif: no page",)
    assert missing_flags([M("a.tif: no page"), M("b.tif: truncated")]) == (
        "frame cannot be read: view 1: a.tif: no page; view 2: b.tif: truncated",)
    # one reason for the whole frame is said once; one view of a one-view rig still names it
    assert missing_flags([M("frame 3 is past the end")] * 2) == (
        "frame cannot be read: frame 3 is past the end",)
    assert missing_flags([M("a.tif: no page")]) == ("frame cannot be read: view 1: a.tif: no page",)
    # a view with a reason and a view without one: both said
    assert missing_flags([None, M("b.tif: truncated"), im]) == (
        "frame cannot be read: view 2: b.tif: truncated", "frame missing in view 1")
    assert missing_flags([M(""), im]) == ("frame missing in view 1",)  # an empty reason is none


class _Frames:
    """A plain frame source: frame 1's view 1 cannot be read (a reason), frame 2 has no view 0."""

    def __init__(self, frames):
        self.frames, self.asked = frames, []

    def __call__(self, f):
        imgs = list(self.frames(f))
        if f == 1:
            imgs[1] = None
        if f == 2:
            imgs[0] = None
        return imgs

    def reason(self, f, v):
        self.asked.append((f, v))
        return "cam2/frame_0001.tif: checksum mismatch" if (f, v) == (1, 1) else None


def test_the_feed_keeps_each_frames_reasons_through_the_look_ahead():
    from core.tracking.feed import FrameFeed, MissingView

    src = _Frames(lambda f: [np.full((8, 8), 0.5, np.float32) for _ in range(2)])  # new images each frame
    feed = FrameFeed(src, (0.02, 0.999), 3)
    try:
        feed.get(0)
        feed.prefetch(1)  # frame 1 read (and its reason asked) while frame 0 registers
        assert feed.ahead is not None
        imgs, fr = feed.get(1)
        assert imgs[1] == MissingView("cam2/frame_0001.tif: checksum mismatch") and fr is None
        imgs, fr = feed.get(2)  # no look-ahead: read at its turn; no reason: None
        assert imgs[0] is None and fr is None
        assert src.asked == [(1, 1), (2, 0)]  # asked only for the views without an image
    finally:
        feed.close()


def test_a_plain_sources_reason_reaches_the_result(walking_talus_64):
    """track() on a source of its own (ideal 64² views, Warp CPU): frame 1's flag gives the
    source's reason and the view (counted from 1), frame 2's says which view has no frame; frame 0
    is given, so nothing is registered."""
    from core.tracking.trial import track

    w = walking_talus_64
    pose = w["scene"].poses(0)[0]
    seen = []
    res = track(w["renderer"], [w["model"]], _Frames(w["frames"]), range(3), keyframes={"talus": {0: pose}},
                skip={"talus": {0: pose}}, progress=lambda d, n, fr: seen.append((fr.frame, fr.flags)))
    r1, r2 = res.results[("talus", 1)], res.results[("talus", 2)]
    assert r1.pose is None
    assert r1.flags == ("frame cannot be read: view 2: cam2/frame_0001.tif: checksum mismatch",)
    assert r2.pose is None and r2.flags == ("frame missing in view 1",)
    assert seen == [(1, r1.flags), (2, r2.flags)]  # the progress events (the report's frames) say the same
    assert {r.frame for r in res.flagged} == {1, 2}
