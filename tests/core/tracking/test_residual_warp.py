"""The residual-warp self-calibration (core.tracking.residual_warp): the field's algebra, and a
known smooth warp recovered from warped frames of two bones (128² views)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from core.tracking.residual_warp import ResidualWarp, estimate_residual_warp, monomials

PX = 128


def _field(view: int, uv: np.ndarray) -> np.ndarray:
    """A smooth warp (pixels) not of the estimator's form: an off-centre cubic with a sine term."""
    s = PX / 2
    x, y = (uv[:, 0] - (PX - 1) / 2) / s - 0.1, (uv[:, 1] - (PX - 1) / 2) / s + 0.05
    a, r2 = (1.2, -1.0)[view], x * x + y * y
    return a * np.stack([r2 * x + 0.5 * np.sin(2.0 * y) * x, r2 * y - 0.4 * r2 * x * (1 + 0.3 * y)], 1)


def test_monomials_and_apply_shift():
    assert monomials(1) == [(0, 0), (1, 0), (0, 1)]
    assert len(monomials(3)) == 10
    w = ResidualWarp([(32, 48)], order=1)
    w.add(0, [[1.0, 0, 0], [0, 0, 0]])  # g = (1, 0) everywhere: output x samples x + 1
    img = np.tile(np.arange(48, dtype=np.float32), (32, 1))
    out = w.apply(0, img)
    np.testing.assert_allclose(out[:, :-1], img[:, 1:], atol=1e-5)
    assert w.apply(0, None) is None
    np.testing.assert_allclose(w.displacement(0, [[3.0, 4.0]]), [[1.0, 0.0]])


@pytest.fixture(scope="module")
def warped_trial(talus_calcaneus_128):
    """The shared two-bone 128² scene's frames 0 and 1 re-rendered noise-free and warped by
    :func:`_field` (the frame shows at p the content that belongs at p - g(p))."""
    sc, models, r, _ = talus_calcaneus_128
    v, u = np.mgrid[0:PX, 0:PX].astype(float)
    uv = np.stack([u.ravel(), v.ravel()], 1)
    frames = {}
    for i in range(2):
        out = []
        for view in range(2):
            ideal = (0.6 * np.exp(-r.render_full(sc.poses(i), view))).astype(np.float32)
            g = _field(view, uv)
            mx = (uv[:, 0] - g[:, 0]).reshape(PX, PX).astype(np.float32)
            my = (uv[:, 1] - g[:, 1]).reshape(PX, PX).astype(np.float32)
            out.append(cv2.remap(ideal, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE))
        frames[i] = out
    return sc, models, r, frames


def test_known_warp_recovered_from_true_poses(warped_trial):
    sc, models, r, frames = warped_trial
    poses = {(m.name, f): sc.poses(f)[b] for b, m in enumerate(models) for f in range(2)}
    est = estimate_residual_warp(r, models, frames.__getitem__, poses, order=3, iterations=2,
                                 valid_range=(0.01, 0.9999))
    for view in range(2):
        vv, uu = np.nonzero(r.render_full(sc.poses(1), view) > 0)  # where the bones are
        uv = np.stack([uu, vv], 1).astype(float)
        g, e = _field(view, uv), est.warp.displacement(view, uv)
        rms = float(np.sqrt(np.mean(g**2)))
        err = float(np.sqrt(np.mean((e - g) ** 2)))
        assert rms > 0.09
        assert err < 0.45 * rms, (view, rms, err)
    # the poses stay near the truth: the field is not absorbed into them
    from core.geometry.transforms import params_from_pose

    E = np.array([params_from_pose(est.poses[(m.name, f)], center=m.centroid, base=sc.poses(f)[b])
                  for b, m in enumerate(models) for f in range(2)])
    assert np.sqrt(np.mean(np.sum(E[:, :3] ** 2, 1))) < 0.06


def test_refine_refuses_a_bone_without_a_pose_before_estimating(monkeypatch):
    """A bone with no pose in the run cannot be tracked again: refused, naming it, before the
    estimate's work."""
    from types import SimpleNamespace

    import core.tracking.residual_warp as rw

    monkeypatch.setattr(rw, "estimate_residual_warp", lambda *a, **k: pytest.fail("estimated"))
    ok, lost = SimpleNamespace(pose=np.eye(4), flags=[]), SimpleNamespace(pose=None, flags=["lost"])
    runs = {("talus", 0): ok, ("talus", 1): ok, ("calcaneus", 0): lost}
    result = SimpleNamespace(frames=[0, 1], results=runs)
    bones = [SimpleNamespace(name="talus"), SimpleNamespace(name="calcaneus")]
    with pytest.raises(ValueError, match="'calcaneus' has no pose"):
        rw.refine_residual_warp(None, bones, lambda f: [], result)
