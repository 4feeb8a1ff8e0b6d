"""The first frame's global search with its pinned copy made aside, its next pyramid level made ahead and
the restart check's first level made during its final stage (core.tracking.engine_upload.FILL_ASIDE,
core.tracking.engine_frames.PYRAMID_AHEAD, core.tracking.first_restarts.RESTART_REGIONS_AHEAD), against
all three off: the ideal 64² walking talus, frames 0-1 on Warp's CPU device, the shared upload taking the
CPU (engine_upload.DEVICES patched) and the automatic levels keeping the pyramid scales 4 and 2 at these
pixels (default_levels' and the restarts' coarsest pixel widened), so that the CMA-ES stage runs at scale
4, a Gauss-Newton level and the restarts' first level at scale 2: the same poses, scores, flags, notes,
confidences and stage outcomes to the bit; the first frame's copy made aside (not in the registering
thread) and regions taken from the ahead preparations."""

from __future__ import annotations

import functools
import threading

import numpy as np
import pytest

from tests.core.tracking.test_joint_pipeline import _same

FRAMES = range(0, 2)


def _track(walk, monkeypatch, on: bool):
    import core.tracking.engine_frames as ef
    import core.tracking.engine_upload as eu
    import core.tracking.first_restarts as first_restarts
    import core.tracking.register as reg
    from core.tracking.register import RegistrationOptions
    from core.tracking.register_options import default_levels
    from core.tracking.trial import TrackingOptions, track

    monkeypatch.setattr(eu, "DEVICES", ("cuda", "cpu"))
    monkeypatch.setattr(eu, "_UPLOADS", {})
    monkeypatch.setattr(eu, "_ACTIVE", {})
    monkeypatch.setattr(eu, "FILL_ASIDE", on)
    monkeypatch.setattr(ef, "PYRAMID_AHEAD", on)
    monkeypatch.setattr(first_restarts, "RESTART_REGIONS_AHEAD", on)
    monkeypatch.setattr(reg, "default_levels", functools.partial(default_levels, coarsest_mm=24.0))
    monkeypatch.setattr(reg, "_newton_fallback", functools.partial(reg._newton_fallback, coarsest_mm=24.0))
    sc, model = walk["scene"], walk["model"]
    keys = {model.name: {FRAMES[0]: sc.poses(FRAMES[0])[0]}}
    ro = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")
    o = TrackingOptions(refine_likelihood=True, registration=ro, trajectory_limit=None)
    return track(walk["renderer"], [model], walk["frames"], list(FRAMES), keyframes=keys, options=o)


@pytest.fixture(scope="module")
def plain(walking_talus_64):
    with pytest.MonkeyPatch.context() as mp:
        return _track(walking_talus_64, mp, False)


def test_first_frame_aside_gives_the_same_results(walking_talus_64, plain, monkeypatch):
    import core.tracking.engine as eng
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
    hits = []
    real_rois = eng.pyramid_rois

    def rois(frame, views, roi, scale):
        got = ef._AHEAD.get(threading.get_ident())
        hits.append(got is not None and got[0][0]() is frame and got[0][1:] == (
            tuple(int(v) for v in views), np.asarray(roi, dtype=np.int64).tobytes(), float(scale)))
        return real_rois(frame, views, roi, scale)

    monkeypatch.setattr(eng, "pyramid_rois", rois)
    on = _track(walking_talus_64, monkeypatch, True)
    assert asides and asides[0]  # the first frame's global search pinned its frame aside
    assert firsts == [0]  # and the first upload found that copy made
    # the search's scale-2 level took the regions prepared during the CMA-ES stage, and the restart check's
    # those prepared during the stage (where the stage moved no region's edge across a pixel)
    assert sum(hits) >= 1
    print('pyramid levels taken from the ahead preparations:', hits)
    _same(plain, on)
    assert all(np.all(np.isfinite(fr.pose)) for fr in on.results.values())


def test_a_first_frame_that_raises_leaves_no_frame_coming(walking_talus_64, monkeypatch):
    """The global search's CMA-ES level raising after the copy aside started: the copy waited for and the
    frame no longer counted as coming (no pinned set kept for it), the error raised as before."""
    import core.tracking.engine_upload as eu
    import core.tracking.register as reg

    drops, real_run, real_drop = [], reg._run, eu.Aside.drop

    def run(method, *a, **k):
        if method == "cmaes":
            raise RuntimeError("a level's error")
        return real_run(method, *a, **k)

    def drop(self):
        real_drop(self)
        drops.append(self.future is not None and self.future.done())

    monkeypatch.setattr(reg, "_run", run)
    monkeypatch.setattr(eu.Aside, "drop", drop)
    with pytest.raises(RuntimeError, match="a level's error"):
        _track(walking_talus_64, monkeypatch, True)
    assert drops == [True]  # (started before the level ran, finished when dropped)
    ups = list(eu._UPLOADS.values())
    assert ups and all(up.coming is None for up in ups)
    assert not any(s.filling for up in ups for s in up.sets)
