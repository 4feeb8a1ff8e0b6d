"""Joint registration's engines reading their regions from one upload of the whole frame
(core.tracking.engine_upload, run on Warp's CPU device here): the same results to the bit as each engine
uploading its own regions, on the ideal 128² talus-calcaneus views (frame 1 tracked jointly from frame
0's given poses, with the likelihood stage); the pinned sets filled ahead and taken; a frame not held
is uploaded again."""

from __future__ import annotations

import numpy as np

from tests.core.tracking.test_joint_pipeline import _same


def _track(fixture, monkeypatch, on: bool, frames=(0, 1)):
    import core.tracking.engine_upload as eu
    from core.tracking.register import RegistrationOptions
    from core.tracking.trial import TrackingOptions, track

    sc, models, r, imgs = fixture
    monkeypatch.setattr(eu, "SHARED_UPLOAD", on)
    monkeypatch.setattr(eu, "DEVICES", ("cuda", "cpu"))
    keys = {m.name: {0: sc.poses(0)[k]} for k, m in enumerate(models)}
    reg = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")
    o = TrackingOptions(mode="joint", verify_restarts=0, registration=reg, refine_likelihood=True)
    return track(r, models, imgs.__getitem__, list(frames), keyframes=keys, skip=keys, options=o)


def test_shared_upload_gives_the_same_results(talus_calcaneus_128, monkeypatch):
    import core.tracking.engine_frames as ef
    import core.tracking.engine_upload as eu

    shared = []
    real = ef._prepare

    def spy(self, frame, info, src, given, done):
        up = eu.holding(self.device, frame)
        shared.append(up is not None and src is up.src)
        return real(self, frame, info, src, given, done)

    monkeypatch.setattr(ef, "_prepare", spy)
    monkeypatch.setattr(eu, "_UPLOADS", {})
    monkeypatch.setattr(eu, "_ACTIVE", {})
    off = _track(talus_calcaneus_128, monkeypatch, False)
    assert shared and not any(shared)
    shared.clear()
    on = _track(talus_calcaneus_128, monkeypatch, True)
    assert shared and all(shared)  # every full-resolution preparation of the joint frame read the upload
    _same(off, on)


def test_pinned_ahead_by_the_feed(talus_calcaneus_128, monkeypatch):
    """The feed's worker fills a pinned set with the next frame once a frame was shared; share takes it
    (no copy of its own), and a frame no longer held is uploaded again; the device holds the frame's
    whole fluence."""
    import warp as wp

    import core.tracking.engine_upload as eu
    from core.tracking.cost import prepare_frame
    from core.tracking.feed import FrameFeed

    monkeypatch.setattr(eu, "_UPLOADS", {})
    monkeypatch.setattr(eu, "_ACTIVE", {})
    monkeypatch.setattr(eu, "DEVICES", ("cuda", "cpu"))
    imgs = talus_calcaneus_128[3]
    dev = wp.get_device("cpu")
    feed = FrameFeed(imgs.__getitem__, (0.02, 0.999), 3)
    try:
        _, f0 = feed.get(0)
        up = eu.share(dev, f0)
        assert up.filled_here == 1 and eu.holding(dev, f0) is up
        feed.prefetch(1)
        _, f1 = feed.get(1)
        assert any(s.frame is not None and s.frame() is f1 for s in up.sets)  # filled ahead
        assert eu.share(dev, f1) is up and up.filled_here == 1 and up.uploads == 2
        assert eu.holding(dev, f0) is None and eu.holding(dev, f1) is up
        src = up.src.numpy()
        for v, im in enumerate(imgs[1]):
            h, w = im.shape
            np.testing.assert_array_equal(src[v, :h, :w], np.asarray(im, np.float32))
        eu.share(dev, f0)  # back to frame 0: its set still holds it
        assert up.uploads == 3 and up.filled_here == 1 and eu.holding(dev, f0) is up
        # a run whose frames the device does not hold (one bone's, after joint tracking) pins nothing
        other = prepare_frame(imgs[1])
        assert not eu.pin_ahead(other, after=(f1,)) and eu.pin_ahead(other, after=(f1, f0))
    finally:
        feed.close()


def test_sets_not_written_while_busy():
    """The set uploaded last is not written by the worker (the least recently filled of the others is); a
    frame filled ahead is not copied again, one whose set was written over is."""
    import warp as wp

    from core.tracking.cost import prepare_frame
    from core.tracking.engine_upload import FrameUpload

    rng = np.random.default_rng(0)
    frames = [prepare_frame([rng.uniform(0.1, 0.9, (16, 20)).astype(np.float32) for _ in range(2)])
              for _ in range(4)]
    up = FrameUpload(wp.get_device("cpu"), (2, 16, 20))
    up.upload(frames[0])
    assert up.filled_here == 1 and up.holds(frames[0])
    assert up.pin_ahead(frames[1]) and not up.pin_ahead(frames[1])
    assert up.pin_ahead(frames[2])
    busy = [s for s in up.sets if s.busy]
    assert len(busy) == 1 and busy[0].frame() is frames[0]
    assert up.pin_ahead(frames[3])  # over the least recently filled set not busy (frame 1's)
    assert busy[0].frame() is frames[0]
    assert sorted(id(s.frame()) for s in up.sets) == sorted(id(f) for f in (frames[0], frames[2], frames[3]))
    up.upload(frames[2])
    assert up.filled_here == 1  # taken from its set
    np.testing.assert_array_equal(up.src.numpy()[1], frames[2]._fluence[1])
    up.upload(frames[1])  # copied again (its set was written over)
    assert up.filled_here == 2 and up.holds(frames[1])
    np.testing.assert_array_equal(up.src.numpy()[0], frames[1]._fluence[0])


def test_pinned_ahead_in_a_tracking_run(talus_calcaneus_128, monkeypatch):
    """Frames 1-3 tracked jointly (the views of frames 1, 0, 1 again; frame 0 given): the feed's worker
    is asked to pin the frames ahead for the registering thread, and every copy it made is the one share
    takes (share copies only the others). Which frames the worker gets to first depends on the threads'
    timing (on a busy machine it may prepare a frame before the one before it was shared, and then pins
    nothing), so the test counts the worker's copies rather than expecting one."""
    import threading

    import core.tracking.engine_upload as eu
    from core.tracking.register import RegistrationOptions
    from core.tracking.trial import TrackingOptions, track

    monkeypatch.setattr(eu, "_UPLOADS", {})
    monkeypatch.setattr(eu, "_ACTIVE", {})
    monkeypatch.setattr(eu, "DEVICES", ("cuda", "cpu"))
    asked, plain = [], eu.pin_ahead

    def spy(frame, after=(), owner=None):
        ok = plain(frame, after=after, owner=owner)
        asked.append((owner, ok))
        return ok

    monkeypatch.setattr(eu, "pin_ahead", spy)
    sc, models, r, imgs = talus_calcaneus_128
    keys = {m.name: {0: sc.poses(0)[k]} for k, m in enumerate(models)}
    reg = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")
    o = TrackingOptions(mode="joint", verify_restarts=0, registration=reg, refine_likelihood=True,
                        backward_limit=None)
    got = track(r, models, lambda f: imgs[f % 2], [0, 1, 2, 3], keyframes=keys, skip=keys, options=o)
    assert all(x.pose is not None for x in got.results.values())
    (up,) = eu._UPLOADS.values()
    assert asked and {o for o, _ in asked} == {threading.get_ident()}  # (for this thread's registration)
    ahead = sum(ok for _, ok in asked)
    assert up.uploads == 3 and ahead <= 2 and up.filled_here == up.uploads - ahead


def test_each_registering_thread_has_its_own(monkeypatch):
    """Two threads sharing frames at once in one process (two windows tracking, a batch beside a window)
    each have their own device copy: a frame shared by one is not held for the other, and the other's
    upload does not overwrite it."""
    import threading

    import warp as wp

    import core.tracking.engine_upload as eu
    from core.tracking.cost import prepare_frame

    monkeypatch.setattr(eu, "_UPLOADS", {})
    monkeypatch.setattr(eu, "_ACTIVE", {})
    monkeypatch.setattr(eu, "DEVICES", ("cuda", "cpu"))
    dev = wp.get_device("cpu")
    rng = np.random.default_rng(1)
    fa, fb = (prepare_frame([rng.uniform(0.1, 0.9, (12, 10)).astype(np.float32) for _ in range(2)])
              for _ in range(2))
    ua = eu.share(dev, fa)
    seen = {}

    def other() -> None:
        seen["held_a"] = eu.holding(dev, fa)
        seen["up"] = eu.share(dev, fb)
        seen["held_b"] = eu.holding(dev, fb)

    t = threading.Thread(target=other)
    t.start()
    t.join()
    assert seen["held_a"] is None and seen["up"] is not ua and seen["held_b"] is seen["up"]
    assert eu.holding(dev, fa) is ua and eu.holding(dev, fb) is None
    np.testing.assert_array_equal(ua.src.numpy()[0], fa._fluence[0])
    assert len(eu._UPLOADS) == 2
    t = threading.Thread(target=lambda: eu.share(dev, fb))  # a new thread: the finished one's let go (or
    t.start()  # taken over, where the new thread has its ident)
    t.join()
    assert len(eu._UPLOADS) == 2 and eu.holding(dev, fa) is ua
