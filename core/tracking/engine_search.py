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
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from numpy.linalg import _umath_linalg

try:  # (numpy 2: ndarray.clip's ufunc for float bounds, without its dispatch; np.linalg.solve's error call)
    from numpy._core.umath import clip as _clip
    from numpy.linalg._linalg import _raise_linalgerror_singular as _raise_singular
except ImportError:  # (numpy 1.26)
    from numpy.core.umath import clip as _clip
    from numpy.linalg.linalg import _raise_linalgerror_singular as _raise_singular

from .engine_kernels import N_POSES as _N
from .optimize import OptimizeResult
from .quadratic import QuadraticFit

__all__ = ["GRADIENTS", "GaussNewtonFit", "GaussNewtonStep", "LevenbergMarquardt", "gauss_newton_search",
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


_DESIGN = np.zeros((_N, 6))  # the unit design: 0, +e_k, -e_k
for _k in range(6):
    _DESIGN[1 + 2 * _k, _k], _DESIGN[2 + 2 * _k, _k] = 1.0, -1.0


_OFFSETS: dict = {}  # h -> the design's offsets _DESIGN * h (step_design)


def step_design(x, h) -> np.ndarray:
    """``(13, 6)`` poses of a step: ``x``, then ``x + h_k e_k``, ``x - h_k e_k`` for k = 1…6."""
    h = np.asarray(h, dtype=float)
    key = h.tobytes()
    dh = _OFFSETS.get(key)
    if dh is None:  # (a search's half-steps: the same from step to step)
        if len(_OFFSETS) >= 64:
            _OFFSETS.clear()
        dh = _OFFSETS[key] = _DESIGN * h
    return np.asarray(x, dtype=float) + dh  # x ± h_k exactly, x + 0 = x


_SCALES: dict = {}  # h -> the outer product of the moments' scales (moments_to_newton)


def _scale2(h: np.ndarray, nv: int = 0) -> np.ndarray:
    """The outer product ``(9, 9)`` of the moments' scales of half-steps ``h``; with ``nv``, repeated
    ``(nv, 9, 9)`` (contiguous: a product with it one plain loop, not a broadcast)."""
    key = (h.tobytes(), nv)
    s2 = _SCALES.get(key)
    if s2 is None:
        sc = np.concatenate([np.ones(3), 1.0 / (2 * h)])  # z -> (1, a, b, D_1..D_6)
        if len(_SCALES) >= 64:
            _SCALES.clear()
        s2 = np.outer(sc, sc)
        s2 = _SCALES[key] = np.ascontiguousarray(np.broadcast_to(s2, (nv, 9, 9))) if nv else s2
    return s2


def moments_to_newton(M, h, weights=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(r (n_views,), g (6,), H (6, 6))`` from the moment matrices ``M (n_views, 9, 9)`` of
    :func:`~core.tracking.engine_kernels.moments_kernel` and the half-steps ``h (6,)``: each
    view's correlation, and the gradient and Gauss–Newton Hessian of the cost
    ``Σ_v w_v (1 - r_v)`` (``weights`` default equal, normalised) in x units (see the module
    docs of :mod:`core.tracking.engine`). A view without contrast in Ω
    contributes r = 0 and nothing to g and H. (The views' centred sums in one pass; the same
    arithmetic, element by element, as one view at a time. Where every view has contrast and the
    weights are equal — every step of a tracked bone — :class:`_Work`: the same values with
    fewer array operations on the step's critical path.)"""
    M = np.asarray(M, dtype=np.float64).reshape(-1, 9, 9)
    h = np.asarray(h, dtype=float)
    if weights is None and all(a >= 2 for a in M[:, 0, 0].tolist()):  # (on Python floats: the same tests)
        got = _work(len(M)).newton(M, h)
        if got is not None:
            return got
    return _moments_general(M, h, weights)


class _Work:
    """:func:`moments_to_newton`'s arrays for ``nv`` views where every view has at least 2 pixels and
    the weights are equal: the moments copied in, the centred sums, each view's terms and the views
    of them the arithmetic reads, made once (a thread's own: :func:`_work`), so that a step's algebra
    is ~20 ufunc calls into them. The operations of :func:`_moments_general`'s expressions, element
    by element in the same order (``n (m_i m_j)``, ``(C_1k / √(caa cbb)) - (r C_2k) / cbb``,
    ``(C_kl - (C_2k C_2l) / cbb) / cbb``); each view's correlation from Python floats (``sqrt``,
    ``*`` and ``/`` correctly rounded as numpy's); the sums over the views as reductions along the
    first axis from 0 — ``g = 0 - w dr_0 - w dr_1 …``, ``H = 0 + c_0 J_0 + c_1 J_1 …``, the loop's
    order: the same values to the bit."""

    def __init__(self, nv: int) -> None:
        self.w = 1.0 / nv
        self.M = M = np.zeros((nv, 9, 9))
        self.n1 = M[:, 0, 0, None]  # (nv, 1)
        self.n2 = M[:, 0, 0, None, None]  # (nv, 1, 1)
        self.M0 = M[:, 0]
        self.m = m = np.zeros((nv, 9))
        self.mi, self.mj = m[:, :, None], m[:, None, :]
        self.C = C = np.zeros((nv, 9, 9))
        self.cab = C[:, 1:3, 1:3]
        self.C1, self.C2 = C[:, 1, 3:], C[:, 2, 3:]
        self.C2k, self.C2l = C[:, 2, 3:, None], C[:, 2, None, 3:]
        self.C33 = C[:, 3:, 3:]
        self.K = K = np.zeros((nv, 4, 1))  # per view: sqrt(caa cbb), r, cbb, its weight in H
        self.Kf = K.reshape(-1)
        self.sq, self.r, self.cb = K[:, 0], K[:, 1], K[:, 2]
        self.cb3, self.c3 = K[:, 2:3], K[:, 3:4]  # (nv, 1, 1)
        self.t = np.zeros((nv, 6))
        self.dr = np.zeros((nv, 6))
        self.J = np.zeros((nv, 6, 6))

    def newton(self, M: np.ndarray, h: np.ndarray):
        """(r, g, H) of the moments ``M`` (n_views, 9, 9), or None where a view has no contrast."""
        self.M[...] = M
        m, C, J, dr, t = self.m, self.C, self.J, self.dr, self.t
        np.divide(self.M0, self.n1, out=m)
        np.multiply(self.mi, self.mj, out=C)
        np.multiply(self.n2, C, out=C)
        np.subtract(self.M, C, out=C)
        np.multiply(C, _scale2(h, len(C)), out=C)  # centred sums of (., a, b, D): S - n m mᵀ, scaled
        w = self.w
        rows = []
        rl = []
        for (caa, cab), (_, cbb) in self.cab.tolist():
            if not (caa > 0 and cbb > 0):
                return None
            sq = math.sqrt(caa * cbb)
            r = cab / sq
            rl.append(r)
            rows += (sq, r, cbb, w * max(r, 0.05))
        self.Kf[:] = rows
        np.divide(self.C1, self.sq, out=dr)
        np.multiply(self.r, self.C2, out=t)
        np.divide(t, self.cb, out=t)
        np.subtract(dr, t, out=dr)
        np.multiply(self.C2k, self.C2l, out=J)
        np.divide(J, self.cb3, out=J)
        np.subtract(self.C33, J, out=J)
        np.divide(J, self.cb3, out=J)
        np.multiply(dr, w, out=dr)
        np.multiply(J, self.c3, out=J)
        g = np.subtract.reduce(dr, axis=0, initial=0.0)
        H = np.add.reduce(J, axis=0, initial=0.0)
        return np.array(rl), g, 0.5 * (H + H.T)


_WORK = threading.local()


def _work(nv: int) -> _Work:
    """This thread's :class:`_Work` for ``nv`` views."""
    got = getattr(_WORK, "by_nv", None)
    if got is None:
        got = _WORK.by_nv = {}
    w = got.get(nv)
    if w is None:
        w = got[nv] = _Work(nv)
    return w


def _moments_general(M, h, weights) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`moments_to_newton` of any moments and weights (views without contrast left out)."""
    nv = len(M)
    w = [1.0 / nv] * nv if weights is None else list(np.asarray(weights, float) / np.sum(weights))
    n = M[:, 0, 0]
    every = all(a >= 2 for a in n.tolist())  # (the checks on Python floats: the same comparisons)
    ok = None if every else n >= 2
    m = M[:, 0] / (n if every else np.where(ok, n, 1.0))[:, None]
    # centred sums of (., a, b, D): S - n m mᵀ, scaled
    C = (M - n[:, None, None] * (m[:, :, None] * m[:, None, :])) * _scale2(h)
    caa, cbb, cab = C[:, 1, 1], C[:, 2, 2], C[:, 1, 2]
    if every:
        every = all(a > 0 and b > 0 for a, b in zip(caa.tolist(), cbb.tolist(), strict=True))
    if not every:
        ok = (n >= 2) & (caa > 0) & (cbb > 0)
    if every:  # every view has contrast: nothing to leave out
        cb = cbb
        sq = np.sqrt(caa * cbb)
    elif not ok.any():
        return np.zeros(nv), np.zeros(6), np.zeros((6, 6))
    else:
        every = False
        cb = np.where(ok, cbb, 1.0)  # the views without contrast are left out below
        sq = np.sqrt(np.where(ok, caa, 1.0) * cb)
    r = cab / sq
    cbd = C[:, 2, 3:]
    dr = C[:, 1, 3:] / sq[:, None] - r[:, None] * cbd / cb[:, None]
    cb3 = cb[:, None, None]
    jtj = (C[:, 3:, 3:] - cbd[:, :, None] * cbd[:, None, :] / cb3) / cb3
    g = np.zeros(6)
    H = np.zeros((6, 6))
    rl = r.tolist()
    if every:
        r_out = r
        for v in range(nv):
            g -= w[v] * dr[v]
            H += w[v] * max(rl[v], 0.05) * jtj[v]
    else:
        r_out = np.zeros(nv)
        for v in range(nv):
            if ok[v]:
                rv = rl[v]
                r_out[v] = rv
                g -= w[v] * dr[v]
                H += w[v] * max(rv, 0.05) * jtj[v]
    return r_out, g, 0.5 * (H + H.T)


_TRACE: list | None = None

#: Where a search takes the cost's gradient from (``gradient`` of :func:`gauss_newton_search`).
GRADIENTS = ("moments", "corrected")


class LevenbergMarquardt:
    """The state of one Levenberg–Marquardt search (arguments as :func:`gauss_newton_search`)."""

    def __init__(self, x0, *, step, lower, upper, tol_x: float = 0.02, tol_noise: float = 0.1,
                 max_generations: int = 8, trust=None, lam: float = 1e-3, gradient: str = "moments") -> None:
        if gradient not in GRADIENTS:
            raise ValueError(f"gradient: expected one of {GRADIENTS}, got {gradient!r}")
        self.gradient = gradient
        # gradient="corrected": the scores' gradient less the moments' and its variance, summed over steps
        corrected = gradient == "corrected"
        self._dsum, self._dvar, self._dn = (np.zeros(6), np.zeros(6), 0) if corrected else (0, 0, 0)
        self.t_start = time.perf_counter()
        self.lo = np.asarray(lower, dtype=float)
        self.hi = np.asarray(upper, dtype=float)
        self.h = _six(step)
        self.tr = 8.0 * self.h if trust is None else _six(trust)
        # (every value above 0, as min() > 0: a NaN fails)
        if not (all(v > 0 for v in self.h.tolist()) and all(v > 0 for v in self.tr.tolist())):
            raise ValueError(f"step, trust: expected positive (mm, degrees) values, got {step!r}, {trust!r}")
        self.x0 = np.asarray(x0, dtype=float)
        # keep the design inside the box
        self._lo_in, self._hi_in = self.lo + self.h, self.hi - self.h
        self.x = _clip(self.x0, self._lo_in, self._hi_in)
        self.tol_x, self.tol_noise = float(tol_x), float(tol_noise)
        self.max_generations = int(max_generations)
        self.best = None  # the accepted step
        self._best_g = None  # its moments' gradient (without the correction)
        self._coef = None  # the accepted step's fitted (c0, g) with its roughness (_residuals)
        self.evals = self.gens = 0
        self.reason = "max_generations"
        self.final_x = None
        self.lam = float(lam)
        self.noise = 0.0
        self.alpha = 1.0  # true curvature / Gauss-Newton curvature along the steps (secant estimate)
        self.done = False

    def _solve(self, s, lam_: float) -> np.ndarray:
        A = np.multiply(self.alpha, s.H, order="C")
        # (αH + λ diag(max(diag αH, 1e-12))): the damping on the diagonal alone (a strided view of it),
        # its six values in Python floats (max as np.maximum's, a NaN kept; a + λ·m as the in-place add)
        dg = [max(a, 1e-12) for a in A.diagonal().tolist()]
        A.reshape(36)[::7] = [a + lam_ * m for a, m in zip(A.diagonal().tolist(), dg, strict=True)]
        try:
            d = _solve6(A, -s.g)
        except np.linalg.LinAlgError:
            d = -s.g / np.array(dg)
        # the largest |d_k| / trust_k (np.maximum.reduce's: NaN where any is, and then no shortening)
        q = [abs(a) / t for a, t in zip(d.tolist(), self.tr.tolist(), strict=True)]
        u = max(q)
        return d / u if u > 1 and all(v == v for v in q) else d

    def _correction(self, s) -> np.ndarray:
        """``gradient="corrected"``: the mean over the steps so far of the scores' central differences
        less the moments' gradient, shrunk toward 0 by its noise (positive-part James–Stein,
        ``max(0, 1 - var / mean²)``) along each eigenvector of the step's Gauss–Newton Hessian.
        One step's differences have the variance ``σ_c² / 2h_k²``, σ_c the step's roughness about
        its quadratic (:func:`_residuals`), independent between coordinates (their poses differ);
        the roughness is the cost's own at nearby poses, not independent from step to step, so
        ``var`` is the steps' mean variance, not divided by their number (divided, the tibia's
        rotation about its long axis on the acceptance trial at 256² was 0.57° RMS against 0.42°,
        moments 0.36°, over 10 registrations; the talus 0.60° against 0.61°, moments 0.74°).

        Shrunk along the eigenvectors, not the coordinates: the correction moves the pose by
        ``(αH)⁻¹`` times it, most along H's weakest direction, so that is where its noise must be
        judged. Shrunk by coordinates, the tibia's correction on the acceptance trial at 256²
        (tracked every second frame, this 2-core CPU machine) was significant in rx and y, but its
        part along the weakest direction (rotation about the long axis, an eigenvalue ~25× below
        the next) was 0.0002-0.0007 per degree against a noise of 0.0013-0.0044, and it moved the
        Newton step from the truth 0.2-0.3° further along that direction in frames 10-16 than the
        moments' did; the velocity guess carried it on (up to 1.44° off, moments 0.82°). Shrunk
        along the eigenvectors: 0.43° RMS over the 10 frames against 0.76° (moments 0.40°), the
        talus 0.553° against 0.567° (moments 0.739°)."""
        h = s.h
        self._dsum += (s.costs[1::2] - s.costs[2::2]) / (2.0 * h) - s.g
        _, res = _residuals(s, self.alpha)
        self._dvar += float(res @ res) / 6.0 / (2.0 * h * h)
        self._dn += 1
        mean = self._dsum / self._dn
        var = self._dvar / self._dn
        try:
            _, U = np.linalg.eigh(s.H)
        except np.linalg.LinAlgError:
            U = np.eye(6)
        m = U.T @ mean
        v = (U * U).T @ var  # the variance of each eigenvector's part (independent coordinates)
        return U @ (m * np.maximum(0.0, 1.0 - v / np.maximum(m * m, 1e-300)))

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
        h = self.h
        self.evals += _N
        self.gens += 1
        g_moments = s.g
        if self.gradient == "corrected":
            s = replace(s, g=s.g + self._correction(s))
        if _TRACE is not None:
            _TRACE.append(("eval", s.x.copy(), s.cost))
        best = self.best
        cost = s.cost
        if best is not None and not cost <= best.cost + max(self.noise, 1e-7):
            # worse: a shorter, more gradient-like step from the accepted centre
            self.lam = max(10.0 * self.lam, 0.5)
            if self.lam > 1e4:
                self.reason, self.done = "stalled", True
                return
            d = self._solve(best, self.lam)
            self.x = _clip(best.x + d, self._lo_in, self._hi_in)
            return
        if best is not None:  # secant: the gradient's change along the step against the model's
            # (the moments' gradients: the correction held fixed, its own change is no curvature)
            dx = s.x - best.x
            den = float(dx @ best.H @ dx)
            num = float((g_moments - self._best_g) @ dx)
            short = zip(dx.tolist(), h.tolist(), strict=True)
            if den > 0 and num > 0 and all(abs(a) <= 4 * b for a, b in short):
                self.alpha = float(min(max(num / den, 0.5), 1.5))  # (a short step: near quadratic)
        self.best, self._best_g = s, g_moments
        self._coef, res = _residuals(s, self.alpha)
        self.noise = math.sqrt(float(res @ res) / 6.0)  # (np.sqrt's value: both correctly rounded)
        self.lam = max(self.lam / 10.0, 1e-7)
        d = self._solve(s, self.lam)
        if _TRACE is not None:
            _TRACE.append((s.x.copy(), s.cost, self.noise, d.copy(), self.alpha))
        tol = self.tol_x
        if (all(abs(v) < tol for v in d.tolist())
                or 0.5 * self.alpha * d @ s.H @ d < self.tol_noise * self.noise):
            self.reason, self.done = "tol_x", True
            self.final_x = _clip(s.x + d, self.lo, self.hi)
            return
        self.x = _clip(s.x + d, self._lo_in, self._hi_in)

    def result(self) -> OptimizeResult:
        """The outcome once :meth:`ask` has returned None."""
        t = time.perf_counter() - self.t_start
        if self.best is None:
            return OptimizeResult(self.x0.copy(), float("inf"), self.evals, self.gens, t, False, self.reason,
                                  "gauss_newton", None)
        final_x = self.best.x if self.final_x is None else self.final_x
        fit = _fit(self.best, self.noise, self.alpha, self._coef)
        fun = fit.predict(final_x - self.best.x)
        return OptimizeResult(final_x, float(fun), self.evals, self.gens, t, self.reason == "tol_x",
                              self.reason, "gauss_newton", fit)


def _six(v) -> np.ndarray:
    """``v`` as a new (6,) float array (a scalar repeated): ``np.array(np.broadcast_to(v, (6,)))``."""
    a = np.asarray(v, dtype=float)
    return a.copy() if a.shape == (6,) else np.array(np.broadcast_to(a, (6,)))


def _solve6(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.linalg.solve(A, b)`` of a float64 ``(6, 6)`` matrix and ``(6,)`` vector: its LAPACK gufunc
    under its error state (a singular matrix raises LinAlgError), without its argument checks and
    conversions — the same call, the same values."""
    with np.errstate(call=_raise_singular, invalid="call", over="ignore", divide="ignore", under="ignore"):
        return _umath_linalg.solve1(A, b, signature="dd->d")


def gauss_newton_search(cost, x0, *, step, lower, upper, tol_x: float = 0.02,
                        tol_noise: float = 0.1, max_generations: int = 8, trust=None, lam: float = 1e-3,
                        cancel: Callable[[], bool] | None = None,
                        gradient: str = "moments", idle: Callable[[], None] | None = None) -> OptimizeResult:
    """Levenberg–Marquardt search of ``cost`` (a :class:`~core.tracking.engine.GaussNewtonCost`)
    from ``x0`` inside ``[lower, upper]`` (module docs of :mod:`core.tracking.engine`).

    ``step``: the central-difference half-steps ``h`` (6,) (x units); ``trust`` (6,): the largest
    move per step (default ``8 h``); ``tol_x``: converged when every coordinate of the step from
    an accepted centre is below it, or ``tol_noise``: when the step's predicted decrease
    ``½ dᵀHd`` is below ``tol_noise`` × the cost's roughness (a move the data cannot confirm, as
    in :func:`~core.tracking.quadratic.quadratic_search`); ``max_generations``: launches of 13
    poses. The Gauss–Newton curvature is rescaled along the way by a secant estimate (the
    moments' gradient's change along an accepted step of at most ``4 h`` over the model's, within
    [0.5, 1.5]); a rejected step raises λ to at least 0.5 (about half the Newton step). ``model`` of
    the result is a :class:`~core.tracking.quadratic.QuadraticFit` with the last accepted step's
    rescaled Hessian and the cost's roughness (6 residual degrees of freedom).

    ``gradient``: ``"moments"`` (default) the step's gradient from its moments, over the centre
    DRR's domain Ω held fixed; ``"corrected"`` that plus the mean, over the search's steps so far,
    of the 13 scores' central differences ``(c(x + h_k e_k) - c(x - h_k e_k)) / 2h_k`` less the
    moments' gradient — the share of the gradient from Ω's change with the pose, which each pose's
    score has (its own Ω) and the moments miss; large on coarse pixels
    (:func:`~core.tracking.register_options.newton_step`), where the search then stops at the
    scores' minimum rather than the fixed domain's. Averaged because a single step's differences
    are as rough as the cost; the difference changes slowly with the pose. Shrunk by its noise
    along the Hessian's eigenvectors (:meth:`LevenbergMarquardt._correction`); held fixed in the
    secant estimate (the correction's change between steps is its estimate's, not curvature).

    ``idle``: a callable run once, while the device works on the first step (``cost.step``'s
    ``idle``; after the search where it took no step): host work of the caller's that needs nothing
    of the search (:func:`core.tracking.register.register`'s). The same iterates.
    """
    lm = LevenbergMarquardt(x0, step=step, lower=lower, upper=upper, tol_x=tol_x, tol_noise=tol_noise,
                            max_generations=max_generations, trust=trust, lam=lam, gradient=gradient)
    while (x := lm.ask(cancel)) is not None:
        if idle is None:
            lm.tell(cost.step(x, lm.h))
        else:
            lm.tell(cost.step(x, lm.h, idle))
            idle = None
    if idle is not None:  # no step was taken (cancelled): run once all the same
        idle()
    return lm.result()


def _residuals(s: GaussNewtonStep, alpha: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares ``(c0, g)`` of the 13 costs with the Hessian fixed (``alpha H``), and the
    residuals. The design's columns (1, ±h_k at rows 2k+1, 2k+2) are orthogonal: the fit is
    the mean and the central differences, in closed form. (Element by element in Python floats,
    the operations of the arrays' expressions in their order; the mean numpy's sum of the 13.)"""
    hl = np.asarray(s.h, dtype=float).tolist()
    a = 0.5 * alpha
    y = np.asarray(s.costs, dtype=float).tolist()
    for k, (hk, dk) in enumerate(zip(hl, s.H.diagonal().tolist(), strict=True)):
        q = a * hk * hk * dk
        y[2 * k + 1] -= q
        y[2 * k + 2] -= q
    c0 = float(np.add.reduce(np.array(y))) / _N  # the mean
    coef = [c0]
    res = [y[0] - c0]
    for k, hk in enumerate(hl):
        yp, ym = y[2 * k + 1], y[2 * k + 2]
        gk = (yp - ym) / (2.0 * hk)
        hg = hk * gk
        coef.append(gk)
        res += (yp - (c0 + hg), ym - (c0 - hg))
    return np.array(coef), np.array(res)


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


def _fit(s: GaussNewtonStep, noise: float, alpha: float = 1.0, coef=None) -> GaussNewtonFit:
    if coef is None:
        coef, _ = _residuals(s, alpha)
    # (the step's own arrays, made for it and not written after, without copies; its half-steps are the
    # search's: copied)
    return GaussNewtonFit(s.x, np.array(s.h), float(coef[0]), s.g, alpha * s.H, float(noise), 6, s.costs,
                          np.array(s.view_scores[0]))
