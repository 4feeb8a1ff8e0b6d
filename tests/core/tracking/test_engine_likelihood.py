"""The device weighted least-squares refinement (core.tracking.engine_likelihood): its Gauss–Newton
quantities against the host reference, a known pose recovered, the sandwich covariance."""

from __future__ import annotations

import numpy as np
import pytest

from core.geometry.transforms import params_from_pose, pose_from_params
from core.similarity.likelihood import highpass, wls_gauss_newton_step
from core.tracking.cost import prepare_frame, search_roi
from core.tracking.engine_likelihood import LikelihoodEngine, solve_moments
from core.tracking.engine_search import step_design


def _setup(talus_scene, frame: int, offset, **kw):
    sc, model, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    truth = sc.poses(frame)[0]
    off = np.r_[offset[:3], np.radians(offset[3:])]
    start = pose_from_params(off, center=model.centroid, base=truth)
    fr = prepare_frame(talus_scene["fluence"](frame), valid_range=None)
    roi = search_roi(r, start, 0, views=[0, 1], center=model.centroid, reach_mm=2.0)
    eng = LikelihoodEngine(r, bone=0, views=(0, 1), **kw)
    eng.set_frame(fr, base_pose=start, center=model.centroid, roi=roi)
    return eng, truth, model


def test_step_equals_the_host_reference(talus_scene):
    eng, _, _ = _setup(talus_scene, 2, [0.3, 0, 0, 0, 0.4, 0], highpass_px=2.0)
    h = np.full(6, 0.05)
    x = np.array([0.05, -0.1, 0.0, 0.1, 0.0, -0.05])
    s = eng.step(x, h)
    img = eng._render(eng.poses(step_design(x, h))[:, None], (0,)).numpy()
    y, w = eng._y_raw.numpy(), eng._w.numpy()
    JJ, Jr, chi2 = np.zeros((6, 6)), np.zeros(6), 0.0
    for v, (hh, ww) in enumerate(eng._ref_hw.numpy()):
        D = highpass(np.nan_to_num(img[v::2, :hh, :ww]), 2.0)
        dD = (D[1:13:2] - D[2:13:2]) / (2 * h[:, None, None])
        a, b, c, _ = wls_gauss_newton_step(D[0], dD, highpass(y[v, :hh, :ww], 2.0), w[v, :hh, :ww])
        JJ, Jr, chi2 = JJ + a, Jr - b, chi2 + c
    # the device's Gaussian (4σ taps) and float32 sums against OpenCV's and float64
    np.testing.assert_allclose(s["chi2"], chi2, rtol=2e-2)
    np.testing.assert_allclose(s["JJ"], JJ, rtol=2e-2, atol=2e-2 * np.abs(JJ).max())
    np.testing.assert_allclose(s["Jr"], Jr, rtol=5e-2, atol=5e-2 * np.abs(Jr).max())


def test_refine_recovers_a_known_pose_with_a_covariance(talus_scene):
    eng, truth, model = _setup(talus_scene, 3, [0.4, -0.3, 0.2, 0.5, -0.4, 0.3], highpass_px=3.0)
    out = eng.refine(iters=6)
    e = params_from_pose(eng.poses(out["x"][None])[0], center=model.centroid, base=truth)
    assert np.linalg.norm(e[:3]) < 0.01 and np.degrees(np.linalg.norm(e[3:])) < 0.02, e
    for k in ("covariance", "covariance_independent"):
        C = out[k]
        assert C.shape == (6, 6) and np.all(np.isfinite(C)) and np.all(np.linalg.eigvalsh(C) > 0), k
    # the autocorrelation of the residual is 1 at lag 0
    assert np.allclose(eng.autocorrelation[:, eng.lag_px, eng.lag_px], 1.0)


def test_sandwich_without_lags_is_the_independent_covariance(talus_scene, monkeypatch):
    import core.tracking.likelihood_confidence as lc

    monkeypatch.setattr(lc, "SANDWICH_STRIDE", 1)  # (every pixel: the sums exactly JᵀWJ's)
    eng, _, _ = _setup(talus_scene, 1, [0.2, 0, 0, 0, 0, 0.2], highpass_px=2.0, lag_px=0)
    s = eng.step(np.zeros(6), np.full(6, 0.05))
    Hinv = np.linalg.inv(s["JJ"])
    C = eng.sandwich(s, Hinv)
    # one lag: meat = c(0) JᵀWJ with c(0) the weighted residual's mean square (float32 projections)
    c0 = s["chi2"] / eng.n_pixels
    np.testing.assert_allclose(C, c0 * Hinv, rtol=3e-2, atol=3e-2 * np.abs(c0 * Hinv).max())


def test_solve_moments_background_one():
    rng = np.random.default_rng(0)
    Z = rng.normal(size=(500, 12))
    Z[:, 8] = 1.0
    M = (Z.T @ Z)[None]
    s = solve_moments(M, np.full(6, 0.1), background=1)
    assert s["JJ"].shape == (6, 6) and s["lin"].shape == (1, 42) and s["chi2"] >= 0
    more = solve_moments(M, np.full(6, 0.1), background=1, others=True)  # one regressor more
    assert more["chi2"] <= s["chi2"] + 1e-9 * M[0, 0, 0]


def test_register_with_the_final_stage(talus_scene):
    import pytest

    from core.tracking.confidence import confidence_from_fit
    from core.tracking.final_stage import LikelihoodFit
    from core.tracking.options import TrackingOptions
    from core.tracking.register import RegistrationOptions, register

    sc, model, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    truth = sc.poses(2)[0]
    start = pose_from_params(np.r_[0.5, -0.4, 0.3, np.radians([0.6, -0.5, 0.4])], center=model.centroid,
                             base=truth)
    fr = prepare_frame(talus_scene["fluence"](2), valid_range=None)
    o = RegistrationOptions(bounds=(3.0, 3.0), search="newton", final="likelihood", final_highpass_px=2.0)
    res = register(r, fr, bone=0, initial_pose=start, center=model.centroid, options=o)
    e = params_from_pose(res.pose, center=model.centroid, base=truth)
    assert np.linalg.norm(e[:3]) < 0.02 and np.degrees(np.linalg.norm(e[3:])) < 0.05, e
    assert res.timing["likelihood_taken"] == 1 and res.timing["likelihood_steps"] >= 1
    assert isinstance(res.fit, LikelihoodFit)
    np.testing.assert_allclose(confidence_from_fit(res.fit).covariance, res.fit.covariance, rtol=1e-8)
    # x is relative to the initial pose, as the pose
    back = pose_from_params(np.r_[res.x[:3], np.radians(res.x[3:])], center=model.centroid, base=start)
    np.testing.assert_allclose(back, res.pose, atol=1e-9)
    t = TrackingOptions(refine_likelihood=True)
    assert t.registration.final == "likelihood" and t.first_options.final == "likelihood"
    with pytest.raises(ValueError, match="final"):
        RegistrationOptions(final="ml")
    with pytest.raises(ValueError, match="refine_likelihood"):
        TrackingOptions(refine_likelihood=1)


def test_final_stage_options():
    import pytest

    from core.tracking.register import RegistrationOptions

    o = RegistrationOptions(final="likelihood")
    assert o.final_confidence == "sandwich+move" and o.to_dict()["final"] == "likelihood"
    for kw, msg in (({"final_confidence": "both"}, "final_confidence"),
                    ({"final_lag_px": -1}, "final_lag_px"),
                    ({"final_iters": 0}, "final_iters"), ({"final_reach": (1.0, 0.0)}, "final_reach"),
                    ({"final_highpass_px": float("nan")}, "final_highpass_px")):
        with pytest.raises(ValueError, match=msg):
            RegistrationOptions(final="likelihood", **kw)


def test_neighbours_with_a_gain_of_their_own(talus_scene):
    # the talus's own DRR at a known offset as the "neighbour": with its own gain the fit explains
    # it away (the refinement still converges, its covariance finite)
    sc, model, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    truth = sc.poses(3)[0]
    start = pose_from_params(np.r_[0.3, -0.2, 0.1, np.radians([0.3, -0.2, 0.2])], center=model.centroid,
                             base=truth)
    fr = prepare_frame(talus_scene["fluence"](3), valid_range=None)
    roi = search_roi(r, start, 0, views=[0, 1], center=model.centroid, reach_mm=2.0)
    far = truth.copy()
    far[:3, 3] += [40.0, 0.0, 0.0]  # mostly outside the region: a faint, fixed structure
    eng = LikelihoodEngine(r, bone=0, views=(0, 1), highpass_px=3.0, others_gain=True)
    eng.set_frame(fr, base_pose=start, center=model.centroid, roi=roi, others=(far[None], [0]))
    assert eng._with_o
    out = eng.refine(iters=6)
    e = params_from_pose(eng.poses(out["x"][None])[0], center=model.centroid, base=truth)
    assert np.linalg.norm(e[:3]) < 0.02 and np.degrees(np.linalg.norm(e[3:])) < 0.05, e
    assert np.all(np.isfinite(out["covariance"]))


def test_final_stage_set_up_time_is_counted_once(talus_scene):
    """The attempt's per-frame breakdown: the final stage's set-up is a part of its likelihood_s,
    so "other" (the rest of the attempt's wall time) is not pushed negative by counting it twice."""
    from core.tracking.attempt import register_checked
    from core.tracking.options import TrackingOptions
    from core.tracking.register import RegistrationOptions

    sc, model, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    truth = sc.poses(2)[0]
    fr = prepare_frame(talus_scene["fluence"](2), valid_range=None)
    o = RegistrationOptions(bounds=(3.0, 3.0), search="newton", final="likelihood", final_highpass_px=2.0)
    a = register_checked(r, fr, model, 0, truth, truth, o, TrackingOptions(confidence=False), [], None,
                         lambda: False, [])
    t = a.timing
    assert t["likelihood_setup_s"] > 0 and t["likelihood_s"] >= t["likelihood_setup_s"]
    assert t["other_s"] >= 0, t
    parts = sum(v for k, v in t.items() if k.endswith("_s") and k != "likelihood_setup_s")
    assert abs(parts - a.time_s) < 1e-6 * max(1.0, a.time_s), (parts, a.time_s)


@pytest.mark.parametrize("device_regions", [False, True])
def test_set_up_on_the_device_equals_the_hosts_regions(talus_scene, monkeypatch, device_regions):
    """set_frame's line integrals, usable pixels and neighbour-subtracted regions (the neighbours'
    DRRs rendered and subtracted on the device) equal fluoro_rois' on the host, bit for bit with
    the regions cut on the host; made on the device (engine_likelihood.DEVICE_REGIONS, the default)
    the logarithm's last bit may differ, the usable pixels and their count are the same."""
    import core.tracking.engine_likelihood as el
    from core.tracking.cost import fluoro_rois

    monkeypatch.setattr(el, "DEVICE_REGIONS", device_regions)

    sc, model, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    truth = sc.poses(3)[0]
    fr = prepare_frame(talus_scene["fluence"](3), valid_range=None)
    roi = search_roi(r, truth, 0, views=[0, 1], center=model.centroid, reach_mm=2.0)
    near = truth.copy()
    near[:3, 3] += [6.0, 0.0, 0.0]  # overlapping the region
    others = (near[None], [0])
    eng = LikelihoodEngine(r, bone=0, views=(0, 1), highpass_px=2.0)
    eng.set_frame(fr, base_pose=truth, center=model.centroid, roi=roi, others=others)
    plain, masks = fluoro_rois(r, fr, views=(0, 1), roi=roi)
    sub, _ = fluoro_rois(r, fr, views=(0, 1), roi=roi, others=others)
    li, m, y = eng._bufs["li"].numpy(), eng._bufs["mask"].numpy(), eng._y_raw.numpy()
    same = np.testing.assert_array_equal if not device_regions else \
        (lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6))
    for v in range(2):
        h, w = plain[v].shape
        same(li[v, :h, :w], plain[v])
        np.testing.assert_array_equal(m[v, :h, :w] > 0, masks[v])
        same(y[v, :h, :w], sub[v])
        assert not np.any(m[v, h:]) and not np.any(m[v, :, w:])
    assert not np.array_equal(plain[0], sub[0])  # the neighbour was in the region
    if device_regions:  # (counted on the device: taken at the next step's synchronisation)
        eng.step(np.zeros(6), np.full(6, 0.05))
    assert eng.n_pixels == sum(int(k.sum()) for k in masks)


def test_autocorrelation_equals_numpys(talus_scene, monkeypatch):
    """The sandwich's residual autocorrelation (half the lags summed on the device, the others
    their mirror) equals the pairs' mean products computed with numpy over every lag (every pixel:
    the sub-lattice's in test_likelihood_stride)."""
    import core.tracking.likelihood_confidence as lc

    monkeypatch.setattr(lc, "SANDWICH_STRIDE", 1)
    eng, _, _ = _setup(talus_scene, 2, [0.2, 0, 0, 0, 0.3, 0], highpass_px=2.0, lag_px=3)
    s = eng.step(np.zeros(6), np.full(6, 0.05))
    eng.sandwich(s, np.linalg.inv(s["JJ"]))
    e = eng.residual(s).astype(np.float64)
    used = eng._w.numpy() > 0
    L, (H, W) = 3, e.shape[1:]
    for v in range(2):
        c = np.zeros((2 * L + 1, 2 * L + 1))
        for a in range(-L, L + 1):
            for b in range(-L, L + 1):
                p = (slice(max(0, -a), H - max(0, a)), slice(max(0, -b), W - max(0, b)))
                q = (slice(max(0, a), H - max(0, -a)), slice(max(0, b), W - max(0, -b)))
                both = used[v][p] & used[v][q]
                c[a + L, b + L] = np.sum((e[v][p] * e[v][q])[both]) / max(both.sum(), 1)
        np.testing.assert_allclose(eng.autocorrelation[v], c / c[L, L], rtol=1e-5, atol=1e-7)
