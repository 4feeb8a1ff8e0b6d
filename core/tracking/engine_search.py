"""Levenberg–Marquardt search of the Gauss–Newton engine (:mod:`core.tracking.engine`).

:class:`LevenbergMarquardt` is the search as a state machine — :meth:`~LevenbergMarquardt.ask`
gives the next centre whose 13-pose step is needed, :meth:`~LevenbergMarquardt.tell` takes that
step's :class:`~core.tracking.engine.GaussNewtonStep` — so that the searches of several bones
advance in lockstep, their steps rendered and scored together with one synchronisation per
iteration (:mod:`core.tracking.joint`). :func:`gauss_newton_search` runs one search alone; both
give the same iterates. :func:`moments_to_newton` turns a step's moment matrices into the
cost's gradient and Gauss–Newton Hessian.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .engine_kernels import N_POSES as _N
from .optimize import OptimizeResult
from .quadratic import QuadraticFit

__all__ = ["GaussNewtonFit", "GaussNewtonStep", "LevenbergMarquardt", "gauss_newton_search",
           "moments_to_newton", "step_design"]


@dataclass(frozen=True, eq=False)
class GaussNewtonStep:
    """One step's evaluation at ``x`` with half-steps ``h``: ``costs (13,)`` of the design poses
    (:func:`core.tracking.engine.step_design`, row 0 = x), ``view_scores (13, n_views)``, the
    Gauss–Newton gradient ``g`` and Hessian ``H`` of the cost at ``x`` (x units) and the per-view
    correlations ``r`` over the centre's domain."""

    x: np.ndarray
    h: np.ndarray
    costs: np.ndarray
    view_scores: np.ndarray
    g: np.ndarray
    H: np.ndarray
    r: np.ndarray

    @property
    def cost(self) -> float:
        return float(self.costs[0])


def step_design(x, h) -> np.ndarray:
    """``(13, 6)`` poses of a step: ``x``, then ``x + h_k e_k``, ``x - h_k e_k`` for k = 1…6."""
    x = np.asarray(x, dtype=float)
    h = np.asarray(h, dtype=float)
    X = np.repeat(x[None], _N, axis=0)
    for k in range(6):
        X[1 + 2 * k, k] += h[k]
        X[2 + 2 * k, k] -= h[k]
    return X


def moments_to_newton(M, h, weights=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(r (n_views,), g (6,), H (6, 6))`` from the moment matrices ``M (n_views, 9, 9)`` of
    :func:`~core.tracking.engine_kernels.moments_kernel` and the half-steps ``h (6,)``: each
    view's correlation, and the gradient and Gauss–Newton Hessian of the cost
    ``Σ_v w_v (1 - r_v)`` (``weights`` default equal, normalised) in x units (see the module
    docs of :mod:`core.tracking.engine`). A view without contrast in Ω
    contributes r = 0 and nothing to g and H."""
    M = np.asarray(M, dtype=np.float64).reshape(-1, 9, 9)
    h = np.asarray(h, dtype=float)
    nv = len(M)
    w = np.full(nv, 1.0 / nv) if weights is None else np.asarray(weights, float) / np.sum(weights)
    r_out = np.zeros(nv)
    g = np.zeros(6)
    H = np.zeros((6, 6))
    scale = np.r_[1.0, 1.0, 1.0, 1.0 / (2 * h)]  # z -> (1, a, b, D_1..D_6)
    for v in range(nv):
        S = M[v]
        n = S[0, 0]
        if n < 2:
            continue
        m = S[0] / n
        C = (S - n * np.outer(m, m)) * np.outer(scale, scale)  # centred sums of (., a, b, D)
        caa, cbb, cab = C[1, 1], C[2, 2], C[1, 2]
        if caa <= 0 or cbb <= 0:
            continue
        r = cab / math.sqrt(caa * cbb)
        cad, cbd, cdd = C[1, 3:], C[2, 3:], C[3:, 3:]
        dr = cad / math.sqrt(caa * cbb) - r * cbd / cbb
        jtj = (cdd - np.outer(cbd, cbd) / cbb) / cbb
        r_out[v] = r
        g -= w[v] * dr
        H += w[v] * max(r, 0.05) * jtj
    return r_out, g, 0.5 * (H + H.T)


_TRACE: list | None = None


class LevenbergMarquardt:
    """The state of one Levenberg–Marquardt search (arguments as :func:`gauss_newton_search`)."""

    def __init__(self, x0, *, step, lower, upper, tol_x: float = 0.02, tol_noise: float = 0.1,
                 max_generations: int = 8, trust=None, lam: float = 1e-3) -> None:
        self.t_start = time.perf_counter()
        self.lo = np.asarray(lower, dtype=float)
        self.hi = np.asarray(upper, dtype=float)
        self.h = np.broadcast_to(np.asarray(step, dtype=float), (6,)).copy()
        tr = 8.0 * self.h if trust is None else np.broadcast_to(np.asarray(trust, dtype=float), (6,))
        self.tr = np.array(tr, dtype=float)
        if np.any(self.h <= 0) or np.any(self.tr <= 0):
            raise ValueError(f"step, trust: expected positive (mm, degrees) values, got {step!r}, {trust!r}")
        self.x0 = np.asarray(x0, dtype=float)
        # keep the design inside the box
        self.x = np.clip(self.x0, self.lo + self.h, self.hi - self.h)
        self.tol_x, self.tol_noise = float(tol_x), float(tol_noise)
        self.max_generations = int(max_generations)
        self.best = None  # the accepted step
        self.evals = self.gens = 0
        self.reason = "max_generations"
        self.final_x = None
        self.lam = float(lam)
        self.noise = 0.0
        self.alpha = 1.0  # true curvature / Gauss-Newton curvature along the steps (secant estimate)
        self.done = False

    def _solve(self, s, lam_: float) -> np.ndarray:
        Hs = self.alpha * s.H
        D = np.diag(np.maximum(np.diag(Hs), 1e-12))
        try:
            d = np.linalg.solve(Hs + lam_ * D, -s.g)
        except np.linalg.LinAlgError:
            d = -s.g / np.diag(D)
        u = np.max(np.abs(d) / self.tr)
        return d / u if u > 1 else d

    def ask(self, cancel: Callable[[], bool] | None = None) -> np.ndarray | None:
        """The centre of the next 13-pose step (half-steps :attr:`h`), or None when the search
        has ended."""
        if self.done:
            return None
        if cancel is not None and cancel():
            self.reason, self.done = "cancelled", True
            return None
        if self.gens >= self.max_generations:
            self.done = True
            return None
        return self.x

    def tell(self, s) -> None:
        """Take the step evaluated at the centre :meth:`ask` gave."""
        lo, hi, h = self.lo, self.hi, self.h
        self.evals += _N
        self.gens += 1
        if _TRACE is not None:
            _TRACE.append(("eval", s.x.copy(), s.cost))
        best = self.best
        if best is not None and not s.cost <= best.cost + max(self.noise, 1e-7):
            # worse: a shorter, more gradient-like step from the accepted centre
            self.lam = max(10.0 * self.lam, 0.5)
            if self.lam > 1e4:
                self.reason, self.done = "stalled", True
                return
            d = self._solve(best, self.lam)
            self.x = np.clip(best.x + d, lo + h, hi - h)
            return
        if best is not None:  # secant: the gradient's change along the step against the model's
            dx = s.x - best.x
            den = float(dx @ best.H @ dx)
            num = float((s.g - best.g) @ dx)
            if den > 0 and num > 0 and np.all(np.abs(dx) <= 4 * h):  # a short step: near quadratic
                self.alpha = float(np.clip(num / den, 0.5, 1.5))
        self.best = s
        self.noise = _roughness(s, self.alpha)
        self.lam = max(self.lam / 10.0, 1e-7)
        d = self._solve(s, self.lam)
        if _TRACE is not None:
            _TRACE.append((s.x.copy(), s.cost, self.noise, d.copy(), self.alpha))
        if np.all(np.abs(d) < self.tol_x) or 0.5 * self.alpha * d @ s.H @ d < self.tol_noise * self.noise:
            self.reason, self.done = "tol_x", True
            self.final_x = np.clip(s.x + d, lo, hi)
            return
        self.x = np.clip(s.x + d, lo + h, hi - h)

    def result(self) -> OptimizeResult:
        """The outcome once :meth:`ask` has returned None."""
        t = time.perf_counter() - self.t_start
        if self.best is None:
            return OptimizeResult(self.x0.copy(), float("inf"), self.evals, self.gens, t, False, self.reason,
                                  "gauss_newton", None)
        final_x = self.best.x if self.final_x is None else self.final_x
        fit = _fit(self.best, self.noise, self.alpha)
        fun = fit.predict(final_x - self.best.x)
        return OptimizeResult(final_x, float(fun), self.evals, self.gens, t, self.reason == "tol_x",
                              self.reason, "gauss_newton", fit)


def gauss_newton_search(cost, x0, *, step, lower, upper, tol_x: float = 0.02,
                        tol_noise: float = 0.1, max_generations: int = 8, trust=None, lam: float = 1e-3,
                        cancel: Callable[[], bool] | None = None) -> OptimizeResult:
    """Levenberg–Marquardt search of ``cost`` (a :class:`~core.tracking.engine.GaussNewtonCost`)
    from ``x0`` inside ``[lower, upper]`` (module docs of :mod:`core.tracking.engine`).

    ``step``: the central-difference half-steps ``h`` (6,) (x units); ``trust`` (6,): the largest
    move per step (default ``8 h``); ``tol_x``: converged when every coordinate of the step from
    an accepted centre is below it, or ``tol_noise``: when the step's predicted decrease
    ``½ dᵀHd`` is below ``tol_noise`` × the cost's roughness (a move the data cannot confirm, as
    in :func:`~core.tracking.quadratic.quadratic_search`); ``max_generations``: launches of 13
    poses. The Gauss–Newton curvature is rescaled along the way by a secant estimate (the
    gradient's change along an accepted step of at most ``4 h`` over the model's, within
    [0.5, 1.5]); a rejected step raises λ to at least 0.5 (about half the Newton step). ``model`` of
    the result is a :class:`~core.tracking.quadratic.QuadraticFit` with the last accepted step's
    rescaled Hessian and the cost's roughness (6 residual degrees of freedom).
    """
    lm = LevenbergMarquardt(x0, step=step, lower=lower, upper=upper, tol_x=tol_x, tol_noise=tol_noise,
                            max_generations=max_generations, trust=trust, lam=lam)
    while (x := lm.ask(cancel)) is not None:
        lm.tell(cost.step(x, lm.h))
    return lm.result()


def _residuals(s: GaussNewtonStep, alpha: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares ``(c0, g)`` of the 13 costs with the Hessian fixed (``alpha H``), and the
    residuals. The design's columns (1, ±h_k at rows 2k+1, 2k+2) are orthogonal: the fit is
    the mean and the central differences, in closed form."""
    h = np.asarray(s.h, dtype=float)
    q = np.zeros(_N)
    q[1:] = np.repeat(0.5 * alpha * h * h * np.diag(s.H), 2)
    y = np.asarray(s.costs, dtype=float) - q
    c0 = y.mean()
    g = (y[1::2] - y[2::2]) / (2.0 * h)
    fitted = np.full(_N, c0)
    fitted[1::2] += h * g
    fitted[2::2] -= h * g
    return np.r_[c0, g], y - fitted


def _roughness(s: GaussNewtonStep, alpha: float = 1.0) -> float:
    """RMS residual (6 degrees of freedom) of the 13 costs about the quadratic with the
    Gauss–Newton Hessian: the cost's roughness at the scale of the step."""
    _, res = _residuals(s, alpha)
    return float(np.sqrt(res @ res / 6.0))


@dataclass(frozen=True, eq=False)
class GaussNewtonFit(QuadraticFit):
    """The :class:`~core.tracking.quadratic.QuadraticFit` of a search's last accepted step, with
    the per-view similarities at its centre (``view_scores (n_views,)``)."""

    view_scores: np.ndarray | None = None


def _fit(s: GaussNewtonStep, noise: float, alpha: float = 1.0) -> GaussNewtonFit:
    coef, _ = _residuals(s, alpha)
    return GaussNewtonFit(np.array(s.x), np.array(s.h), float(coef[0]), np.array(s.g), alpha * np.array(s.H),
                          float(noise), 6, np.array(s.costs), np.array(s.view_scores[0]))
