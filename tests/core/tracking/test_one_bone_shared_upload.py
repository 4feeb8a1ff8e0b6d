"""One bone's registration reading its regions, and its final stage's, from one upload of the whole frame
(core.tracking.register.SHARE_FRAME), the next frame put on the device during the stage's first step
(core.tracking.trial.NEXT_FRAME_AHEAD); run on Warp's CPU device here (engine_upload.DEVICES patched):
the same poses, scores, flags, confidences and stage outcomes to the bit as each uploading its own rows,
on the ideal 128² walking talus with the likelihood stage."""

from __future__ import annotations

import numpy as np

from tests.core.tracking.test_joint_pipeline import _same


def _track(walk, monkeypatch, on: bool, frames):
    import core.tracking.engine_upload as eu
    import core.tracking.register as reg
    import core.tracking.trial as trial
    from core.tracking.register import RegistrationOptions
    from core.tracking.trial import TrackingOptions, track

    monkeypatch.setattr(eu, "DEVICES", ("cuda", "cpu"))
    monkeypatch.setattr(eu, "_UPLOADS", {})
    monkeypatch.setattr(eu, "_ACTIVE", {})
    monkeypatch.setattr(reg, "SHARE_FRAME", on)
    monkeypatch.setattr(trial, "NEXT_FRAME_AHEAD", on)
    sc, model = walk["scene"], walk["model"]
    keys = {model.name: {frames[0]: sc.poses(frames[0])[0]}}
    ro = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")
    o = TrackingOptions(verify_restarts=0, refine_likelihood=True, registration=ro)
    return track(walk["renderer"], [model], walk["frames"], list(frames), keyframes=keys, options=o)


def test_one_bone_shared_upload_gives_the_same_results(walking_talus, monkeypatch):
    import core.tracking.engine_frames as ef
    import core.tracking.engine_upload as eu
    import core.tracking.feed as feed
    import core.tracking.likelihood_frames as lf

    searched, staged, ahead = [], [], []
    real_prep, real_held, real_ahead = ef._prepare, lf._FrameRegions._held, feed.FrameFeed.upload_ahead

    def prep(self, frame, info, src, given, done):
        up = eu.holding(self.device, frame)
        searched.append(up is not None and src is up.src)
        return real_prep(self, frame, info, src, given, done)

    def held(self, frame):
        up = real_held(self, frame)
        staged.append(up is not None)
        return up

    def upload_ahead(self, device):
        nxt = self.ahead[0] if self.ahead is not None else None  # (the frame it would put up)
        ok = real_ahead(self, device)
        ahead.append((nxt, ok))
        return ok

    monkeypatch.setattr(ef, "_prepare", prep)
    monkeypatch.setattr(lf._FrameRegions, "_held", held)
    monkeypatch.setattr(feed.FrameFeed, "upload_ahead", upload_ahead)
    frames = range(0, 11)
    off = _track(walking_talus, monkeypatch, False, frames)
    assert searched and not any(searched) and not any(staged) and not ahead
    searched.clear()
    staged.clear()
    on = _track(walking_talus, monkeypatch, True, frames)
    assert searched and all(searched)  # every full-resolution search read the whole frame
    # and every frame's stage (a later stage of a frame whose next frame went up during its first, the
    # move's confirmation, reads its own rows unless a registration of the frame put it up again)
    assert staged.count(True) >= len(frames)
    assert len(ahead) == len(frames) - 1  # asked once a frame, but the last
    assert any(ok for _, ok in ahead)  # (False where the worker was not done yet)
    _same(off, on)
    assert all(np.all(np.isfinite(fr.pose)) for fr in on.results.values())
