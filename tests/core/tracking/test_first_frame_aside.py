"""The first frame's global search with its pinned copy made aside and its next pyramid level made ahead
(core.tracking.engine_upload.FILL_ASIDE, core.tracking.engine_frames.PYRAMID_AHEAD), against both off:
the ideal 128² walking talus, frames 0-2 on Warp's CPU device, the shared upload taking the CPU
(engine_upload.DEVICES patched) and the automatic levels keeping the pyramid scales 4 and 2 at these
pixels (default_levels' coarsest pixel widened), so that the CMA-ES stage runs at scale 4 and a
Gauss-Newton level at scale 2: the same poses, scores, flags, notes, confidences and stage outcomes to the
bit; the first frame's copy made aside (not in the registering thread) and the scale-2 regions taken
from the ahead preparation."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from tests.core.tracking.test_joint_pipeline import _same

FRAMES = range(0, 3)


class _Taken(dict):
    """``engine_frames._AHEAD`` counting the preparations taken from it."""

    taken = 0

    def pop(self, *a):
        got = super().pop(*a)
        if got is not None:
            type(self).taken += 1
        return got


def _track(walk, monkeypatch, on: bool):
    import core.tracking.engine_frames as ef
    import core.tracking.engine_upload as eu
    import core.tracking.register as reg
    from core.tracking.register import RegistrationOptions
    from core.tracking.register_options import default_levels
    from core.tracking.trial import TrackingOptions, track

    monkeypatch.setattr(eu, "DEVICES", ("cuda", "cpu"))
    monkeypatch.setattr(eu, "_UPLOADS", {})
    monkeypatch.setattr(eu, "_ACTIVE", {})
    monkeypatch.setattr(eu, "FILL_ASIDE", on)
    monkeypatch.setattr(ef, "PYRAMID_AHEAD", on)
    monkeypatch.setattr(reg, "default_levels", functools.partial(default_levels, coarsest_mm=12.0))
    sc, model = walk["scene"], walk["model"]
    keys = {model.name: {FRAMES[0]: sc.poses(FRAMES[0])[0]}}
    ro = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")
    o = TrackingOptions(refine_likelihood=True, registration=ro, trajectory_limit=None)
    return track(walk["renderer"], [model], walk["frames"], list(FRAMES), keyframes=keys, options=o)


@pytest.fixture(scope="module")
def plain(walking_talus):
    with pytest.MonkeyPatch.context() as mp:
        return _track(walking_talus, mp, False)


def test_first_frame_aside_gives_the_same_results(walking_talus, plain, monkeypatch):
    import core.tracking.engine_frames as ef
    import core.tracking.engine_upload as eu

    firsts, asides = [], []
    real_upload, real_aside = eu.FrameUpload.upload, eu.fill_aside

    def upload(self, frame, ahead=False):
        n = self.filled_here
        real_upload(self, frame, ahead)
        if self.uploads == 1:
            firsts.append(self.filled_here - n)

    def aside(device, frame):
        fut = real_aside(device, frame)
        asides.append(fut is not None)
        return fut

    monkeypatch.setattr(eu.FrameUpload, "upload", upload)
    monkeypatch.setattr(eu, "fill_aside", aside)
    monkeypatch.setattr(ef, "_AHEAD", _Taken())
    _Taken.taken = 0
    on = _track(walking_talus, monkeypatch, True)
    assert asides and asides[0]  # the first frame's global search pinned its frame aside
    assert firsts == [0]  # and the first upload found that copy made
    assert _Taken.taken >= 1  # the scale-2 level took the regions prepared during the CMA-ES stage
    _same(plain, on)
    assert all(np.all(np.isfinite(fr.pose)) for fr in on.results.values())
