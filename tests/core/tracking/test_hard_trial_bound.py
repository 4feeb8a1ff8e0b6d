"""The harder trial's Cramér–Rao bound comes from the volumes the frames were rendered from, not from
the tracker's CT: with the CT's (blurred) derivatives the bound is too large, and a maximum-likelihood
fit on the trial's quanta beats it."""

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from core.render import DRRRenderer
from core.studies.tracking.hard_bound_check import oracle_ml
from core.studies.tracking.hard_trial import HardRun, truth_bounds
from core.tracking.bound import pose_bound


def _trial(talus_scene, N=20000.0):
    """A stand-in for :class:`HardRun` on the talus scene: the frames rendered from the scene's
    volume (a ramp of tissue behind it), the tracker's model a CT blurred by one voxel."""
    sc, model, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    vol = sc.bones[0]
    ct = vol.__class__(gaussian_filter(np.asarray(vol.data, np.float32), 1.0), spacing=vol.spacing,
                       origin=vol.origin, units=vol.units, name=vol.name)
    tracker = DRRRenderer(sc.rig, [ct.to_attenuation(sc.bone_transfer)], device="cpu")
    scene = SimpleNamespace(rig=sc.rig, bones=sc.bones, bone_transfer=sc.bone_transfer,
                            imaging=[SimpleNamespace(photons_per_pixel=N)] * len(sc.rig))

    def line_integrals(f):
        own = r.render(sc.poses(f)[None, :1], roi="full").numpy()[0][:, 0].astype(np.float64)
        w = own.shape[-1]
        return own + (1.0 + np.arange(w) / (w - 1))[None, None, :]

    return SimpleNamespace(scene=scene, names=("talus",), models=[model], truth=lambda f: sc.poses(f)[:1],
                           line_integrals=line_integrals, renderer=tracker, device="cpu")


def test_the_bound_uses_the_frames_volumes_and_an_ml_fit_does_not_beat_it(talus_scene):
    hr = _trial(talus_scene)
    f, c = 2, hr.models[0].centroid
    truth = hr.truth(f)[0]
    L = hr.line_integrals(f)
    N = hr.scene.imaging[0].photons_per_pixel
    got = HardRun.bounds(hr, [f])["talus"][0]
    ref = pose_bound(talus_scene["renderer"], 0, truth, c, line_integral=L, quanta_per_pixel=N)
    assert got == pytest.approx([ref.rms_mm, ref.rms_deg], rel=1e-6)
    assert np.array_equal(truth_bounds(hr.scene, hr.names, [c], hr.truth, hr.line_integrals, [f],
                                       device="cpu")["talus"], HardRun.bounds(hr, [f])["talus"])
    tracker = HardRun.bounds(hr, [f], derivatives="tracker")["talus"][0]
    assert np.all(tracker > 1.1 * got)  # the blurred CT's DRR changes less with the pose
    with pytest.raises(ValueError, match="derivatives"):
        HardRun.bounds(hr, [f], derivatives="ct")

    # Poisson frames of the scene: the ML fit's spread is the truth's bound, below the tracker's
    g = np.random.default_rng(3)
    frames = np.array([[g.poisson(N * np.exp(-Lv)) / N for Lv in L] for _ in range(24)])
    E = oracle_ml(talus_scene["renderer"], 0, truth, c, frames, L, [N, N], iterations=2)
    spread = np.array([np.sqrt(np.mean(np.sum((E[:, s] - E[:, s].mean(0)) ** 2, axis=1)))
                       for s in (slice(0, 3), slice(3, 6))])
    assert np.all(spread / got > 0.7) and np.all(spread / got < 1.35)
    assert np.all(spread / tracker < 0.85)  # an efficient fit would beat the CT's bound
