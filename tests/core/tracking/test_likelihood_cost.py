"""LikelihoodCost (weighted least squares on the line-integral image): against the numpy
reference, and recovering a known pose by its Gauss–Newton refinement."""

from __future__ import annotations

import numpy as np
import pytest

from core.geometry.transforms import params_from_pose, pose_from_params
from core.similarity.likelihood import expected_counts, highpass, wls_chi2
from core.tracking.cost import prepare_frame, search_roi
from core.tracking.likelihood_cost import LikelihoodCost


def _setup(talus_scene, frame: int, offset, **kw):
    sc, model, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    truth = sc.poses(frame)[0]
    off = np.r_[offset[:3], np.radians(offset[3:])]
    start = pose_from_params(off, center=model.centroid, base=truth)
    fr = prepare_frame(talus_scene["fluence"](frame), valid_range=None)  # ideal frames: air reads exactly 1
    roi = search_roi(r, start, 0, views=[0, 1], center=model.centroid, reach_mm=2.0)
    cost = LikelihoodCost(r, fr, bone=0, base_pose=start, center=model.centroid, roi=roi, **kw)
    return cost, truth, model


def test_cost_equals_the_numpy_reference(talus_scene):
    cost, _, _ = _setup(talus_scene, 2, [0.3, 0, 0, 0, 0.4, 0], background=0, highpass_px=2.0)
    X = np.array([[0.0] * 6, [0.1, -0.2, 0.0, 0.3, 0.0, -0.1]])
    D = cost._render(X)
    ref = 0.5 * wls_chi2(D, cost.fluoro_rois, cost.weights, background=0, highpass_px=2.0)
    np.testing.assert_allclose(cost(X), ref, rtol=1e-10)
    # the fluoroscope regions are the frame's line integrals, high-passed, and weigh by their fluence
    li = -np.log(np.clip(talus_scene["fluence"](2)[0], 1 / 4096, 1))
    u0, v0, w, h = cost.roi[0]
    np.testing.assert_allclose(cost.fluoro_rois[0], highpass(li[v0:v0 + h, u0:u0 + w], 2.0), atol=1e-5)
    np.testing.assert_allclose(cost.weights[0], expected_counts(li[v0:v0 + h, u0:u0 + w]), rtol=1e-5)


@pytest.mark.parametrize("kw", [{"background": 1}, {"background": 0, "highpass_px": 3.0}])
def test_refine_recovers_a_known_pose(talus_scene, kw):
    cost, truth, model = _setup(talus_scene, 3, [0.4, -0.3, 0.2, 0.5, -0.4, 0.3], **kw)
    out = cost.refine(iters=6)
    e = params_from_pose(cost.poses(out["x"][None])[0], center=model.centroid, base=truth)
    assert np.linalg.norm(e[:3]) < 0.01 and np.degrees(np.linalg.norm(e[3:])) < 0.02, e
    assert out["cost"] < float(cost(np.zeros((1, 6)))[0])
    assert out["covariance"].shape == (6, 6) and np.all(np.isfinite(out["covariance"]))


def test_bad_options(talus_scene):
    with pytest.raises(ValueError, match="psf"):
        _setup(talus_scene, 1, [0] * 6, psf=np.ones((4, 4)))
    with pytest.raises(ValueError, match="background"):
        _setup(talus_scene, 1, [0] * 6, background=3)


def test_background_bases():
    from core.tracking.likelihood_cost import background_basis

    for k in (0, 2, 5):
        assert background_basis((9, 12), k, "legendre").shape == ((k + 1) * (k + 2) // 2, 9, 12)
    B = background_basis((20, 30), 4, "bspline")
    assert B.shape == (49, 20, 30) and np.allclose(B.sum(axis=0), 1.0)  # a partition of unity
    # the Legendre basis of order 2 spans the monomials of order 2
    L2 = background_basis((15, 17), 2, "legendre").reshape(6, -1).T
    M2 = background_basis((15, 17), 2, "monomial").reshape(6, -1).T
    assert np.allclose(L2 @ np.linalg.lstsq(L2, M2, rcond=None)[0], M2)
    with pytest.raises(ValueError, match="basis"):
        background_basis((5, 5), 1, "fourier")


def test_general_background_refines_as_the_monomial_one(talus_scene):
    mono, truth, model = _setup(talus_scene, 3, [0.3, -0.2, 0.1, 0.4, -0.3, 0.2], background=2)
    leg, _, _ = _setup(talus_scene, 3, [0.3, -0.2, 0.1, 0.4, -0.3, 0.2], background=2, basis="legendre")
    a, b = mono.refine(iters=3), leg.refine(iters=3)
    np.testing.assert_allclose(a["x"], b["x"], atol=1e-6)
    assert a["cost"] == pytest.approx(b["cost"], rel=1e-6)
    X = np.array([[0.0] * 6, [0.1, 0.0, -0.1, 0.2, 0.0, 0.1]])
    np.testing.assert_allclose(mono(X), leg(X), rtol=1e-6)
    # a B-spline background and the robust second refinement still find the pose of a clean frame
    bs, _, _ = _setup(talus_scene, 3, [0.3, -0.2, 0.1, 0.4, -0.3, 0.2], background=3, basis="bspline")
    out = bs.refine(iters=6, robust=2.5)
    e = params_from_pose(bs.poses(out["x"][None])[0], center=model.centroid, base=truth)
    assert np.linalg.norm(e[:3]) < 0.01 and np.degrees(np.linalg.norm(e[3:])) < 0.02, e
    assert out["first"].shape == (6,) and bs.residual(out["x"]).shape[0] == 2
    with pytest.raises(ValueError, match="background"):
        _setup(talus_scene, 1, [0] * 6, background=0, basis="bspline")


def test_extra_regressor_takes_a_known_structure_out(talus_scene):
    sc, model, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    truth = sc.poses(3)[0]
    start = pose_from_params(np.r_[0.3, -0.2, 0.1, np.radians([0.4, -0.3, 0.2])], center=model.centroid,
                             base=truth)
    yy, xx = np.mgrid[0:128, 0:128]
    T = 0.8 * (np.hypot(xx - 60, yy - 70) < 25)  # a sharp "skin" disc over the bone, known in shape
    fr = prepare_frame([f * np.exp(-T) for f in talus_scene["fluence"](3)], valid_range=None)
    roi = search_roi(r, start, 0, views=[0, 1], center=model.centroid, reach_mm=2.0)
    regs = [T[v0:v0 + h, u0:u0 + w] for u0, v0, w, h in np.asarray(roi).reshape(2, 4)]
    errs = []
    for kw in ({"background": 1}, {"background": 1, "regressors": regs}):
        cost = LikelihoodCost(r, fr, bone=0, base_pose=start, center=model.centroid, roi=roi, **kw)
        out = cost.refine(iters=6)
        e = params_from_pose(cost.poses(out["x"][None])[0], center=model.centroid, base=truth)
        errs.append(np.linalg.norm(e[:3]))
    assert errs[1] < 0.01 < errs[0], errs
