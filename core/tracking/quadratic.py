"""Batched quadratic-model local search: a trust-region Newton method on sampled costs.

Near the optimum a registration cost is a smooth bowl with a little roughness (image noise, DRR
interpolation). :func:`quadratic_search` samples it on a second-order design about the current
centre ``x`` — all points of a generation in **one** batched call of ``fun`` (one DRR launch +
one metric launch) — fits the full quadratic::

    c(x + d) ≈ c0 + gᵀd + ½ dᵀHd          (1 + n + n(n+1)/2 coefficients; 28 for n = 6)

by least squares (:func:`fit_quadratic`) and moves to the model's minimum ``d* = -H⁻¹g``, limited
to a trust region. Because every generation fits all 28 coefficients from many points, a 6-DOF
registration converges in a few generations instead of the ~100 of CMA-ES or a compass search,
and the minimiser of the *fitted* bowl averages the cost's roughness over the whole design
rather than picking its luckiest sample. The last fit is returned with the result: its Hessian
and residual give the pose uncertainty at no extra cost
(:func:`core.tracking.confidence.confidence_from_fit`).

Designs (unit offsets, scaled per coordinate by the half-widths ``h``)
-----------------------------------------------------------------------
* ``"full"`` — the centre, ``±e_i`` and all four ``±e_i ± e_j``: 73 points for n = 6
  (45 residual degrees of freedom);
* ``"compact"`` — the centre, ``±e_i`` and ``+e_i + e_j``, ``-e_i - e_j``: 43 points (15 residual
  degrees of freedom), for when a generation's poses are expensive.

Iteration (scaled coordinates ``u = d / h``)
--------------------------------------------
1. Evaluate the design about ``x``; fit. If ``H`` is positive definite the proposal is the
   Newton step, shortened to the trust radius ``Δ`` (∞-norm, in units of ``h``); otherwise the
   best design point, with a 1.5× wider design.
2. The next design is centred on the proposal, with half-widths ``h_i`` chosen so that the
   cost rises well above its roughness across them — ``2 sqrt(2 σ_c / H_ii)`` (``σ_c`` the fit's
   residual RMS) — and at least half the step, within ``[min_step, max_step]``: a poorly
   constrained direction (a rotation about a bone's long axis, a noisy image) gets a wider
   design instead of a fit of noise.
3. The new fit's value at its centre ``c0`` (a smoothed value: single samples carry the
   roughness) is compared with the previous one: the move is accepted unless it is worse by
   more than the roughness; otherwise it is retried from the previous centre with ``Δ``
   halved. A step that reached the trust radius doubles ``Δ`` (up to ``max_trust``).
   A trust radius below ``tol_x`` ends the run as ``"stalled"`` (not converged).
4. Converged (``"tol_x"``) when ``H`` is positive definite, the design's half-widths are
   settled (within 30 % of the wanted ones) and the Newton step is below ``tol_x`` in every
   coordinate or its predicted decrease ``½ dᵀHd`` is below ``tol_noise`` × the roughness (a
   move the data cannot confirm: with the default 0.1, a third of the
   :func:`~core.tracking.confidence.confidence_from_fit` sigma). The result is the model's
   minimum ``x + d*`` and ``fun`` its fitted value.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from itertools import combinations

import numpy as np

from .optimize import OptimizeResult, _box, _positive_int, _Tracker

__all__ = ["QuadraticFit", "design", "fit_quadratic", "quadratic_search"]


def design(n: int = 6, kind: str = "full") -> np.ndarray:
    """Unit second-order design ``(m, n)``; row 0 is the centre (see the module docs)."""
    if kind not in ("full", "compact"):
        raise ValueError(f"kind: expected 'full' or 'compact', got {kind!r}")
    if isinstance(n, bool) or int(n) != n or n < 1:
        raise ValueError(f"n: expected a positive dimension, got {n!r}")
    n = int(n)
    eye = np.eye(n)
    rows = [np.zeros(n)]
    for i in range(n):
        rows += [eye[i], -eye[i]]
    signs = ((1, 1), (1, -1), (-1, 1), (-1, -1)) if kind == "full" else ((1, 1), (-1, -1))
    for i, j in combinations(range(n), 2):
        rows += [si * eye[i] + sj * eye[j] for si, sj in signs]
    return np.array(rows)


def _design_matrix(U: np.ndarray) -> np.ndarray:
    n = U.shape[1]
    iu, ju = np.triu_indices(n)
    quad = U[:, iu] * U[:, ju] * np.where(iu == ju, 0.5, 1.0)
    return np.hstack([np.ones((len(U), 1)), U, quad])


@dataclass(frozen=True, eq=False)
class QuadraticFit:
    """A quadratic ``c0 + gᵀd + ½ dᵀHd`` fitted about ``x`` (``d`` in x units).

    Attributes
    ----------
    x : (n,) array
        Centre of the design.
    h : (n,) array
        Design half-widths.
    c0 : float
        Fitted value at the centre.
    g : (n,) array
        Gradient.
    H : (n, n) array
        Hessian.
    noise : float
        RMS residual of the fit (the cost's roughness at the scale of the design).
    dof : int
        Residual degrees of freedom.
    values : (m,) array
        The sampled cost values (row 0: the centre).
    """

    x: np.ndarray
    h: np.ndarray
    c0: float
    g: np.ndarray
    H: np.ndarray
    noise: float
    dof: int
    values: np.ndarray

    @property
    def positive_definite(self) -> bool:
        w = np.linalg.eigvalsh(self.H / np.outer(1 / self.h, 1 / self.h))
        return bool(w.min() > 1e-9 * max(abs(w.max()), 1e-300))

    def newton_step(self) -> np.ndarray:
        """``d* = -H⁻¹ g`` (meaningful when :attr:`positive_definite`)."""
        Hu = self.H * np.outer(self.h, self.h)
        return np.linalg.solve(Hu, -self.g * self.h) * self.h

    def predict(self, d) -> float:
        d = np.asarray(d, dtype=float)
        return float(self.c0 + self.g @ d + 0.5 * d @ self.H @ d)

    def to_dict(self) -> dict:
        return {"x": self.x.tolist(), "h": self.h.tolist(), "c0": self.c0, "g": self.g.tolist(),
                "H": self.H.tolist(), "noise": self.noise, "dof": self.dof}


def fit_quadratic(D, f, h, *, x=None, pinv: np.ndarray | None = None) -> QuadraticFit:
    """Least-squares quadratic through values ``f (m,)`` at offsets ``D (m, n)`` about ``x``.

    ``h`` (n,) scales the offsets for conditioning (the design's half-widths); ``pinv`` is an
    optional precomputed pseudo-inverse of the scaled design matrix (same ``D / h``)."""
    D = np.atleast_2d(np.asarray(D, dtype=float))
    f = np.asarray(f, dtype=float).ravel()
    m, n = D.shape
    h = np.broadcast_to(np.asarray(h, dtype=float), (n,))
    p = 1 + n + n * (n + 1) // 2
    if len(f) != m or m < p:
        raise ValueError(f"D, f: expected at least {p} points with one value each, got {m} and {len(f)}")
    U = D / h
    A = _design_matrix(U)
    coef = pinv @ f if pinv is not None else np.linalg.lstsq(A, f, rcond=None)[0]
    resid = f - A @ coef
    dof = m - p
    noise = float(np.sqrt(resid @ resid / max(dof, 1)))
    iu, ju = np.triu_indices(n)
    Hu = np.zeros((n, n))
    Hu[iu, ju] = coef[1 + n:]
    Hu[ju, iu] = coef[1 + n:]
    return QuadraticFit(np.zeros(n) if x is None else np.asarray(x, dtype=float).copy(), h.copy(),
                        float(coef[0]), coef[1:1 + n] / h, Hu / np.outer(h, h), noise, dof, f.copy())


def quadratic_search(fun: Callable, x0, *, step, min_step=None, max_step=None, lower=None, upper=None,
                     tol_x: float = 0.01, tol_noise: float = 0.1, max_generations: int = 12,
                     max_evaluations: int | None = None, trust: float = 2.0, max_trust: float = 4.0,
                     kind: str = "full", cancel: Callable[[], bool] | None = None) -> OptimizeResult:
    """Minimise ``fun(X (B, n)) -> (B,)`` from ``x0`` by fitted quadratic models (module docs).

    Parameters
    ----------
    step : float or (n,) array
        Initial design half-widths (x units).
    min_step, max_step : float or (n,) array, optional
        Bounds of the half-widths (defaults ``step`` and ``2 step``).
    lower, upper : optional
        Box; design points are clipped to it.
    tol_x : float
        Converged when every coordinate of the Newton step is below it (x units), ...
    tol_noise : float
        ... or when the step's predicted decrease ``½ dᵀHd`` is below ``tol_noise`` × the fit's
        residual RMS: a move the cost's roughness cannot confirm.
    max_generations : int
        Batched calls of ``fun``.
    trust, max_trust : float
        Initial and largest trust radius, ∞-norm in units of the half-widths.
    kind : {"full", "compact"}
        Design (:func:`design`).

    Returns
    -------
    OptimizeResult
        ``method="quadratic"``; ``model`` holds the last accepted :class:`QuadraticFit`.
    """
    x, lo, hi = _box(x0, lower, upper)
    n = x.size

    def vec(v, name):
        a = np.broadcast_to(np.asarray(v, dtype=float), (n,)).copy()
        if np.any(a <= 0) or not np.all(np.isfinite(a)):
            raise ValueError(f"{name}: expected positive finite half-widths, got {v!r}")
        return a

    h = vec(step, "step")
    hmin = h.copy() if min_step is None else vec(min_step, "min_step")
    hmax = 2 * h if max_step is None else vec(max_step, "max_step")
    if np.any(hmin > h) or np.any(hmax < h):
        raise ValueError(f"step, min_step, max_step: expected min_step <= step <= max_step, got "
                         f"{min_step!r}, {step!r}, {max_step!r}")
    if not (tol_x > 0) or not (tol_noise >= 0):
        raise ValueError(f"tol_x, tol_noise: expected tol_x > 0 and tol_noise >= 0, "
                         f"got {tol_x!r}, {tol_noise!r}")
    if not (0 < trust <= max_trust):
        raise ValueError(f"trust, max_trust: expected 0 < trust <= max_trust, got {trust!r}, {max_trust!r}")
    max_generations = _positive_int(max_generations, "max_generations")
    S = design(n, kind)
    pinv_unit = np.linalg.pinv(_design_matrix(S))

    def sample(centre: np.ndarray, hh: np.ndarray) -> QuadraticFit:
        X = np.clip(centre + S * hh, lo, hi)
        f = tr(X)
        D = X - centre
        # nothing clipped: the scaled design is the unit one, whose pseudo-inverse is known
        pinv = pinv_unit if np.array_equal(D, S * hh) else None
        return fit_quadratic(D, f, hh, x=centre, pinv=pinv)

    def wanted(fit: QuadraticFit, d: np.ndarray) -> np.ndarray:
        """Half-widths over which the cost rises well above its roughness and that reach the
        next step."""
        diag = np.diag(fit.H)
        rough = np.where(diag > 0, 2.0 * np.sqrt(2.0 * fit.noise / np.where(diag > 0, diag, 1.0)), np.inf)
        return np.clip(np.maximum(rough, np.abs(d) / 2), hmin, hmax)

    tr = _Tracker(fun, max_evaluations, cancel)
    delta = float(trust)
    fit = sample(x, h)
    reason, final_x, final_f = "max_generations", None, None
    while True:
        pd = fit.positive_definite
        if pd:
            d = fit.newton_step()
            h_next = wanted(fit, d)
            small = np.all(np.abs(d) < tol_x) or 0.5 * d @ fit.H @ d < tol_noise * fit.noise
            if small and np.all(np.abs(h_next / fit.h - 1) < 0.3):
                reason = "tol_x"
                final_x = np.clip(fit.x + d, lo, hi)
                final_f = fit.predict(final_x - fit.x)
                break
            u = np.max(np.abs(d / fit.h))
            if u > delta:
                d = d * (delta / u)
        else:  # saddle or flat: go to the best sampled point with a wider design
            k = int(np.argmin(fit.values))
            d = (S[k] * fit.h) if k else np.zeros(n)
            h_next = np.minimum(fit.h * (1.0 if k else 1.5), hmax)
        if tr.gens >= max_generations:
            break
        stop = tr.out_of_budget()
        if stop:
            reason = stop
            break
        if not np.any(d) and np.array_equal(h_next, fit.h):
            reason = "stalled"  # flat everywhere within the widest design
            break
        new = sample(np.clip(fit.x + d, lo, hi), h_next)
        if new.c0 <= fit.c0 + max(fit.noise, new.noise):
            if pd and np.max(np.abs(d / fit.h)) >= delta * (1 - 1e-9):
                delta = min(2 * delta, max_trust)
            fit = new
        else:
            delta = 0.5 * delta
            if delta * np.max(fit.h) < tol_x:
                reason = "stalled"
                break
    if final_x is None:
        final_x = np.array(fit.x)
        final_f = float(fit.values[0])
        if tr.best_f < final_f:
            final_x, final_f = np.array(tr.best_x), float(tr.best_f)
    res = tr.result(reason, "quadratic")
    return OptimizeResult(final_x, float(final_f), res.evaluations, res.generations, res.time_s,
                          res.converged, reason, "quadratic", fit)
