"""spread_screen: candidate names, the WLS step against the stage's moment solve, the GC quadratic."""

import numpy as np
import pytest

from core.studies.tracking import spread_screen as ss
from core.tracking.likelihood_kernels import NZ
from core.tracking.likelihood_solve import solve_moments
from tests.core.studies._blobs import blobs as _blobs


def test_parse_reads_every_token():
    c = ss.parse("hp8+dog2+tissue+rim+norobust+bin2+edge0.5")
    assert (c.kind, c.highpass, c.inner, c.tissue, c.rim, c.robust, c.binning) == ("wls", 8.0, 2.0, True, 3.0,
                                                                                  None, 2)
    assert (c.weights, c.edge_power) == ("edge", 0.5)
    assert ss.parse("gc").kind == "gc"
    assert ss.parse("hp0+poly4+flat").poly == 4
    assert ss.parse("hp4").robust == 2.5
    with pytest.raises(ValueError, match="unknown token"):
        ss.parse("hp4+what")


def test_wls_step_recovers_an_offset_and_matches_the_stage_solve():
    h = 0.05
    X = np.concatenate([np.zeros((1, 6)), np.eye(6) * h, -np.eye(6) * h])
    D = np.stack([_blobs(x) for x in X])
    delta = np.array([0.03, -0.02, 0.01, 0.04, -0.03, 0.02])
    y = 0.9 * _blobs(delta) + 0.2
    w = np.exp(-0.3 * _blobs(np.zeros(6)))
    dD = (D[1:7] - D[7:13]) / (2 * h)
    JJ, Jr, e = ss.wls_step(D[0], dD, y, w)
    est = np.linalg.solve(JJ, Jr)
    np.testing.assert_allclose(est, delta, rtol=0.05, atol=2e-4)
    # the engine's table z = (y, D, δ_1 … δ_6, 1, u, v, O) and its host solve: the same step
    z = np.stack([y, D[0], *(D[1:7] - D[7:13]), np.ones_like(y), np.zeros_like(y), np.zeros_like(y),
                  np.zeros_like(y)]).reshape(NZ, -1)
    M = (z * w.ravel()) @ z.T
    s = solve_moments(M[None], np.full(6, h))
    np.testing.assert_allclose(np.linalg.solve(s["JJ"], s["Jr"]), est, rtol=1e-8, atol=1e-12)
    assert float(np.sum(e**2)) == pytest.approx(s["chi2"], rel=1e-6, abs=1e-12)


def test_quadratic_fit_gives_back_gradient_and_hessian():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(6, 6))
    H = A @ A.T + 6 * np.eye(6)
    g = rng.normal(size=6)
    X = ss._design(0.1)
    c = 1.0 + X @ g + 0.5 * np.einsum("bi,ij,bj->b", X, H, X)
    g2, H2 = ss._quadratic(X, c)
    np.testing.assert_allclose(g2, g, atol=1e-9)
    np.testing.assert_allclose(H2, H, atol=1e-7)


def test_filters_and_binning():
    c = ss.parse("hp4")
    a = np.ones((3, 20, 24)) * 5.0
    np.testing.assert_allclose(ss._filter(a, c, 1.0), 0.0, atol=1e-12)  # a constant is high-passed away
    d = ss.parse("hp4+dog1")
    x = np.random.default_rng(1).normal(size=(20, 24))
    assert np.std(ss._filter(x, d, 1.0)) < np.std(ss._filter(x, c, 1.0))  # (the inner blur: less noise)
    b = ss._bin(np.arange(4 * 6, dtype=float).reshape(4, 6), 2)
    np.testing.assert_allclose(b, [[3.5, 5.5, 7.5], [15.5, 17.5, 19.5]])


def test_summary_splits_bias_and_spread():
    rng = np.random.default_rng(3)
    bias = np.array([0.02, 0.0, 0.0, 0.0, 0.1, 0.0])
    D = bias + rng.normal(0.0, 0.01, size=(4, 2001, 6))
    D[:, 0] = bias  # the noise-free frame's step
    bound = {"rms_mm": 0.02, "rms_deg": 0.1}
    r = ss._summary(D, bound)
    assert r["bias"][0] == pytest.approx(0.02, rel=0.05)
    assert r["spread"][0] == pytest.approx(0.01 * np.sqrt(3), rel=0.05)
    assert r["over_bound"][0] == pytest.approx(np.hypot(0.02, 0.01 * np.sqrt(3)) / 0.02, rel=0.05)
    assert r["noise_free"][1] == pytest.approx(0.1)
    assert r["bound_axes"] is None
