"""A residual warp's frame source (core.tracking.residual_warp.ResidualWarp.frames, what
refine_residual_warp tracks again) keeps the source's reason(frame, view) and passes a view without
its image (None or a core.tracking.feed.MissingView) through, as core.tracking.trial.track takes it."""

import numpy as np

from core.tracking.feed import FrameFeed, MissingView
from core.tracking.residual_warp import ResidualWarp


class _Source:
    def __call__(self, f):
        img = np.full((8, 8), 0.5, np.float32)
        img[2:5, 3:6] = 0.2
        return [img, None] if f == 1 else [img, MissingView("cam2/frame_0002.tif: truncated")] if f == 2 \
            else [img, img.copy()]

    def reason(self, f, v):
        return "cam2/frame_0001.tif: checksum mismatch" if (f, v) == (1, 1) else None


def test_the_warped_source_keeps_the_reason_and_the_missing_views():
    w = ResidualWarp([(8, 8), (8, 8)], order=1)
    w.add(0, [[0.5, 0.0, 0.0], [0.0, 0.0, 0.0]])  # half a pixel along u in view 1
    w.add(1, [[0.5, 0.0, 0.0], [0.0, 0.0, 0.0]])
    src = _Source()
    warped = w.frames(src)
    assert warped.reason(1, 1) == "cam2/frame_0001.tif: checksum mismatch" and warped.reason(0, 1) is None
    a, _ = warped(0)
    assert a.shape == (8, 8) and not np.array_equal(a, src(0)[0])  # the field undone
    assert warped(1)[1] is None
    assert warped(2)[1] == MissingView("cam2/frame_0002.tif: truncated")
    feed = FrameFeed(warped, (0.02, 0.999), 1)  # the tracker's feed reads the reason through the warp
    try:
        imgs, frame = feed.get(1)
        assert imgs[1] == MissingView("cam2/frame_0001.tif: checksum mismatch") and frame is None
    finally:
        feed.close()
    assert not hasattr(w.frames(lambda f: [None, None]), "reason")  # a plain callable: none made up
