"""The Gauss–Newton engine (core.tracking.engine) on ideal 128² views of the talus (CPU device)."""

from __future__ import annotations

import numpy as np
import pytest

from core.geometry.transforms import pose_from_params
from core.studies.tracking.acceptance import pose_errors
from core.tracking.cost import DEFAULT_TERMS, MetricTerm, RegistrationCost, prepare_frame, search_roi
from core.tracking.engine import (
    GaussNewtonCost,
    engine_cost,
    gauss_newton_search,
    moments_to_newton,
    step_design,
    supports,
)
from core.tracking.register import RegistrationOptions, default_levels, register

H = np.array([0.25] * 3 + [0.5] * 3)
BOX = np.array([5.0] * 6)


def _start(scene, frame, c, offset):
    truth = scene.poses(frame)[0]
    off = np.asarray(offset, dtype=float)
    return truth, pose_from_params(np.r_[off[:3], np.radians(off[3:])], center=c, base=truth)


def _engine(sc, frame, start):
    r, m = sc["renderer"], sc["model"]
    roi = search_roi(r, start, 0, views=(0, 1), center=m.centroid, reach_mm=7.6, points=m.outline)
    gn = GaussNewtonCost(r, bone=0, views=(0, 1), scale=1.0, term=DEFAULT_TERMS[0])
    gn.set_frame(frame, base_pose=start, center=m.centroid, roi=roi)
    return gn, roi


def test_engine_scores_as_the_cost_and_its_gradient_is_the_costs(talus_scene):
    sc = talus_scene
    m = sc["model"]
    frame = prepare_frame(sc["fluence"](2))
    _, start = _start(sc["scene"], 2, m.centroid, [1.0, -0.8, 0.6, 1.0, -1.0, 1.5])
    gn, roi = _engine(sc, frame, start)
    rc = RegistrationCost(sc["renderer"], frame, bone=0, base_pose=start, center=m.centroid, roi=roi)
    X = step_design(np.zeros(6), H)
    np.testing.assert_allclose(gn(X), rc(X), atol=1e-6)
    s = gn.step(np.zeros(6), H)
    np.testing.assert_allclose(s.costs, rc(X), atol=1e-6)
    # the Gauss-Newton gradient is the cost's: central differences of the 13 costs agree
    cd = (s.costs[1::2] - s.costs[2::2]) / (2 * H)
    np.testing.assert_allclose(s.g, cd, rtol=0.05, atol=2e-3 * np.abs(cd).max())
    assert np.all(np.linalg.eigvalsh(s.H) > 0)  # JᵀJ: positive definite
    # the per-view correlations over the centre's domain are the metric's view scores
    np.testing.assert_allclose(s.r, s.view_scores[0], atol=1e-5)


@pytest.mark.parametrize("offset", [[1.5, -1.0, 1.0, 1.5, -1.0, 2.0], [-2.0, 1.5, -1.0, -2.0, 1.5, -1.0]])
def test_local_search_recovers_a_known_pose(talus_scene, offset):
    """Rendered at a known pose, started 1–2 mm / 1–2° off: back within 0.02 mm / 0.05° (ideal
    noise-free views; the per-frame bound at the trial's dose is several times larger)."""
    sc = talus_scene
    m = sc["model"]
    frame = prepare_frame(sc["fluence"](3))
    truth, start = _start(sc["scene"], 3, m.centroid, offset)
    gn, _ = _engine(sc, frame, start)
    res = gauss_newton_search(gn, np.zeros(6), step=H, lower=-BOX, upper=BOX, tol_x=0.01, max_generations=10)
    assert res.converged and res.reason == "tol_x"
    assert res.generations <= 8 and res.evaluations == 13 * res.generations
    err = pose_errors(gn.poses(res.x[None])[0], truth, m.centroid)
    assert np.linalg.norm(err[:3]) < 0.02 and np.linalg.norm(err[3:]) < 0.05, err
    fit = res.model
    assert fit.H.shape == (6, 6) and fit.dof == 6 and np.isfinite(fit.noise)


def test_register_with_the_newton_search(talus_scene):
    sc = talus_scene
    m = sc["model"]
    frame = prepare_frame(sc["fluence"](1))
    truth, start = _start(sc["scene"], 1, m.centroid, [1.0, 1.0, -1.0, -1.0, 1.5, 1.0])
    o = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")
    res = register(sc["renderer"], frame, bone=0, initial_pose=start, center=m.centroid, options=o,
                   outline=m.outline)
    assert res.converged
    assert all(s.method == "gauss_newton" for s in res.stages)
    assert res.score == pytest.approx(1 - res.stages[-1].model.predict(res.x - res.stages[-1].model.x))
    err = pose_errors(res.pose, truth, m.centroid)
    assert np.linalg.norm(err[:3]) < 0.05 and np.linalg.norm(err[3:]) < 0.1, err
    assert res.fit is not None and res.fit.H.shape == (6, 6)
    assert res.timing["engine_steps_x1"] >= 1 and res.timing["engine_scores_x1"] == 0  # scored by its model
    # the engine stays with the renderer: a second frame reuses its buffers
    c1 = engine_cost(sc["renderer"], bone=0, views=(0, 1), scale=1.0, term=DEFAULT_TERMS[0])
    pipes, cap = dict(c1._pipes), c1._cap
    frame2 = prepare_frame(sc["fluence"](2))
    res2 = register(sc["renderer"], frame2, bone=0, initial_pose=res.pose, center=m.centroid, options=o,
                    outline=m.outline)
    assert res2.converged
    if c1._cap == cap:  # buffers of the same size: the same pipelines (graphs on CUDA)
        assert all(c1._pipes[k] is v for k, v in pipes.items())


def test_a_frame_scores_alike_whatever_came_before(talus_scene):
    """Buffers sized by the frame alone: a frame's costs do not depend on the frames before it
    (a resumed run repeats an uninterrupted one)."""
    sc = talus_scene
    m = sc["model"]
    fa, fb = prepare_frame(sc["fluence"](1)), prepare_frame(sc["fluence"](5))
    pa, pb = sc["scene"].poses(1)[0], sc["scene"].poses(5)[0]
    r = sc["renderer"]
    roi_a = search_roi(r, pa, 0, views=(0, 1), center=m.centroid, reach_mm=7.6, points=m.outline)
    roi_b = search_roi(r, pb, 0, views=(0, 1), center=m.centroid, reach_mm=15.0, points=m.outline)
    X = step_design(np.zeros(6), H)
    fresh = GaussNewtonCost(r, bone=0, views=(0, 1), term=DEFAULT_TERMS[0])
    fresh.set_frame(fa, base_pose=pa, center=m.centroid, roi=roi_a)
    first = fresh.step(np.zeros(6), H)
    used = GaussNewtonCost(r, bone=0, views=(0, 1), term=DEFAULT_TERMS[0])
    used.set_frame(fb, base_pose=pb, center=m.centroid, roi=roi_b)
    used(X)
    used.set_frame(fa, base_pose=pa, center=m.centroid, roi=roi_a)
    again = used.step(np.zeros(6), H)
    np.testing.assert_array_equal(again.costs, first.costs)
    np.testing.assert_array_equal(again.g, first.g)


def test_newton_levels_and_fallback(talus_scene):
    lv = default_levels(0.3, search="newton")
    assert [x.method for x in lv] == ["gauss_newton"] and [x.scale for x in lv] == [1.0]
    assert supports(DEFAULT_TERMS) and supports((MetricTerm("ncc"),))
    assert not supports((MetricTerm("mi"),)) and not supports(DEFAULT_TERMS * 2)
    with pytest.raises(ValueError, match="Gauss-Newton"):
        GaussNewtonCost(talus_scene["renderer"], bone=0, views=(0, 1), term=MetricTerm("mi"))
    # a cost the engine cannot score runs the quadratic-model search instead
    sc = talus_scene
    m = sc["model"]
    frame = prepare_frame(sc["fluence"](0))
    o = RegistrationOptions(terms=(MetricTerm("mi"),), bounds=(3.0, 3.0), sigma=(0.5, 0.5), search="newton")
    res = register(sc["renderer"], frame, bone=0, initial_pose=sc["scene"].poses(0)[0], center=m.centroid,
                   options=o, outline=m.outline)
    assert all(s.method == "quadratic" for s in res.stages)


def test_moments_to_newton_of_a_known_correlation():
    """Moments of synthetic pixel data: r, gradient and JᵀJ as the definitions give them."""
    g = np.random.default_rng(3)
    n = 4000
    h = np.full(6, 0.1)
    a = g.normal(size=n)
    D = g.normal(size=(n, 6))  # dB/dx per pixel
    b = 0.8 * a + 0.3 * g.normal(size=n)
    z = np.column_stack([np.ones(n), a, b, D * 2 * h])
    M = (z.T @ z)[None]
    r, grad, Hm = moments_to_newton(M, h)
    assert r[0] == pytest.approx(np.corrcoef(a, b)[0, 1], abs=1e-12)
    # finite differences of r along each D column
    eps = 1e-6
    for k in range(6):
        rp = np.corrcoef(a, b + eps * D[:, k])[0, 1]
        rm = np.corrcoef(a, b - eps * D[:, k])[0, 1]
        assert -grad[k] == pytest.approx((rp - rm) / (2 * eps), rel=1e-5, abs=1e-9)
    bc = b - b.mean()
    Dc = D - D.mean(axis=0)
    nb = np.linalg.norm(bc)
    bh = bc / nb
    J = (Dc - np.outer(bh, bh @ Dc)) / nb
    np.testing.assert_allclose(Hm, r[0] * (J.T @ J), rtol=1e-9)


def test_widened_newton_options_search_globally_then_by_gauss_newton(talus_scene):
    o = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")
    w = o.widened(2.0)
    assert w.search == "global_newton" and w.bounds == (10.0, 10.0)
    assert RegistrationOptions(search="local").widened().search == "global"
    lv = default_levels(0.3, search="global_newton")
    assert [x.method for x in lv] == ["cmaes", "gauss_newton", "gauss_newton"]
    assert [x.scale for x in lv] == [4.0, 2.0, 1.0]
    sc = talus_scene
    m = sc["model"]
    truth, start = _start(sc["scene"], 4, m.centroid, [3.0, -2.0, 2.0, 3.0, -2.0, 3.0])
    res = register(sc["renderer"], prepare_frame(sc["fluence"](4)), bone=0, initial_pose=start,
                   center=m.centroid, options=w, outline=m.outline)
    assert res.converged and [s.method for s in res.stages] == ["cmaes", "gauss_newton"]
    assert res.timing["engine_scores_x1"] > 0  # the CMA-ES populations scored on the engine
    err = pose_errors(res.pose, truth, m.centroid)
    assert np.linalg.norm(err[:3]) < 0.05 and np.linalg.norm(err[3:]) < 0.1, err


def test_search_roi_from_the_outline_hull_is_that_of_every_point(talus_scene):
    """The search region is the image box of the outline's convex hull: the same box as of all
    its points (perspective maps the hull onto the hull of the projections)."""
    sc = talus_scene
    m, r = sc["model"], sc["renderer"]
    for f in (0, 3):
        pose = sc["scene"].poses(f)[0]
        a = search_roi(r, pose, 0, views=(0, 1), center=m.centroid, reach_mm=5.0, points=m.outline)
        b = search_roi(r, pose, 0, views=(0, 1), center=m.centroid, reach_mm=5.0, points=m.outline.tolist())
        np.testing.assert_array_equal(a, b)


def test_newton_starts_again_from_half_resolution_when_it_does_not_converge(talus_scene, monkeypatch):
    import core.tracking.register as reg

    sc = talus_scene
    m = sc["model"]
    truth, start = _start(sc["scene"], 2, m.centroid, [2.0, -1.5, 1.5, 2.0, -1.5, 2.0])
    # a first attempt that cannot converge: one step only
    monkeypatch.setattr(reg, "default_levels", lambda *a, **k: (reg.Level(
        scale=1.0, method="gauss_newton", sigma=reg.FINAL_STEP, max_generations=1, tol_x=0.02),))
    o = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")
    res = register(sc["renderer"], prepare_frame(sc["fluence"](2)), bone=0, initial_pose=start,
                   center=m.centroid, options=o, outline=m.outline)
    assert [s.method for s in res.stages] == ["gauss_newton"] * 3
    assert res.stages[0].reason == "max_generations" and res.converged
    err = pose_errors(res.pose, truth, m.centroid)
    assert np.linalg.norm(err[:3]) < 0.05 and np.linalg.norm(err[3:]) < 0.1, err
    assert [lv.scale for lv in reg._newton_fallback(0.3)] == [2.0, 1.0]
    assert [lv.scale for lv in reg._newton_fallback(1.0)] == [1.0, 1.0]


@pytest.mark.parametrize("kind", ["gc", "ncc"])
def test_device_frame_preparation_is_the_hosts(talus_scene, kind):
    """Full-resolution ROIs prepared on the device (line integrals, the eroded usable-pixel mask,
    the frame's own masks) score as those prepared on the host; an ROI without a usable pixel
    raises OutsideViewError on both paths."""
    from core.tracking.cost import OutsideViewError

    sc = talus_scene
    m = sc["model"]
    flu = [0.8 * np.array(f, dtype=np.float32) for f in sc["fluence"](2)]  # the ideal views' background: 1
    pose = sc["scene"].poses(2)[0]
    r = sc["renderer"]
    roi = search_roi(r, pose, 0, views=(0, 1), center=m.centroid, reach_mm=4.0, points=m.outline)
    u0, v0, w, h = roi[0]
    flu[0][v0 + h // 2: v0 + h // 2 + 3, u0: u0 + w // 2] = 0.0  # black pixels (eroded around)
    flu[0][: v0 + 2] = 1.0  # saturated up to the region's second row
    u0, v0, w, h = roi[1]
    flu[1][v0 + h // 2: v0 + h // 2 + 4, u0 + w // 3: u0 + w] = 1.0
    given = [None, np.ones(flu[1].shape, bool)]
    given[1][: roi[1, 1] + roi[1, 3] // 3] = False
    frame = prepare_frame(flu, masks=given)
    term = MetricTerm(kind, 1.0, {"fluoro_sigma_mm": 0.3, "drr_sigma_mm": 0.3})
    X = step_design(np.zeros(6), H) + np.r_[0.3, -0.2, 0.1, 0.4, -0.3, 0.2]
    out = {}
    for dev in (True, False):
        gn = GaussNewtonCost(r, bone=0, views=(0, 1), term=term)
        gn.device_frames = dev
        gn.set_frame(frame, base_pose=pose, center=m.centroid, roi=roi)
        out[dev] = (gn._raw.numpy(), gn._fmask.numpy(), gn._fmax.numpy(), gn._fshift.numpy(), gn(X),
                    gn.step(np.zeros(6), H))
    a, b = out[True], out[False]
    gn = GaussNewtonCost(r, bone=0, views=(0, 1), term=term)
    wide = search_roi(r, pose, 0, views=(0, 1), center=m.centroid, reach_mm=12.0, points=m.outline)
    assert np.all(wide[:, 2:] > roi[:, 2:])
    for f, rr in ((frame, roi), (prepare_frame(sc["fluence"](3)), wide), (frame, roi), (frame, roi)):
        gn.set_frame(f, base_pose=pose, center=m.centroid, roi=rr)  # grown, uploaded again, then kept
    np.testing.assert_array_equal(gn._raw.numpy(), a[0])
    np.testing.assert_array_equal(gn._fmask.numpy(), a[1])
    np.testing.assert_allclose(a[0], b[0], rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(a[1], b[1])
    assert 0 < a[1].sum() < a[1].size
    np.testing.assert_allclose(a[2], b[2], rtol=1e-6)
    np.testing.assert_allclose(a[3], b[3], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(a[4], b[4], atol=1e-6)
    np.testing.assert_allclose(a[5].g, b[5].g, rtol=1e-4, atol=1e-7)
    bad = [f.copy() for f in flu]
    bad[1][:] = 0.0
    for dev in (True, False):
        gn = GaussNewtonCost(r, bone=0, views=(0, 1), term=term)
        gn.device_frames = dev
        with pytest.raises(OutsideViewError, match="no usable fluoroscope pixel"):
            # the device's count is checked at the first evaluation's synchronisation
            gn.set_frame(prepare_frame(bad), base_pose=pose, center=m.centroid, roi=roi)
            gn(np.zeros((1, 6)))


def test_engine_renders_as_the_renderer(talus_scene):
    """The engine fills the renderer's item table itself (no checks of its own rigid poses):
    the same images as DRRRenderer.render at the engine's ROIs and output size."""
    sc = talus_scene
    m = sc["model"]
    frame = prepare_frame(sc["fluence"](1))
    _, start = _start(sc["scene"], 1, m.centroid, [0.5, -0.5, 0.3, 1.0, 2.0, -1.0])
    gn, roi = _engine(sc, frame, start)
    P = gn.poses(step_design(np.r_[0.2, 0.1, -0.3, 1.5, -2.0, 0.5], H))
    mine = gn._render(P[:, None], (0,)).numpy().copy()
    ref = sc["renderer"].render(P[:, None], views=(0, 1), bones=[0], roi=roi[None, :, None, :],
                                out_shape=gn._cap).images.numpy()
    assert mine.shape == ref.shape and np.abs(ref).max() > 0
    np.testing.assert_allclose(mine, ref, rtol=1e-5, atol=1e-5 * np.abs(ref).max())


def test_pyramid_regions_are_those_of_the_cost_and_score_alike(talus_scene):
    """The engine's pyramid preparation (OpenCV's Gaussian) gives cost.fluoro_rois's regions
    within float32 rounding, the same masks, and the same scores as RegistrationCost at scale 2."""
    from core.tracking.cost import fluoro_rois
    from core.tracking.engine_frames import pyramid_rois

    sc = talus_scene
    m, r = sc["model"], sc["renderer"]
    frame = prepare_frame(sc["fluence"](2))
    _, start = _start(sc["scene"], 2, m.centroid, [1.0, -0.8, 0.6, 1.0, -1.0, 1.5])
    roi = search_roi(r, start, 0, views=(0, 1), center=m.centroid, reach_mm=7.6, points=m.outline)
    for s in (2.0, 4.0):
        a, am = pyramid_rois(frame, (0, 1), roi, s)
        b, bm = fluoro_rois(r, frame, views=(0, 1), roi=roi, scale=s)
        for x, y, xm, ym in zip(a, b, am, bm, strict=True):
            np.testing.assert_allclose(x, y, atol=2e-6 * max(1.0, float(np.abs(y).max())))
            np.testing.assert_array_equal(xm, ym)
    gn = GaussNewtonCost(r, bone=0, views=(0, 1), scale=2.0, term=DEFAULT_TERMS[0])
    gn.set_frame(frame, base_pose=start, center=m.centroid, roi=roi)
    rc = RegistrationCost(r, frame, bone=0, base_pose=start, center=m.centroid, roi=roi, scale=2.0)
    X = step_design(np.zeros(6), 2 * H)
    np.testing.assert_allclose(gn(X), rc(X), atol=1e-5)
