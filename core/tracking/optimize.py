"""Population optimisers for registration: CMA-ES, PSO, a batched pattern search, Nelder–Mead, Powell.

Every optimiser minimises ``fun(X (B, n)) -> (B,)``, a function that scores a whole population in
one call (one DRR launch + one metric launch, :class:`core.tracking.cost.RegistrationCost`),
inside a box ``lower <= x <= upper``, and returns an :class:`OptimizeResult`. Stopping rules are
explicit and reported in ``reason``:

* ``"tol_x"`` — the search has contracted below ``tol_x`` in every coordinate (converged);
* ``"tol_fun"`` — the best value changed by less than ``tol_fun`` over ``stall`` generations
  (converged);
* ``"max_generations"`` / ``"max_evaluations"`` — the budget ran out (not converged);
* ``"cancelled"`` — ``cancel()`` returned True (not converged).

Algorithms
----------
* :func:`cmaes` — CMA-ES (Hansen 2016, the ``cma`` package) with ask/tell, so each generation is
  one batched call; bounds by the package's boundary handling.
* :func:`pso` — particle swarm with the settings of Autoscoper's tracker (:data:`AUTOSCOPER_PSO`:
  100 particles, c1 = c2 = 1.5, inertia 0.8 decaying ×0.9 per epoch, particles drawn uniformly in
  ``[start_min, start_max]`` per coordinate with the first at the initial guess, stall after 25
  epochs whose best improved by < 1e-4). Autoscoper updates particles one at a time; here the
  whole swarm moves synchronously per epoch, so an epoch is one batched call.
* :func:`pattern_search` — compass search: all 2n axis moves of the current step are evaluated in
  one call; the best improving move is taken, otherwise the step halves (Kolda, Lewis & Torczon
  2003). A GPU-friendly local refinement.
* :func:`core.tracking.quadratic.quadratic_search` — fitted quadratic models on a batched
  second-order design (a trust-region Newton method): the fast local search of tracking.
* :func:`nelder_mead`, :func:`powell` — scipy's serial methods (one point per call; slower on the
  GPU, kept for comparison and for Autoscoper-like set-ups: Autoscoper refines with a downhill
  simplex of initial offsets 0.1).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

__all__ = ["AUTOSCOPER_PSO", "OptimizeResult", "cmaes", "nelder_mead", "pattern_search", "powell", "pso"]


@dataclass(frozen=True)
class OptimizeResult:
    """Outcome of one optimiser run.

    Attributes
    ----------
    x : (n,) array
        Best point found.
    fun : float
        Its value.
    evaluations : int
        Points evaluated.
    generations : int
        Batched calls of ``fun``.
    time_s : float
        Wall time of the run (s).
    converged : bool
        True when a convergence rule (``tol_x``/``tol_fun``) stopped it.
    reason : str
        The stopping rule (see the module docs).
    method : str
    model : object, optional
        Method-specific final state: the last :class:`~core.tracking.quadratic.QuadraticFit` of
        :func:`~core.tracking.quadratic.quadratic_search` (None for the other methods).
    """

    x: np.ndarray
    fun: float
    evaluations: int
    generations: int
    time_s: float
    converged: bool
    reason: str
    method: str
    model: object = None

    def to_dict(self) -> dict:
        return {"x": self.x.tolist(), "fun": self.fun, "evaluations": self.evaluations,
                "generations": self.generations, "time_s": self.time_s,
                "converged": self.converged, "reason": self.reason, "method": self.method}


def _box(x0, lower, upper) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    x0 = np.asarray(x0, dtype=float).ravel()
    n = x0.size
    lo = np.broadcast_to(np.asarray(-np.inf if lower is None else lower, dtype=float), (n,)).copy()
    hi = np.broadcast_to(np.asarray(np.inf if upper is None else upper, dtype=float), (n,)).copy()
    if np.any(lo >= hi):
        raise ValueError(f"lower, upper: expected lower < upper in every coordinate, got {lo}, {hi}")
    if np.any(x0 < lo) or np.any(x0 > hi):
        raise ValueError(f"x0: {x0} lies outside the bounds [{lo}, {hi}]")
    return x0, lo, hi


def _positive_int(v, name: str) -> int:
    if isinstance(v, bool) or int(v) != v or v < 1:
        raise ValueError(f"{name}: expected a positive integer, got {v!r}")
    return int(v)


class _Tracker:
    """Best point, counts, budget and cancel checks shared by the optimisers."""

    def __init__(self, fun, max_evaluations, cancel):
        self.fun, self.cancel = fun, cancel
        self.max_evaluations = max_evaluations
        self.evals = self.gens = 0
        self.best_x, self.best_f = None, np.inf
        self.t0 = time.perf_counter()

    def __call__(self, X: np.ndarray) -> np.ndarray:
        f = np.asarray(self.fun(X), dtype=float).reshape(-1)
        if f.shape != (len(X),):
            raise ValueError(f"fun: expected {len(X)} values for {len(X)} points, got shape {f.shape}")
        f = np.where(np.isfinite(f), f, np.inf)
        self.evals += len(X)
        self.gens += 1
        i = int(np.argmin(f))
        if f[i] < self.best_f:
            self.best_f, self.best_x = float(f[i]), np.array(X[i], dtype=float)
        return f

    def out_of_budget(self) -> str | None:
        if self.cancel is not None and self.cancel():
            return "cancelled"
        if self.max_evaluations is not None and self.evals >= self.max_evaluations:
            return "max_evaluations"
        return None

    def result(self, reason: str, method: str) -> OptimizeResult:
        return OptimizeResult(np.array(self.best_x), float(self.best_f), self.evals, self.gens,
                              time.perf_counter() - self.t0, reason in ("tol_x", "tol_fun"), reason, method)


def cmaes(fun: Callable, x0, *, sigma0=1.0, lower=None, upper=None, popsize: int | None = None,
          max_generations: int = 100, max_evaluations: int | None = None, tol_x: float = 1e-3,
          tol_fun: float = 1e-7, stall: int = 10, seed: int = 0,
          cancel: Callable[[], bool] | None = None) -> OptimizeResult:
    """CMA-ES from ``x0`` with initial step ``sigma0`` (scalar or per coordinate).

    ``tol_x``: stop when ``σ · sqrt(max diag C)`` (the largest search step, in x units) falls
    below it; ``tol_fun``: stop when the best value improved by less than it over ``stall``
    generations. ``popsize`` defaults to CMA-ES's ``4 + 3 ln n`` (10 for n = 6).
    """
    import cma

    x0, lo, hi = _box(x0, lower, upper)
    n = x0.size
    sig = np.broadcast_to(np.asarray(sigma0, dtype=float), (n,))
    if np.any(sig <= 0) or not np.all(np.isfinite(sig)):
        raise ValueError(f"sigma0: expected positive steps, got {sigma0!r}")
    max_generations = _positive_int(max_generations, "max_generations")
    # the search's own generator, not numpy's global one (which ``cma`` would re-seed and draw from,
    # shared with every thread and the user's scripts): the same samples as cma's ``seed: seed + 1``
    # (``np.random.seed(s)`` then ``np.random.randn`` is ``RandomState(s).randn``); ``seed`` NaN: cma
    # leaves the global generator alone when ``randn`` is given.
    opts = {"seed": np.nan, "randn": np.random.RandomState(int(seed) + 1).randn,
            "verbose": -9, "CMA_stds": sig.tolist(),
            "bounds": [np.where(np.isfinite(lo), lo, None).tolist(),
                       np.where(np.isfinite(hi), hi, None).tolist()],
            "tolx": 0, "tolfun": 0, "tolfunhist": 0, "tolstagnation": 10**9, "maxfevals": np.inf,
            "maxiter": np.inf, "tolflatfitness": 10**9}
    if popsize is not None:
        opts["popsize"] = _positive_int(popsize, "popsize")
    opts["BoundaryHandler"] = _bound_transform()
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        es = cma.CMAEvolutionStrategy(x0, 1.0, opts)
    tr = _Tracker(fun, max_evaluations, cancel)
    tr(x0[None])
    history = [tr.best_f]
    reason = "max_generations"
    for _ in range(max_generations):
        r = tr.out_of_budget()
        if r:
            reason = r
            break
        X = np.asarray(es.ask(), dtype=float)
        f = tr(X)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            es.tell(list(X), np.minimum(f, 1e300).tolist())
        history.append(tr.best_f)
        step = es.sigma * float(np.sqrt(np.max(es.sm.variances)))
        if step < tol_x:
            reason = "tol_x"
            break
        if len(history) > stall and history[-stall - 1] - history[-1] < tol_fun:
            reason = "tol_fun"
            break
    else:
        r = tr.out_of_budget()
        reason = r or reason
    # the mean is often better than any sample late in the run
    m = np.clip(np.asarray(es.mean, dtype=float), lo, hi)
    tr(m[None])
    return tr.result(reason, "cmaes")


_BOUND_TRANSFORM = None


def _bound_transform():
    """``cma.BoundTransform`` (the package's default boundary handling) whose transformation returns a
    solution inside its identity domain ``[lb + al, ub - au]`` at once, as the package's returns it
    there after five tests of the solution and ten array operations (a quarter of :func:`cmaes`'s host
    time with a population of 24 in 6 dimensions): the same solutions, the same object. Made once."""
    global _BOUND_TRANSFORM
    if _BOUND_TRANSFORM is None:
        import cma
        from cma.transformations import BoxConstraintsLinQuadTransformation

        class _LinQuad(BoxConstraintsLinQuadTransformation):
            def initialize(self, length=None):
                super().initialize(length)
                self._identity = (self._lb + self._al, self._ub - self._au)

            def __call__(self, solution_genotype, copy=True):
                lo, hi = self._identity
                y = solution_genotype
                if (isinstance(y, np.ndarray) and y.dtype == np.float64 and y.shape == lo.shape
                        and ((y >= lo) & (y <= hi)).all()):
                    return y  # none of the package's five cases applies: y itself, unchanged
                return super().__call__(solution_genotype, copy)

            transform = __call__

        class _BoundTransform(cma.BoundTransform):
            def __init__(self, bounds=None):
                super().__init__(bounds)
                self.bounds_tf = _LinQuad(self.to_dim_times_two(bounds))

        _BOUND_TRANSFORM = _BoundTransform
    return _BOUND_TRANSFORM


#: Autoscoper's PSO settings (libautoscoper PSO.hpp / Tracker.cpp).
AUTOSCOPER_PSO = {"n_particles": 100, "c1": 1.5, "c2": 1.5, "omega": 0.8, "omega_decay": 0.9,
                  "start_min": -3.0, "start_max": 3.0, "max_stall": 25, "stall_tol": 1e-4}


def pso(fun: Callable, x0, *, lower=None, upper=None, n_particles: int = 100, c1: float = 1.5,
        c2: float = 1.5, omega: float = 0.8, omega_decay: float = 0.9, start_min=-3.0, start_max=3.0,
        max_generations: int = 1000, max_evaluations: int | None = None, max_stall: int = 25,
        stall_tol: float = 1e-4, seed: int = 0, cancel: Callable[[], bool] | None = None) -> OptimizeResult:
    """Particle swarm about ``x0`` (defaults: :data:`AUTOSCOPER_PSO`).

    Particles start at ``x0 + U(start_min, start_max)`` per coordinate (the first at ``x0``),
    clipped to the box, with zero velocity. Each epoch::

        v <- ω v + c1 r1 (p_best - x) + c2 r2 (g_best - x);   x <- clip(x + v);   ω <- ω · decay

    A stall counter grows when the best value improved by less than ``stall_tol`` in an epoch and
    resets when it improved by more than 10 × ``stall_tol`` (Autoscoper's rule); ``max_stall``
    stalled epochs stop the run (``"tol_fun"``).
    """
    x0, lo, hi = _box(x0, lower, upper)
    n = x0.size
    n_particles = _positive_int(n_particles, "n_particles")
    max_generations = _positive_int(max_generations, "max_generations")
    smin = np.broadcast_to(np.asarray(start_min, float), (n,))
    smax = np.broadcast_to(np.asarray(start_max, float), (n,))
    if np.any(smin > smax):
        raise ValueError("start_min, start_max: expected start_min <= start_max")
    g = np.random.default_rng(seed)
    X = np.clip(x0 + g.uniform(smin, smax, size=(n_particles, n)), lo, hi)
    X[0] = x0
    V = np.zeros_like(X)
    tr = _Tracker(fun, max_evaluations, cancel)
    f = tr(X)
    P, Pf = X.copy(), f.copy()
    w = float(omega)
    stall, reason = 0, "max_generations"
    for _ in range(max_generations):
        r = tr.out_of_budget()
        if r:
            reason = r
            break
        gb = P[int(np.argmin(Pf))]
        before = tr.best_f
        r1, r2 = g.random((2, n_particles, n))
        V = w * V + c1 * r1 * (P - X) + c2 * r2 * (gb - X)
        X = np.clip(X + V, lo, hi)
        f = tr(X)
        better = f < Pf
        P[better], Pf[better] = X[better], f[better]
        w *= omega_decay
        gain = before - tr.best_f
        if gain < stall_tol:
            stall += 1
        elif gain > 10 * stall_tol:
            stall = 0
        if stall >= max_stall:
            reason = "tol_fun"
            break
    return tr.result(reason, "pso")


def pattern_search(fun: Callable, x0, *, step=0.5, lower=None, upper=None, tol_x: float = 1e-3,
                   max_generations: int = 200, max_evaluations: int | None = None, expand: float = 1.0,
                   cancel: Callable[[], bool] | None = None) -> OptimizeResult:
    """Batched compass search: per call the 2n points ``x ± step_i e_i``; move to the best if it
    improves, otherwise halve every step; stop when all steps are below ``tol_x`` (converged).
    ``expand`` (≥ 1) multiplies the steps after a successful move."""
    x, lo, hi = _box(x0, lower, upper)
    n = x.size
    h = np.broadcast_to(np.asarray(step, dtype=float), (n,)).copy()
    if np.any(h <= 0):
        raise ValueError(f"step: expected positive steps, got {step!r}")
    max_generations = _positive_int(max_generations, "max_generations")
    tr = _Tracker(fun, max_evaluations, cancel)
    fx = float(tr(x[None])[0])
    D = np.concatenate([np.eye(n), -np.eye(n)])
    reason = "max_generations"
    for _ in range(max_generations):
        r = tr.out_of_budget()
        if r:
            reason = r
            break
        if np.all(h < tol_x):
            reason = "tol_x"
            break
        X = np.clip(x + D * h, lo, hi)
        f = tr(X)
        i = int(np.argmin(f))
        if f[i] < fx:
            x, fx = X[i], float(f[i])
            h = h * expand
        else:
            h = h * 0.5
    else:
        if np.all(h < tol_x):
            reason = "tol_x"
    return tr.result(reason, "pattern")


def _scipy(method: str, fun, x0, lower, upper, options, cancel, max_evaluations) -> OptimizeResult:
    from scipy.optimize import minimize

    x0, lo, hi = _box(x0, lower, upper)
    tr = _Tracker(fun, max_evaluations, cancel)

    class _Stop(Exception):
        pass

    def f1(x):
        if tr.out_of_budget():
            raise _Stop
        return float(tr(np.clip(x, lo, hi)[None])[0])

    bounds = list(zip(np.where(np.isfinite(lo), lo, None), np.where(np.isfinite(hi), hi, None), strict=True))
    try:
        res = minimize(f1, x0, method=method, bounds=bounds, options=options)
        reason = "tol_fun" if res.success else "max_generations"
    except _Stop:
        reason = tr.out_of_budget() or "cancelled"
    return tr.result(reason, method.lower().replace("-", "_"))


def nelder_mead(fun: Callable, x0, *, step=0.1, lower=None, upper=None, tol_x: float = 1e-3,
                tol_fun: float = 1e-5, max_evaluations: int = 2000,
                cancel: Callable[[], bool] | None = None) -> OptimizeResult:
    """Downhill simplex from ``x0`` with initial vertices ``x0 + step_i e_i`` (Autoscoper uses
    offsets of 0.1 and a function tolerance of 1e-5), one point per call (scipy)."""
    x0 = np.asarray(x0, dtype=float).ravel()
    h = np.broadcast_to(np.asarray(step, dtype=float), x0.shape)
    simplex = np.vstack([x0, x0 + np.diag(h)])
    opts = {"initial_simplex": simplex, "xatol": tol_x, "fatol": tol_fun, "maxfev": int(max_evaluations)}
    return _scipy("Nelder-Mead", fun, x0, lower, upper, opts, cancel, max_evaluations)


def powell(fun: Callable, x0, *, lower=None, upper=None, tol_x: float = 1e-3, tol_fun: float = 1e-6,
           max_evaluations: int = 2000, cancel: Callable[[], bool] | None = None) -> OptimizeResult:
    """Powell's conjugate-direction method (scipy), one point per call."""
    opts = {"xtol": tol_x, "ftol": tol_fun, "maxfev": int(max_evaluations)}
    return _scipy("Powell", fun, x0, lower, upper, opts, cancel, max_evaluations)
