"""Why the likelihood stage's Gauss–Newton steps contract slowly: the moments' arithmetic gives the
exact step of a linear model in one step; a frame blurrier than the model has a χ² curvature below
Gauss–Newton's, so the steps shrink by 1 - θ a step (numpy)."""

from __future__ import annotations

import numpy as np

from core.tracking.likelihood_solve import solve_moments


def _table(z: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``Σ w z zᵀ`` of pixels ``z (N, 12)`` (one view's moments table)."""
    return (z * w[:, None]).T @ z


def test_moments_give_the_linear_models_step_in_one():
    """y = a (D + Σ G_k x*_k) + c₀ + c_u u + c_v v + noise-free, the differences ``δ_k = 2 h_k G_k``
    (G orthogonal to the linear part in the weights' metric): one step is x* (both views, each
    weighted), so JᵀWJ and JᵀWr carry the weights once and the same differences."""
    rng = np.random.default_rng(0)
    n, h = 4000, np.array([0.05, 0.05, 0.05, 0.1, 0.1, 0.1])
    x_true = np.array([0.03, -0.02, 0.05, 0.08, -0.04, 0.02])
    M = []
    for v in range(2):
        u, vv = rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)
        w = rng.uniform(0.5, 2.0, n)
        D = rng.normal(size=n)
        A = np.stack([D, np.ones(n), u, vv], axis=1)
        G = rng.normal(size=(n, 6))
        Wm = A.T * w  # (the weights' metric: G made orthogonal to A's columns)
        G = G - A @ np.linalg.solve(Wm @ A, Wm @ G)
        a, c = 1.7 + v, (0.3, 0.1, -0.2)
        y = a * (D + G @ x_true) + c[0] + c[1] * u + c[2] * vv
        z = np.zeros((n, 12))
        z[:, 0], z[:, 1] = y, D
        z[:, 2:8] = 2.0 * h * G
        z[:, 8], z[:, 9], z[:, 10] = 1.0, u, vv
        M.append(_table(z, w))
    s = solve_moments(np.array(M), h, background=1)
    np.testing.assert_allclose(np.linalg.solve(s["JJ"], s["Jr"]), x_true, rtol=0, atol=1e-10)


def _profile(t: np.ndarray, blur: float = 0.0) -> np.ndarray:
    """A bone's edge across a row of pixels (a smooth step of width 1 px), blurred by a Gaussian of
    ``blur`` px (the two widths add in quadrature)."""
    from scipy.special import erf

    return 0.5 * (1.0 + erf(t / np.sqrt(2.0 * (1.0 + blur ** 2))))


def _blurred_gn(t_true: float, blur: float, *, steps: int = 30, tol: float = 1e-6):
    """Gauss–Newton for the edge's place ``t`` fitting the sharp model ``a D(p - t) + c`` to a frame
    blurred by ``blur`` px at ``t_true``: the iterates."""
    p = np.arange(-20.0, 20.0, 0.25)
    y = 2.0 * _profile(p - t_true, blur) + 0.5
    t, xs = 0.0, []
    for _ in range(steps):
        D = _profile(p - t)
        dD = (_profile(p - t - 1e-4) - _profile(p - t + 1e-4)) / 2e-4  # ∂D/∂t (the model moved)
        A = np.stack([D, np.ones_like(p)], axis=1)
        coef = np.linalg.lstsq(A, y, rcond=None)[0]
        r = y - A @ coef
        J = coef[0] * (dD - A @ np.linalg.lstsq(A, dD, rcond=None)[0])  # (gain and offset projected out)
        s = {"JJ": np.array([[J @ J]]), "Jr": np.array([J @ r])}
        d = np.linalg.solve(s["JJ"], s["Jr"])
        t += float(d[0])
        xs.append(t)
        if abs(d[0]) < tol:
            break
    return np.array(xs)


def test_a_blurred_frame_contracts_the_steps():
    """The model matches the frame (no blur): Gauss–Newton in 3 steps; the frame blurred by 2 px
    more than the model: each step 0.44 of the one before (1 - θ, θ the χ² curvature over Gauss–
    Newton's, 0.57), all on one side, to the same point."""
    sharp = _blurred_gn(0.4, 0.0)
    assert len(sharp) <= 4 and abs(sharp[-1] - 0.4) < 1e-6
    plain = _blurred_gn(0.4, 2.0)
    d = np.diff(np.r_[0.0, plain])
    ratio = d[2:8] / d[1:7]
    assert np.all((ratio > 0.4) & (ratio < 0.47))
