"""Weighted least squares of core.similarity.likelihood against numpy references."""

from __future__ import annotations

import numpy as np
import pytest

from core.similarity.likelihood import (
    _background,
    expected_counts,
    highpass,
    wls_chi2,
    wls_fit,
    wls_gauss_newton_step,
)


def _lstsq_chi2(d, y, w, others=None, order=1):
    cols = [d.ravel()] + ([others.ravel()] if others is not None else [])
    cols += list(_background(y.shape, order).reshape(-1, y.size))
    A = np.stack(cols, axis=1) * np.sqrt(w.ravel())[:, None]
    b = y.ravel() * np.sqrt(w.ravel())
    sol, *_ = np.linalg.lstsq(A, b, rcond=None)
    return float(np.sum((A @ sol - b) ** 2)), sol


@pytest.mark.parametrize("order", [0, 1, 2])
def test_wls_fit_matches_lstsq(order):
    g = np.random.default_rng(3)
    D = g.random((4, 12, 15))
    y = g.random((12, 15))
    w = g.random((12, 15)) + 0.1
    w[0, :3] = 0.0  # unused pixels
    o = g.random((12, 15))
    chi2, coef = wls_fit(D, y, w, others=o, background=order)
    for b in range(4):
        ref, sol = _lstsq_chi2(D[b], y, np.where(w > 0, w, 0), o, order)
        assert chi2[b] == pytest.approx(ref, rel=1e-9, abs=1e-12)
        np.testing.assert_allclose(coef[b], sol, rtol=1e-7, atol=1e-10)


def test_wls_fit_exact_model_scores_zero():
    g = np.random.default_rng(4)
    D = g.random((1, 10, 11))
    y = 1.7 * D[0] + 0.3 + 0.1 * _background((10, 11), 1)[1]
    chi2, coef = wls_fit(D, y, np.ones_like(y), background=1)
    assert chi2[0] < 1e-20
    np.testing.assert_allclose(coef[0], [1.7, 0.3, 0.1, 0.0], atol=1e-9)


def test_gauss_newton_step_is_half_the_chi2_gradient():
    """Jᵀr of the variable-projection step = ½ ∇χ² (with the linear parameters re-fitted)."""
    g = np.random.default_rng(5)
    D0 = g.random((14, 13))
    dD = g.normal(size=(6, 14, 13))
    y = 1.3 * D0 + 0.2
    y = y + 0.05 * g.normal(size=y.shape)
    w = g.random(y.shape) + 0.2

    def chi2(t):
        return wls_fit(D0 + np.tensordot(t, dD, 1), y, w, background=0)[0][0]

    JJ, Jr, c, dof = wls_gauss_newton_step(D0, dD, y, w, background=0)
    assert c == pytest.approx(chi2(np.zeros(6)), rel=1e-10)
    assert dof == y.size - 2
    h = 1e-6
    grad = np.array([(chi2(h * e) - chi2(-h * e)) / (2 * h) for e in np.eye(6)])
    np.testing.assert_allclose(Jr, 0.5 * grad, rtol=1e-4, atol=1e-8)
    assert np.all(np.linalg.eigvalsh(JJ) > 0)


def test_wls_chi2_sums_views_and_highpass_removes_smooth_background():
    g = np.random.default_rng(6)
    D = [g.random((3, 20, 20)), g.random((3, 16, 18))]
    smooth = [np.add.outer(np.linspace(0, 2, 20), np.linspace(0, 1, 20)) ** 2,
              np.add.outer(np.linspace(0, 1, 16), np.linspace(0, 3, 18)) ** 2]
    y = [highpass(2.0 * D[v][1] + smooth[v], 3.0) for v in range(2)]
    w = [np.ones((20, 20)), np.ones((16, 18))]
    c = wls_chi2(D, y, w, background=0, highpass_px=3.0)
    ref = sum(wls_fit(highpass(D[v], 3.0), y[v], w[v], background=0)[0] for v in range(2))
    np.testing.assert_allclose(c, ref, rtol=1e-6)
    assert np.argmin(c) == 1 and c[1] < 0.5 * min(c[0], c[2])


def test_expected_counts_and_bad_input():
    y = np.full((8, 8), 0.5)
    m = np.ones((8, 8), bool)
    m[0, 0] = False
    w = expected_counts(y, mask=m)
    assert w[0, 0] == 0 and w[4, 4] == pytest.approx(np.exp(-0.5))
    with pytest.raises(ValueError, match="weights"):
        wls_fit(np.ones((1, 4, 4)), np.ones((4, 4)), np.zeros((4, 4)))
    with pytest.raises(ValueError, match="drr, fluoro, weights"):
        wls_fit(np.ones((1, 4, 5)), np.ones((4, 4)), np.ones((4, 4)))
