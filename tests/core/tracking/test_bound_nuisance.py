"""The Cramér–Rao bound with a smooth nuisance field unknown (:mod:`core.tracking.bound_nuisance`):
the Schur complement is the inverse's block, a nuisance W-orthogonal to the derivatives changes
nothing, one that contains a derivative leaves that parameter unbounded; on a rendered bone the
bound nests with the basis and a background in the basis biases nothing."""

import numpy as np
import pytest

from core.tracking.bound import _inverse, pose_bound
from core.tracking.bound_nuisance import lowpass_factors, nuisance_bound, nuisance_information, spline_factors


def _dense(factors):
    """``(m, h, w)`` basis images of separable ``factors``."""
    By, Bx, mask = factors
    B = np.einsum("yi,xk->ikyx", By, Bx).reshape(-1, By.shape[0], Bx.shape[0])
    return B if mask is None else B[np.asarray(mask).ravel()]


@pytest.fixture(scope="module")
def problem():
    g = np.random.default_rng(7)
    h, w = 22, 27
    G = g.normal(size=(6, h, w))
    W = g.uniform(20.0, 300.0, size=(h, w))
    return G, W, spline_factors((5, 3, w, h), 7.0), g.normal(size=(1, h, w))


def test_schur_complement_is_the_inverse_of_the_full_informations_block(problem):
    G, W, fac, extra = problem
    B = np.concatenate([_dense(fac), extra])
    A = np.concatenate([G, B]).reshape(len(G) + len(B), -1)
    full = (A * W.ravel()) @ A.T
    J, Js = nuisance_information(G, W, fac, extra)
    np.testing.assert_allclose(J, full[:6, :6], rtol=1e-12)
    np.testing.assert_allclose(np.linalg.inv(Js), np.linalg.inv(full)[:6, :6], rtol=1e-7)
    assert np.linalg.eigvalsh(np.linalg.inv(Js) - np.linalg.inv(J)).min() > -1e-12  # never below the known


def test_nuisance_orthogonal_to_the_derivatives_changes_nothing(problem):
    G, W, fac, extra = problem
    B = np.concatenate([_dense(fac), extra]).reshape(-1, G[0].size)
    Gf = G.reshape(6, -1)
    coef = np.linalg.lstsq((B * W.ravel()) @ B.T, (B * W.ravel()) @ Gf.T, rcond=None)[0]
    Go = (Gf - coef.T @ B).reshape(G.shape)  # the derivatives W-projected off the basis
    J, Js = nuisance_information(Go, W, fac, extra)
    np.testing.assert_allclose(Js, J, rtol=1e-8, atol=1e-8 * np.abs(J).max())


def test_a_basis_holding_a_derivative_leaves_that_parameter_unbounded(problem):
    G, W, fac, _ = problem
    _, Js = nuisance_information(G, W, fac, G[2:3])
    assert np.all(np.abs(Js[2]) < 1e-8 * np.abs(Js).max())
    assert np.all(np.isinf(_inverse(Js)))
    # nearly in the basis: finite but large for that parameter only
    g = np.random.default_rng(1)
    J, Js = nuisance_information(G, W, fac, G[2:3] + 1e-3 * g.normal(size=G[2:3].shape))
    s = np.sqrt(np.diag(np.linalg.inv(Js)) / np.diag(np.linalg.inv(J)))
    assert s[2] > 50 and np.all(s[[0, 1, 3, 4, 5]] < 3)


def test_lowpass_modes_are_the_ones_the_gaussian_keeps():
    Cy, Cx, mask = lowpass_factors((0, 0, 40, 30), 2.0, keep=0.5)
    np.testing.assert_allclose(Cx.T @ Cx, np.eye(Cx.shape[1]), atol=1e-12)
    fy, fx = np.arange(Cy.shape[1]) / 60.0, np.arange(Cx.shape[1]) / 80.0
    kept = np.exp(-2 * np.pi**2 * 4.0 * (fy[:, None] ** 2 + fx[None, :] ** 2))
    assert np.all(kept[mask] >= 0.5 - 1e-12) and mask[0, 0] and not mask[-1, -1]
    By, Bx, _ = spline_factors((3, 0, 40, 30), 8.0)
    np.testing.assert_allclose(By.sum(axis=1), 1.0, rtol=1e-12)  # a partition of unity: the offset is in
    np.testing.assert_allclose(Bx.sum(axis=1), 1.0, rtol=1e-12)


def test_rendered_bone_bound_nests_with_the_basis_and_a_background_in_it_biases_nothing(talus_scene):
    r, model = talus_scene["renderer"], talus_scene["model"]
    P, c = talus_scene["scene"].poses(2)[0], model.centroid
    h, w = r.cameras[0].image_shape
    yy, xx = np.mgrid[0:h, 0:w]
    L = [1.0 + 2.0 * xx / (w - 1) + 0.5 * np.sin(yy / 9.0) for _ in range(2)]
    kw = {"line_integral": L, "quanta_per_pixel": 3000.0, "grow_px": 16}
    own = pose_bound(r, 0, P, c, line_integral=L, quanta_per_pixel=3000.0)
    nb = [nuisance_bound(r, 0, P, c, spacing_px=d, **kw) for d in (16.0, 8.0, 4.0)]
    np.testing.assert_allclose(nb[0].known.information, own.information, rtol=1e-9)
    prev = own.covariance
    for b in nb:  # spacing 4 holds spacing 8's splines, which hold 16's: each bound at least the last
        assert np.linalg.eigvalsh(b.nuisance.covariance - prev).min() > -1e-9 * np.abs(prev).max()
        prev = b.nuisance.covariance
    assert 1.0 < nb[0].ratio()[0] < nb[2].ratio()[0] < 5.0
    # a background in the span of the splines (a cubic in u) is absorbed: no bias
    bg = [(xx / w) ** 3 + 0.3 * (yy / h) for _ in range(2)]
    b = nuisance_bound(r, 0, P, c, spacing_px=8.0, residual=bg, **kw)
    assert np.all(np.abs(b.bias) < 1e-6 * np.r_[b.nuisance.sigma])
    # a sharp one (an edge through the bone) is not
    edge = [np.where(xx > w // 2, 0.3, 0.0) for _ in range(2)]
    b = nuisance_bound(r, 0, P, c, spacing_px=8.0, residual=edge, **kw)
    assert np.max(np.abs(b.bias) / b.nuisance.sigma) > 0.1
    lp = nuisance_bound(r, 0, P, c, basis="lowpass", sigma_px=1.0, line_integral=L, quanta_per_pixel=3000.0)
    assert lp.ratio()[0] > 1.0 and lp.parameters > 100


def test_bad_basis_is_refused(talus_scene):
    r, model = talus_scene["renderer"], talus_scene["model"]
    with pytest.raises(ValueError, match="basis"):
        nuisance_bound(r, 0, talus_scene["scene"].poses(0)[0], model.centroid, basis="poly",
                       line_integral=[np.ones((128, 128))] * 2, quanta_per_pixel=1.0)
    with pytest.raises(ValueError, match="spacing_px"):
        spline_factors((0, 0, 10, 10), 0.0)


def test_study_bounds_each_model_and_restates_a_stored_run():
    from core.studies.tracking import acceptance
    from core.studies.tracking.tissue_bound import background, bounds, models, restate

    ts = acceptance.TrackingScene(n_frames=2, pixels=80, spacing=2.0, device="cpu", correction="exact")
    mods = models(80, spacings=(16.0, 8.0))
    assert mods["bs8"]["spacing_px"] == pytest.approx(2.5) and mods["hp"]["sigma_px"] == pytest.approx(0.3125)
    R = background(ts, 0)
    L = ts.scene.line_integrals(0, renderer=ts._scene_renderer)
    assert R.shape == L.shape and np.all(R <= L + 1e-4) and R.max() > 1.0  # tissue and walkway: part of L
    b = bounds(ts, [1], {k: mods[k] for k in ("bs16", "bs8")})
    known = acceptance.cramer_rao(ts, [1])  # the acceptance study's bound is the known-tissue one
    for n, t in b.items():
        assert t["frames"] == [1]
        assert t["known"]["rms_mm"] == pytest.approx(known[n]["rms_mm"], rel=1e-9)
        assert t["known"]["rms_deg"] == pytest.approx(known[n]["rms_deg"], rel=1e-9)
        assert 1.0 <= t["bs16"]["ratio"]["mm"] <= t["bs8"]["ratio"]["mm"] * (1 + 1e-9)
        assert t["bs8"]["bias_rms"]["mm"] > 0
    n = ts.names[0]
    cr = {"rms_mm": 0.02, "rms_deg": 0.1}
    row = {"rms_error_mm": 0.03, "rms_error_deg": 0.2, "cramer_rao": cr}
    stored = {"runs": {"joint": {"tracking": {n: row}}}}
    r = restate(stored, b, ("bs8",))["joint"][n]
    assert r["over_known"] == pytest.approx({"mm": 1.5, "deg": 2.0})
    assert r["over_bs8"]["mm"] == pytest.approx(1.5 / b[n]["bs8"]["ratio"]["mm"])
