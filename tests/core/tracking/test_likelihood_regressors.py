"""The device likelihood stage's extra regressors (core.tracking.engine_likelihood: set_frame's
``regressors``, set_tissue; core.tracking.final_stage: FinalModel.tissue) against the host
reference LikelihoodCost with the same regressors: step, χ², residual and sandwich."""

from __future__ import annotations

import numpy as np
import pytest

from core.geometry.transforms import pose_from_params
from core.tracking.cost import prepare_frame, search_roi
from core.tracking.engine_likelihood import LikelihoodEngine, solve_moments
from core.tracking.likelihood_cost import LikelihoodCost


def _blob(shape, seed: int) -> np.ndarray:
    """A smooth, structured stand-in for a soft tissue's line integral over a whole view."""
    h, w = shape
    v, u = np.mgrid[0:h, 0:w] / max(h, w)
    rng = np.random.default_rng(seed)
    c = rng.uniform(0.3, 0.7, 2)
    edge = 1.0 / (1.0 + np.exp(-(u - c[0] + 0.3 * (v - c[1])) * 25.0))  # a skin-like edge
    return 0.4 * edge + 0.2 * np.exp(-((u - c[1]) ** 2 + (v - c[0]) ** 2) / 0.05)


def _scene(talus_scene, frame: int):
    sc, model, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    truth = sc.poses(frame)[0]
    fl = talus_scene["fluence"](frame)
    T = [_blob(f.shape, v) for v, f in enumerate(fl)]
    fr = prepare_frame([f * np.exp(-t) for f, t in zip(fl, T, strict=True)], valid_range=None)
    start = pose_from_params(np.r_[0.3, -0.2, 0.2, np.radians([0.3, -0.3, 0.2])], center=model.centroid,
                             base=truth)
    roi = search_roi(r, start, 0, views=[0, 1], center=model.centroid, reach_mm=2.0)
    crops = [t[int(b[1]):int(b[1] + b[3]), int(b[0]):int(b[0] + b[2])] for t, b in zip(T, roi, strict=True)]
    return sc, model, r, truth, fr, start, roi, crops


def test_solve_moments_with_an_extra_regressor_is_the_least_squares_fit():
    rng = np.random.default_rng(3)
    Z = rng.normal(size=(400, 13))
    Z[:, 8] = 1.0
    Z[:, 11] = 0.0  # no neighbours' regressor
    M = (Z.T @ Z)[None]
    s = solve_moments(M, np.full(6, 0.1), extra=1)
    A = Z[:, [1, 8, 12]]
    coef = np.linalg.lstsq(A, Z[:, 0], rcond=None)[0]
    r = Z[:, 0] - A @ coef
    np.testing.assert_allclose(s["chi2"], r @ r, rtol=1e-9)
    assert s["lin"].shape == (1, 6 + 7 + 36)
    np.testing.assert_allclose(s["lin"][0, [0, 1, 5]], coef, rtol=1e-9)
    # without the extra entries: the plain table's solve
    plain = solve_moments(M[:, :12, :12], np.full(6, 0.1))
    assert plain["chi2"] >= s["chi2"]


def test_device_step_residual_and_sandwich_equal_the_host_reference(talus_scene, monkeypatch):
    import core.tracking.likelihood_confidence as lc

    monkeypatch.setattr(lc, "SANDWICH_STRIDE", 1)  # (the reference sums every pixel)
    _, model, r, _, fr, start, roi, crops = _scene(talus_scene, 2)
    host = LikelihoodCost(r, fr, bone=0, base_pose=start, center=model.centroid, roi=roi, views=(0, 1),
                          background=0, regressors=crops)
    eng = LikelihoodEngine(r, bone=0, views=(0, 1), highpass_px=None, lag_px=2)
    eng.set_frame(fr, base_pose=start, center=model.centroid, roi=roi, regressors=crops)
    assert eng._q == 1
    h = np.full(6, 0.05)
    x = np.array([0.05, -0.1, 0.0, 0.1, 0.0, -0.05])
    s = eng.step(x, h)
    _, (_, chi2, JJ, _) , _ = host._gauss_newton(x, host.weights, 1, (0.05, 0.05), (1e-3, 1e-3))
    # one host step from x: its JᵀJ and χ² (float32 sums on the device against float64)
    np.testing.assert_allclose(s["chi2"], chi2, rtol=2e-3)
    np.testing.assert_allclose(s["JJ"], JJ, rtol=2e-3, atol=2e-3 * np.abs(JJ).max())
    # the step itself: the host's -(JᵀJ)⁻¹Jᵀr, the device's (JᵀJ)⁻¹Jᵀr with its sign
    Dh = host._render(x + np.concatenate([np.zeros((1, 6)), np.diag(h), -np.diag(h)]))
    from core.tracking.likelihood_cost import _step_general

    Jr = np.zeros(6)
    for v, Dv in enumerate(Dh):
        Dv = host._filtered(Dv)
        dD = (Dv[1:7] - Dv[7:13]) / (2 * h[:, None, None])
        Jr = Jr + _step_general(Dv[0], dD, host.fluoro_rois[v], host.weights[v], host._regressors(v))[1]
    np.testing.assert_allclose(np.linalg.solve(s["JJ"], s["Jr"]), -np.linalg.solve(JJ, Jr), rtol=5e-3,
                               atol=5e-3 * np.abs(np.linalg.solve(JJ, Jr)).max())
    # the weighted residual at x equals the host's
    e_dev = eng.residual(s)
    e_host = host.residual(x)
    for v in range(2):
        hh, ww = host.fluoro_rois[v].shape
        np.testing.assert_allclose(e_dev[v, :hh, :ww], e_host[v, :hh, :ww], rtol=0,
                                   atol=2e-3 * np.abs(e_host[v]).max())
    # the sandwich: H⁻¹ (Σ J̃_i J̃_jᵀ C(i - j)) H⁻¹ from the device's residual and projections, and
    # numpy's from the host's residual, over lags |Δ| <= 2 with Bartlett's taper
    Hinv = np.linalg.inv(s["JJ"])
    C = eng.sandwich(s, Hinv)
    _, jt = eng._residual_device(s)
    J = jt.numpy().astype(np.float64)
    L = 2
    meat = np.zeros((6, 6))
    for v in range(2):
        hh, ww = host.fluoro_rois[v].shape
        e = e_host[v, :hh, :ww]
        used = host.weights[v] > 0
        Jv = J[v, :hh, :ww]
        for da in range(-L, L + 1):
            for db in range(-L, L + 1):
                p = (slice(max(0, -da), hh - max(0, da)), slice(max(0, -db), ww - max(0, db)))
                q = (slice(max(0, da), hh - max(0, -da)), slice(max(0, db), ww - max(0, -db)))
                both = used[p] & used[q]
                cov = np.sum((e[p] * e[q])[both]) / max(both.sum(), 1)
                tap = (1 - abs(da) / (L + 1)) * (1 - abs(db) / (L + 1))
                meat += cov * tap * np.einsum("ijk,ijl->kl", Jv[p], Jv[q])
    meat = 0.5 * (meat + meat.T)
    np.testing.assert_allclose(C, Hinv @ meat @ Hinv, rtol=5e-3, atol=5e-3 * np.abs(C).max())


def test_the_regressor_takes_out_what_it_models(talus_scene):
    """The frame's added structure as the regressor: the refinement finds the true pose; without
    it, it does not (no high-pass: the structure stays in the line integrals)."""
    from core.geometry.transforms import params_from_pose

    _, model, r, truth, fr, start, roi, crops = _scene(talus_scene, 3)
    errs = {}
    for k, reg in (("with", crops), ("without", None)):
        eng = LikelihoodEngine(r, bone=0, views=(0, 1), highpass_px=None)
        eng.set_frame(fr, base_pose=start, center=model.centroid, roi=roi, regressors=reg)
        out = eng.refine(iters=8)
        e = params_from_pose(eng.poses(out["x"][None])[0], center=model.centroid, base=truth)
        errs[k] = np.linalg.norm(e[:3])
    assert errs["with"] < 0.01 and errs["without"] > 5 * errs["with"], errs


def test_set_tissue_renders_the_volumes_at_their_poses(talus_scene):
    """set_tissue's regressor (no high-pass) is the tissue renderer's DRR over the regions; with a
    high-pass it is that DRR high-passed (the device's Gaussian against the host's)."""
    from core.similarity.likelihood import highpass
    from core.tracking.final_stage import FinalModel, tissue_renderer

    sc, model, r, truth, fr, start, roi, _ = _scene(talus_scene, 1)
    vol = sc.bones[0]
    fm = FinalModel(tissue=((vol, 0),))
    tr = tissue_renderer(r, fm.tissue)
    assert tissue_renderer(r, fm.tissue) is tr and fm.to_dict()["tissue"][0]["bone"] == 0
    far = truth.copy()
    far[:3, 3] += [3.0, -2.0, 1.0]
    ref = tr.render(far[None, None], views=(0, 1), roi=roi[None, :, None, :]).numpy()[0, :, 0]
    for hp in (None, 2.0):
        eng = LikelihoodEngine(r, bone=0, views=(0, 1), highpass_px=hp)
        eng.set_frame(fr, base_pose=start, center=model.centroid, roi=roi)
        assert eng._q == 0
        eng.set_tissue(tr, far[None])
        t = eng._t.numpy()
        assert eng._q == 1 and t.shape[0] == 2
        for v in range(2):
            hh, ww = int(roi[v][3]), int(roi[v][2])
            want = np.nan_to_num(ref[v, :hh, :ww])
            if hp:
                want = highpass(want, hp)
                np.testing.assert_allclose(t[v, :hh, :ww], want, atol=3e-2 * np.abs(want).max())
            else:
                np.testing.assert_allclose(t[v, :hh, :ww], want, rtol=1e-6, atol=1e-6)
            assert not np.any(t[v, hh:]) and not np.any(t[v, :, ww:])
    with pytest.raises(ValueError, match="tissue"):
        FinalModel(tissue=((vol, -1),))


def test_high_passed_regressors_and_the_fluence_psf(talus_scene):
    """With a high-pass, set_frame's regressors are high-passed like the frame (LikelihoodCost's
    semantics; the device's Gaussian against the host's); set_tissue's ``psf`` blurs the tissue as
    fluence."""
    from core.similarity.likelihood import blur
    from core.tracking.final_stage import FinalModel, tissue_renderer

    _, model, r, truth, fr, start, roi, crops = _scene(talus_scene, 2)
    host = LikelihoodCost(r, fr, bone=0, base_pose=start, center=model.centroid, roi=roi, views=(0, 1),
                          background=0, regressors=crops, highpass_px=2.0)
    eng = LikelihoodEngine(r, bone=0, views=(0, 1), highpass_px=2.0)
    eng.set_frame(fr, base_pose=start, center=model.centroid, roi=roi, regressors=crops)
    t = eng._t.numpy()
    for v in range(2):
        want = host._regressors(v)[-1]
        hh, ww = want.shape
        np.testing.assert_allclose(t[v, :hh, :ww], want, atol=3e-2 * np.abs(want).max())
    h = np.full(6, 0.05)
    s = eng.step(np.zeros(6), h)
    _, (_, chi2, JJ, _), _ = host._gauss_newton(np.zeros(6), host.weights, 1, (0.05, 0.05), (1e-3, 1e-3))
    np.testing.assert_allclose(s["chi2"], chi2, rtol=3e-2)
    np.testing.assert_allclose(s["JJ"], JJ, rtol=3e-2, atol=3e-2 * np.abs(JJ).max())
    # the tissue blurred as fluence: -log(psf ∗ exp(-L)) (no high-pass here)
    tr = tissue_renderer(r, FinalModel(tissue=((talus_scene["scene"].bones[0], 0),)).tissue)
    psf = np.outer([1, 4, 6, 4, 1], [1, 4, 6, 4, 1]).astype(float)
    eng = LikelihoodEngine(r, bone=0, views=(0, 1), highpass_px=None)
    eng.set_frame(fr, base_pose=start, center=model.centroid, roi=roi)
    eng.set_tissue(tr, truth[None], psf=psf)
    ref = tr.render(truth[None, None], views=(0, 1), roi=roi[None, :, None, :]).numpy()[0, :, 0]
    t = eng._t.numpy()
    for v in range(2):
        hh, ww = int(roi[v][3]), int(roi[v][2])
        L = np.nan_to_num(ref[v, :hh, :ww]).astype(np.float64)
        want = -np.log(blur(np.exp(-L), psf / psf.sum()))
        inner = (slice(3, hh - 3), slice(3, ww - 3))  # (the borders' handling may differ)
        np.testing.assert_allclose(t[v][inner], want[inner], atol=1e-4 * max(1.0, np.abs(want).max()))


def test_final_stage_with_a_tissue_volume(talus_scene):
    """FinalModel.tissue through a registration's final stage: a smooth "tissue" volume following
    the bone, in the frame at the true pose, rendered by the stage at the similarity's pose."""
    from core.geometry.transforms import params_from_pose
    from core.render import CTVolume
    from core.tracking.engine_likelihood import likelihood_engine
    from core.tracking.final_stage import FinalModel, final_model, tissue_renderer
    from core.tracking.register import RegistrationOptions, register

    sc, model, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    n, sp = 16, 5.0
    k, j, i = np.indices((n, n, n)) - (n - 1) / 2
    rr = np.sqrt((i / 6.0) ** 2 + (j / 5.0) ** 2 + (k / 7.0) ** 2)
    mu = (0.02 / (1 + np.exp((rr - 1.0) * 8))).astype(np.float32)  # an ellipsoid with a soft skin
    corner = np.asarray(model.centroid) + np.array([6.0, -4.0, 3.0]) - sp * (n - 1) / 2
    vol = CTVolume(mu, spacing=np.full(3, sp), origin=corner, units="1/mm", name="blob")
    fm = FinalModel(tissue=((vol, 0),), tissue_again=True)
    tr = tissue_renderer(r, fm.tissue)
    f = 2
    truth = sc.poses(f)[0]
    Lt = tr.render(truth[None, None], roi="full").numpy()[0, :, 0]
    fr = prepare_frame([fl * np.exp(-np.nan_to_num(t)) for fl, t in zip(talus_scene["fluence"](f), Lt,
                                                                             strict=True)], valid_range=None)
    start = pose_from_params(np.r_[0.4, -0.3, 0.2, np.radians([0.5, -0.4, 0.3])], center=model.centroid,
                             base=truth)
    o = RegistrationOptions(bounds=(3.0, 3.0), search="newton", final="likelihood", final_highpass_px=2.0)
    with final_model(fm):
        res = register(r, fr, bone=0, initial_pose=start, center=model.centroid, options=o)
    eng = likelihood_engine(r, bone=0, views=(0, 1), highpass_px=2.0, lag_px=o.final_lag_px,
                            others_gain=o.final_others_gain)
    assert eng._q == 1 and res.timing["likelihood_taken"] == 1
    e = params_from_pose(res.pose, center=model.centroid, base=truth)
    assert np.linalg.norm(e[:3]) < 0.02 and np.degrees(np.linalg.norm(e[3:])) < 0.05, e
