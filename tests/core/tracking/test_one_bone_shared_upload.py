"""One bone tracked with the likelihood stage on the ideal 128² walking talus (8 frames, Warp's CPU device),
against the serial loop with every switch off (one run, shared by the tests):

* the whole frame uploaded once and read by the search and the stage (core.tracking.register.SHARE_FRAME),
  the next frame put up during the stage's first step (core.tracking.trial.NEXT_FRAME_AHEAD;
  engine_upload.DEVICES patched to take the CPU): the same poses, scores, flags, confidences and stage
  outcomes to the bit."""

from __future__ import annotations

import numpy as np
import pytest

from tests.core.tracking.test_joint_pipeline import _same

FRAMES = range(0, 8)


def _track(walk):
    from core.tracking.register import RegistrationOptions
    from core.tracking.trial import TrackingOptions, track

    sc, model = walk["scene"], walk["model"]
    keys = {model.name: {FRAMES[0]: sc.poses(FRAMES[0])[0]}}
    ro = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")
    o = TrackingOptions(verify_restarts=0, refine_likelihood=True, registration=ro, trajectory_limit=None)
    return track(walk["renderer"], [model], walk["frames"], list(FRAMES), keyframes=keys, options=o)


@pytest.fixture(scope="module")
def serial(walking_talus):
    import core.tracking.register as reg
    import core.tracking.trial as trial

    assert reg.SHARE_FRAME and trial.NEXT_FRAME_AHEAD  # (the defaults)
    was = reg.SHARE_FRAME, trial.NEXT_FRAME_AHEAD
    reg.SHARE_FRAME = trial.NEXT_FRAME_AHEAD = False  # the serial loop, each registration its own rows
    try:
        return _track(walking_talus)
    finally:
        reg.SHARE_FRAME, trial.NEXT_FRAME_AHEAD = was


def test_one_bone_shared_upload_gives_the_same_results(walking_talus, serial, monkeypatch):
    import core.tracking.engine_frames as ef
    import core.tracking.engine_upload as eu
    import core.tracking.feed as feed
    import core.tracking.likelihood_frames as lf
    import core.tracking.register as reg
    import core.tracking.trial as trial

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
        ok = real_ahead(self, device)
        ahead.append(ok)
        return ok

    monkeypatch.setattr(ef, "_prepare", prep)
    monkeypatch.setattr(lf._FrameRegions, "_held", held)
    monkeypatch.setattr(feed.FrameFeed, "upload_ahead", upload_ahead)
    monkeypatch.setattr(eu, "DEVICES", ("cuda", "cpu"))
    monkeypatch.setattr(eu, "_UPLOADS", {})
    monkeypatch.setattr(eu, "_ACTIVE", {})
    monkeypatch.setattr(reg, "SHARE_FRAME", True)
    monkeypatch.setattr(trial, "NEXT_FRAME_AHEAD", True)
    on = _track(walking_talus)
    assert searched and all(searched)  # every full-resolution search read the whole frame
    # and every frame's stage (a later stage of a frame whose next frame went up during its first, a move's
    # confirmation, reads its own rows unless a registration of the frame put it up again)
    assert staged.count(True) >= len(FRAMES)
    # once a frame (False: worker not done), the last's the backward check's frame (trial.BACKWARD_AHEAD)
    assert len(ahead) == len(FRAMES) and any(ahead)
    _same(serial, on)
    assert all(np.all(np.isfinite(fr.pose)) for fr in on.results.values())

