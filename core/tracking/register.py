"""Single-frame 2D/3D registration of one bone in both views: coarse-to-fine, global then local.

:func:`register` minimises :class:`~core.tracking.cost.RegistrationCost` over the 6 pose
parameters ``x`` (mm, degrees; about the bone's centroid, relative to the initial pose) inside
the box ``|t_i| <= bounds[0]`` mm, ``|r_i| <= bounds[1]`` degrees, level by level of an image
pyramid (:class:`Level`: pyramid ``scale``, optimiser and its budget). Each level starts from the
previous level's best point; an optional local refinement (``refine``) polishes the result at
the finest level. All levels share the base pose, the centre and the ROIs (the bone's projected
outline at the initial pose grown by the search bounds), so ``x`` means the same at every level.

Default levels (:func:`default_levels`)
---------------------------------------
* ``search="global"`` (a hand-placed start, a retry): CMA-ES with a population of 24 at the
  coarsest pyramid level, then the quadratic-model search
  (:func:`core.tracking.quadratic.quadratic_search`) at the finer levels;
* ``search="local"`` (tracking from a predicted pose): the quadratic-model search only, at
  half and full resolution. Each generation renders one design of 73 poses in one launch, and a
  frame converges in a handful of generations.
* ``search="newton"`` (tracking from a predicted pose): Levenberg–Marquardt steps of the
  Gauss–Newton engine (:mod:`core.tracking.engine`: the cost's gradient and 6 × 6 curvature from
  13 poses per launch) at full resolution. The engine keeps its device buffers from frame to
  frame; only ``gc`` and ``ncc`` single-term costs. Its widened form ``"global_newton"`` (first
  frames, retries) scores the CMA-ES populations on the engine too.

The full-resolution quadratic fit of the last level is returned (``fit``): its Hessian and
residual give the pose uncertainty without another launch.

The result is converged when the last stage stopped on a convergence rule and the optimum is
not on the search box (a point on the box means the true pose may lie beyond it).

Final stage (``final="likelihood"``, opt-in)
--------------------------------------------
:func:`core.tracking.final_stage.final_stage` refines the registered pose by weighted least
squares of the bone's DRR against the line-integral image on the device
(:mod:`core.tracking.engine_likelihood`: both high-passed by ``final_highpass_px``, the pixels
weighted by their expected counts, the gain and an offset fitted linearly, the neighbours of
``others`` subtracted at their poses), a few Gauss–Newton steps from the similarity's optimum,
in the bone's volume box grown by 1 mm. By default the pixels are weighted robustly
(:class:`~core.tracking.final_stage.FinalModel`, ``robust=2.5``, the module's ``MODEL``): after
a first refinement each pixel's weight falls (Cauchy) where the local residual RMS is over 2.5 ×
its view's median — structure the model lacks — and the pose is refined again; ``robust=None`` is
the plain stage. The similarity search before it may take the quantum noise's share out of the
gradient magnitudes (``noise_correction``, opt-in, below); the stage itself weights pixels by
their expected counts either way.
The result's ``fit`` is then a :class:`~core.tracking.final_stage.LikelihoodFit` whose
confidence (:func:`core.tracking.confidence.confidence_from_fit`) is the sandwich covariance of
the refinement (the residual's autocorrelation accounted for); ``score`` stays the similarity's.
A refinement that moves the pose more than ``final_reach`` (mm, degrees) or fails is not taken
(``timing["likelihood_taken"]`` 0; ``timing["likelihood_s"]``, ``["likelihood_steps"]``: its
cost). Joint tracking's side-by-side searches (:func:`core.tracking.joint.register_together`)
end with the same stage.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from . import optimize as opt
from .cost import (
    DEFAULT_TERMS,
    NOISE_OPTION,
    CostTimer,
    FrameImages,
    MetricTerm,
    RegistrationCost,
    mm_per_pixel,
    search_roi,
    snap_roi,
)
from .quadratic import quadratic_search

__all__ = ["Level", "RegistrationOptions", "RegistrationResult", "default_levels", "mm_per_pixel",
           "register"]

_METHODS = ("cmaes", "pso", "pattern", "quadratic", "nelder_mead", "powell", "gauss_newton")
_SEARCHES = ("global", "local", "newton", "global_newton")
_FINALS = (None, "likelihood")
_FINAL_CONFIDENCES = ("sandwich", "sandwich+move", "independent")
#: Design half-widths (mm, degrees) of the full-resolution quadratic fits.
FINAL_STEP = (0.25, 0.5)


@dataclass(frozen=True)
class Level:
    """One pyramid level: ``scale`` (full-resolution pixels per DRR pixel), the optimiser
    (``method`` in ``cmaes``, ``pso``, ``pattern``, ``quadratic``, ``nelder_mead``, ``powell``),
    its initial step ``sigma`` (mm, degrees; CMA-ES σ, pattern/simplex step, quadratic design
    half-widths; PSO uses ±3·sigma as its start range), ``popsize`` (CMA-ES; PSO particles),
    ``max_generations``, ``tol_x`` (mm/degrees) and extra optimiser keywords ``options``
    (for ``quadratic``: ``min_step`` as (mm, degrees), ``kind``, ``trust``)."""

    scale: float = 1.0
    method: str = "cmaes"
    sigma: tuple[float, float] = (1.0, 1.0)
    popsize: int | None = None
    max_generations: int = 60
    tol_x: float = 0.01
    options: Mapping = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.method not in _METHODS:
            raise ValueError(f"method: expected one of {_METHODS}, got {self.method!r}")
        if not (np.isfinite(self.scale) and self.scale > 0):
            raise ValueError(f"scale: expected a positive pyramid scale, got {self.scale!r}")
        if len(self.sigma) != 2 or min(self.sigma) <= 0:
            raise ValueError(f"sigma: expected (mm, degrees) > 0, got {self.sigma!r}")
        object.__setattr__(self, "options", dict(self.options))

    def to_dict(self) -> dict:
        return {"scale": self.scale, "method": self.method, "sigma": list(self.sigma),
                "popsize": self.popsize, "max_generations": self.max_generations,
                "tol_x": self.tol_x, "options": dict(self.options)}


def default_levels(mm_per_px: float, *, sigma: tuple[float, float] = (1.5, 1.5),
                   coarsest_mm: float = 1.2, search: str = "global") -> tuple[Level, ...]:
    """Levels from DRR pixels of about ``coarsest_mm`` mm down to full resolution.

    Pyramid scales 4, 2, 1 are kept while ``scale × mm_per_px <= coarsest_mm`` (1024² views of a
    foot, ~0.3 mm pixels: 4, 2, 1; 256²: 1 only).

    * ``"global"``: CMA-ES (population 24, first step ``sigma`` in mm and degrees) at the
      coarsest scale, then quadratic-model searches at each finer scale (at a single scale:
      CMA-ES then a quadratic search, both at full resolution);
    * ``"local"``: a quadratic search at the second-finest scale (design half-widths
      ``max(sigma / 2, (0.4 mm, 0.8°))``) and one at full resolution; with one scale, one
      search from ``(0.5 mm, 1°)`` down to :data:`FINAL_STEP`;
    * ``"global_newton"``: the CMA-ES stage of ``"global"``, then Gauss–Newton steps at each finer
      scale (half-steps :data:`FINAL_STEP` × scale) — the widened options of ``"newton"``;
    * ``"newton"``: Gauss–Newton steps at full resolution only (central-difference half-steps
      :data:`FINAL_STEP`, at most 8, stopping below 0.02 or when the predicted decrease is
      below a tenth of the cost's roughness); when they do not converge (a move beyond their
      reach), :func:`register` starts again at half resolution with twice the half-steps.

    The full-resolution search ends with designs of :data:`FINAL_STEP` half-widths and a Newton
    step below 0.02 (mm, degrees).
    """
    if not (np.isfinite(mm_per_px) and mm_per_px > 0):
        raise ValueError(f"mm_per_px: expected a positive pixel size, got {mm_per_px!r}")
    if search not in _SEARCHES:
        raise ValueError(f"search: expected one of {_SEARCHES}, got {search!r}")
    if len(sigma) != 2 or min(sigma) <= 0:
        raise ValueError(f"sigma: expected (mm, degrees) > 0, got {sigma!r}")
    scales = [s for s in (4.0, 2.0) if s * mm_per_px <= coarsest_mm] + [1.0]
    fin = FINAL_STEP
    mid = (max(sigma[0] / 2, 0.4), max(sigma[1] / 2, 0.8))

    def final(step):
        return Level(scale=1.0, method="quadratic", sigma=step, max_generations=8, tol_x=0.02,
                     options={"min_step": fin})

    def between(s):
        return Level(scale=s, method="quadratic", sigma=mid, max_generations=6, tol_x=0.1,
                     options={"min_step": mid})

    if search == "newton":  # a coarse level first made it slower, not more accurate (1024² trial)
        return (Level(scale=1.0, method="gauss_newton", sigma=fin, max_generations=8, tol_x=0.02),)
    if search == "global_newton":  # CMA-ES at the coarsest scale, then Gauss-Newton steps
        out = [Level(scale=scales[0], method="cmaes", sigma=tuple(sigma), popsize=24,
                     max_generations=40, tol_x=0.05)]
        out += [Level(scale=s, method="gauss_newton", sigma=(fin[0] * s, fin[1] * s), max_generations=6,
                      tol_x=0.05) for s in scales[1:-1]]
        out.append(Level(scale=1.0, method="gauss_newton", sigma=fin, max_generations=8, tol_x=0.02))
        return tuple(out)
    if search == "global":
        out = [Level(scale=scales[0], method="cmaes", sigma=tuple(sigma), popsize=24,
                     max_generations=40, tol_x=0.05)]
        out += [between(s) for s in scales[1:-1]]
        out.append(final((0.5, 1.0)))
        return tuple(out)
    if len(scales) > 1:
        return between(scales[-2]), final(fin)
    return (final((0.5, 1.0)),)


@dataclass(frozen=True)
class RegistrationOptions:
    """Options of :func:`register`.

    ``levels=None`` picks :func:`default_levels` (with ``search`` and ``sigma``) for the pixel
    size at the bone. ``bounds``: search box half-widths about the initial pose (mm, degrees).
    ``refine``: an extra local method run at full resolution after the levels (``"pattern"``,
    ``"quadratic"``, ``"nelder_mead"``, ``"powell"`` or None) with initial step ``refine_step``
    (mm, degrees). ``margin_px``: extra ROI margin. ``final_scale``: the pyramid scale that
    counts as full resolution — the finest automatic level, the final score, the refinement and
    the confidence fit (2 for detectors much finer than the bone needs, e.g. 1760² views of a
    wrist at 0.15 mm per pixel). ``final``: ``"likelihood"`` ends the registration with the
    weighted least-squares refinement of :func:`core.tracking.final_stage.final_stage`
    (high-pass σ ``final_highpass_px`` pixels, at most ``final_iters`` steps, taken when it
    moves the pose by at most ``final_reach`` (mm, degrees); ``final_lag_px``: the lag window
    of its covariance, None for the engine's default; ``final_confidence``: the frame's
    covariance — ``"sandwich"`` (the residual's autocorrelation accounted for),
    ``"sandwich+move"`` (the default: plus the outer product of the stage's move from the
    similarity's optimum, the two costs' disagreement as a systematic part; on the 1024² trial,
    one H200, the talus's errors were within 2σ on 94 % of the axes, against 85-86 % with the
    sandwich alone) or ``"independent"``; ``final_others_gain``: the neighbours' DRRs fitted with
    a gain of their own instead of subtracted as they are), or None. ``noise_correction``: the
    gradient correlation of the magnitudes takes the quantum noise's expected share out of the
    fluoroscope's squared gradients at full resolution (debiased magnitudes
    ``sqrt(max(|g|² - E₁/F, 0))``, ``E₁`` estimated from each frame:
    :meth:`core.tracking.cost.FrameImages.noise_energy`), on the Gauss–Newton engine and the host
    cost alike; it sets the ``gc`` terms' ``noise_correction`` option (not those of the
    components' form, which noise does not bias this way).
    """

    terms: tuple[MetricTerm, ...] = DEFAULT_TERMS
    levels: tuple[Level, ...] | None = None
    bounds: tuple[float, float] = (10.0, 10.0)
    sigma: tuple[float, float] = (1.5, 1.5)
    search: str = "global"
    final_scale: float = 1.0
    refine: str | None = None
    refine_step: tuple[float, float] = (0.1, 0.1)
    refine_tol: float = 0.005
    margin_px: int = 4
    seed: int = 0
    final: str | None = None
    final_highpass_px: float = 4.0
    final_iters: int = 5
    final_reach: tuple[float, float] = (1.0, 2.0)
    final_lag_px: int | None = None
    final_confidence: str = "sandwich+move"
    final_others_gain: bool = False
    noise_correction: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.noise_correction, bool):
            raise ValueError(f"noise_correction: expected True or False, got {self.noise_correction!r}")
        # the gc terms of the magnitudes carry the correction's option (the costs and the engine
        # read it there); this flag sets or clears it
        terms = []
        for t in self.terms:
            if t.kind == "gc" and not t.options.get("components", False):
                opts = {k: v for k, v in t.options.items() if k != NOISE_OPTION}
                if self.noise_correction:
                    opts[NOISE_OPTION] = True
                if opts != dict(t.options):
                    t = replace(t, options=opts)
            terms.append(t)
        object.__setattr__(self, "terms", tuple(terms))
        if self.levels is not None:
            object.__setattr__(self, "levels", tuple(self.levels))
            if not self.levels or not all(isinstance(lv, Level) for lv in self.levels):
                raise ValueError("levels: expected a non-empty sequence of Level (or None for automatic)")
        if len(self.bounds) != 2 or min(self.bounds) <= 0:
            raise ValueError(f"bounds: expected (mm, degrees) > 0, got {self.bounds!r}")
        if self.refine not in (None, "pattern", "quadratic", "nelder_mead", "powell"):
            raise ValueError(f"refine: expected 'pattern', 'quadratic', 'nelder_mead', 'powell' or None, "
                             f"got {self.refine!r}")
        if self.search not in _SEARCHES:
            raise ValueError(f"search: expected one of {_SEARCHES}, got {self.search!r}")
        if not (np.isfinite(self.final_scale) and self.final_scale >= 1):
            raise ValueError(f"final_scale: expected a pyramid scale >= 1, got {self.final_scale!r}")
        if self.final not in _FINALS:
            raise ValueError(f"final: expected one of {_FINALS}, got {self.final!r}")
        if not (np.isfinite(self.final_highpass_px) and self.final_highpass_px >= 0):
            raise ValueError(f"final_highpass_px: expected a σ >= 0 (pixels), got {self.final_highpass_px!r}")
        fi = self.final_iters
        if isinstance(fi, bool) or int(fi) != fi or fi < 1:
            raise ValueError(f"final_iters: expected an integer >= 1, got {self.final_iters!r}")
        if len(self.final_reach) != 2 or not all(np.isfinite(v) and v > 0 for v in self.final_reach):
            raise ValueError(f"final_reach: expected (mm, degrees) > 0, got {self.final_reach!r}")
        lag = self.final_lag_px
        if lag is not None and (isinstance(lag, bool) or int(lag) != lag or lag < 0):
            raise ValueError(f"final_lag_px: expected an integer >= 0 or None, got {lag!r}")
        if not isinstance(self.final_others_gain, bool):
            raise ValueError(f"final_others_gain: expected True or False, got {self.final_others_gain!r}")
        if self.final_confidence not in _FINAL_CONFIDENCES:
            raise ValueError(f"final_confidence: expected one of {_FINAL_CONFIDENCES}, "
                             f"got {self.final_confidence!r}")

    def widened(self, factor: float = 2.0) -> RegistrationOptions:
        """The same options with ``factor``× larger bounds and first steps, twice the
        population and a global first stage (for a retry after a failure or a poor initial
        guess): ``"global"``, or ``"global_newton"`` (CMA-ES, then Gauss–Newton steps) for the
        Gauss–Newton searches."""
        lv = None
        if self.levels is not None:
            lv = tuple(replace(x, sigma=(x.sigma[0] * factor, x.sigma[1] * factor),
                               popsize=None if x.popsize is None else 2 * x.popsize) if i == 0 else x
                       for i, x in enumerate(self.levels))
        return replace(self, bounds=(self.bounds[0] * factor, self.bounds[1] * factor),
                       sigma=(self.sigma[0] * factor, self.sigma[1] * factor), levels=lv,
                       search="global_newton" if self.search in ("newton", "global_newton") else "global",
                       seed=self.seed + 1)

    def to_dict(self) -> dict:
        return {"terms": [t.to_dict() for t in self.terms],
                "levels": None if self.levels is None else [lv.to_dict() for lv in self.levels],
                "bounds": list(self.bounds), "sigma": list(self.sigma), "search": self.search,
                "final_scale": self.final_scale,
                "refine": self.refine,
                "refine_step": list(self.refine_step), "refine_tol": self.refine_tol,
                "margin_px": self.margin_px, "seed": self.seed, "final": self.final,
                "final_highpass_px": self.final_highpass_px, "final_iters": self.final_iters,
                "final_reach": list(self.final_reach), "final_lag_px": self.final_lag_px,
                "final_confidence": self.final_confidence, "final_others_gain": self.final_others_gain,
                "noise_correction": self.noise_correction}


@dataclass(frozen=True, eq=False)
class RegistrationResult:
    """Outcome of :func:`register`.

    Attributes
    ----------
    pose : (4, 4) array
        Registered ``T_lab_from_bone``.
    x : (6,) array
        Its parameters relative to the initial pose (mm, degrees, about the centre).
    score : float
        Weighted mean similarity at the pose at ``final_scale`` (full resolution by default); after
        a converged Gauss–Newton search, the value of its last model there (the last centre it
        scored lies within ``tol_x`` of the pose).
    view_scores : (n_views,) array
        Weighted similarity per view at the pose.
    evaluations, generations : int
        Poses rendered and batched calls, all stages.
    time_s : float
    converged : bool
    reason : str
        Stopping rule of the last stage, or ``"at_bound"``.
    stages : tuple of OptimizeResult
    timing : dict
        :class:`~core.tracking.cost.CostTimer` totals over the levels plus ``optimizer_s`` (the
        rest of the wall time: optimiser arithmetic and set-up).
    fit : QuadraticFit or None
        The last full-resolution quadratic fit about the result (x units: mm, degrees), when
        the last stage was a quadratic search.
    """

    pose: np.ndarray
    x: np.ndarray
    score: float
    view_scores: np.ndarray
    evaluations: int
    generations: int
    time_s: float
    converged: bool
    reason: str
    stages: tuple[opt.OptimizeResult, ...]
    timing: dict
    fit: object = None

    def to_dict(self) -> dict:
        return {"pose": self.pose.tolist(), "x": self.x.tolist(), "score": self.score,
                "view_scores": self.view_scores.tolist(), "evaluations": self.evaluations,
                "generations": self.generations, "time_s": self.time_s, "converged": self.converged,
                "reason": self.reason, "stages": [s.to_dict() for s in self.stages], "timing": self.timing}


def _run(level_method: str, fun, x0, *, sigma6, lo, hi, level: Level | None, tol, seed, cancel, popsize,
         max_gen):
    extra = {} if level is None else dict(level.options)
    if level_method == "cmaes":
        return opt.cmaes(fun, x0, sigma0=sigma6, lower=lo, upper=hi, popsize=popsize,
                         max_generations=max_gen, tol_x=tol, seed=seed, cancel=cancel, **extra)
    if level_method == "pso":
        kw = {"start_min": -3 * sigma6, "start_max": 3 * sigma6, "max_generations": max_gen}
        if popsize:
            kw["n_particles"] = popsize
        kw.update(extra)
        return opt.pso(fun, x0, lower=lo, upper=hi, seed=seed, cancel=cancel, **kw)
    if level_method == "quadratic":
        kw = dict(extra)
        if "min_step" in kw:
            ms = np.asarray(kw.pop("min_step"), dtype=float)
            kw["min_step"] = np.minimum(np.repeat(ms, 3) if ms.size == 2 else ms, sigma6)
        kw.setdefault("max_generations", max_gen)
        return quadratic_search(fun, x0, step=sigma6, lower=lo, upper=hi, tol_x=tol, cancel=cancel, **kw)
    if level_method == "pattern":
        return opt.pattern_search(fun, x0, step=sigma6, lower=lo, upper=hi, tol_x=tol,
                                  max_generations=max_gen, cancel=cancel, **extra)
    if level_method == "nelder_mead":
        return opt.nelder_mead(fun, x0, step=sigma6, lower=lo, upper=hi, tol_x=tol, cancel=cancel, **extra)
    return opt.powell(fun, x0, lower=lo, upper=hi, tol_x=tol, cancel=cancel, **extra)


_LEVELS: dict = {}  # (levels function, sigma, final scale) -> the "newton" levels (_automatic_levels)


def _automatic_levels(mm_px: float, fs: float, sigma, search: str) -> tuple[Level, ...]:
    """:func:`default_levels` at ``mm_px`` (mm per DRR pixel at the final scale ``fs``), scaled by
    ``fs``. The ``"newton"`` search's levels do not depend on the pixel size (Gauss–Newton steps at
    full resolution): they are made once per (sigma, fs) and kept (the same frozen levels; checked
    as default_levels checks its arguments)."""
    if search != "newton":
        return tuple(replace(lv, scale=lv.scale * fs)
                     for lv in default_levels(mm_px, sigma=sigma, search=search))
    if not (np.isfinite(mm_px) and mm_px > 0):
        raise ValueError(f"mm_per_px: expected a positive pixel size, got {mm_px!r}")
    key = (default_levels, tuple(float(a) for a in sigma), float(fs))  # (the function: a test may patch it)
    hit = _LEVELS.get(key)
    if hit is None:
        if len(_LEVELS) >= 16:
            _LEVELS.clear()
        hit = _LEVELS[key] = tuple(replace(lv, scale=lv.scale * fs)
                                   for lv in default_levels(mm_px, sigma=sigma, search=search))
    return hit


def _newton_fallback(mm_per_px: float, coarsest_mm: float = 1.2) -> tuple[Level, ...]:
    """The levels of the ``"newton"`` search's second attempt: Gauss–Newton steps at the
    second-finest pyramid scale (half-steps and trust twice as wide), then at full resolution; at
    a single scale, full resolution with twice the half-steps first."""
    fin = FINAL_STEP
    s = 2.0 if 2.0 * mm_per_px <= coarsest_mm else 1.0
    first = Level(scale=s, method="gauss_newton", sigma=(2 * fin[0], 2 * fin[1]), max_generations=6,
                  tol_x=0.05)
    return first, Level(scale=1.0, method="gauss_newton", sigma=fin, max_generations=8, tol_x=0.02)


def search_region(renderer, pose, bone: int, *, views, center, options: RegistrationOptions, outline=None,
                  snap: bool = True) -> np.ndarray:
    """The full-resolution search regions ``(n_views, 4)`` of a registration of ``bone`` about
    ``pose`` (:func:`core.tracking.cost.search_roi` reaching the option's bounds; with ``snap``, on
    the 16-pixel grid the Gauss–Newton engine's buffers keep from frame to frame)."""
    o = options
    roi = search_roi(renderer, pose, bone, views=views, center=center,
                     reach_mm=o.bounds[0] + math.radians(o.bounds[1]) * 30.0, margin_px=o.margin_px,
                     points=outline)
    return snap_roi(roi, renderer, views) if snap else roi


def register(renderer, frame: FrameImages, *, bone: int, initial_pose, center,
             options: RegistrationOptions | None = None, views: Sequence[int] | None = None,
             others=None, cancel: Callable[[], bool] | None = None, profile: bool = False,
             x0=None, outline=None, roi=None, tried=None) -> RegistrationResult:
    """Register bone ``bone`` of ``renderer`` to ``frame`` starting from ``initial_pose``.

    Parameters
    ----------
    renderer : core.render.DRRRenderer
    frame : FrameImages
    bone : int
        Volume index in the renderer.
    initial_pose : (4, 4) array
        Initial guess ``T_lab_from_bone`` (the search box is centred on it).
    center : (3,) array
        Rotation centre in the bone's CT frame (its centroid), mm.
    options : RegistrationOptions
    views : sequence of int, optional
        Views to use (default all).
    others : (poses, bones), optional
        Other bones to subtract from the fluoroscope (see :class:`RegistrationCost`).
    cancel : callable, optional
        Polled once per generation; a cancelled run returns its best point, not converged.
    profile : bool
        Time DRR and metric separately (:class:`RegistrationCost`).
    x0 : (6,) array, optional
        Start point inside the box (default 0: the initial pose).
    outline : (n, 3) array, optional
        Bone-frame points bounding the bone (:attr:`core.tracking.bones.BoneModel.outline`):
        tighter search ROIs than the volume's box (fewer pixels per DRR).
    roi : (n_views, 4) array, optional
        The search regions (full-resolution ``(u0, v0, w, h)``) in place of those computed about
        ``initial_pose`` (:func:`core.tracking.cost.search_roi`; the second round of joint
        tracking keeps the first round's).
    tried : (OptimizeResult, GaussNewtonCost, float), optional
        The ``"newton"`` search's full-resolution stage already run with these inputs that did not
        converge, its engine and the seconds it took (:func:`core.tracking.joint.register_together`):
        the registration goes on with its half-resolution fallback instead of repeating it.

    Raises
    ------
    core.tracking.cost.OutsideViewError
        The bone's search region misses a view.
    """
    o = options or RegistrationOptions()
    t_start = time.perf_counter()
    base = np.asarray(initial_pose, dtype=float)
    center = np.asarray(center, dtype=float)
    views = tuple(range(frame.n_views)) if views is None else tuple(views)
    fs = o.final_scale
    search = o.search
    if search in ("newton", "global_newton") and o.levels is None:
        from .engine import supports

        if not supports(o.terms):  # the engine scores gc and ncc only: the quadratic-model searches
            search = "local" if search == "newton" else "global"
    px_mm = None  # the full-resolution pixel size at the bone (the engine's smoothing takes it too)
    levels = o.levels
    if levels is None:
        px_mm = mm_per_pixel(renderer, base, center, views)
        levels = _automatic_levels(px_mm * fs, fs, o.sigma, search)
    if roi is None:
        roi = search_region(renderer, base, bone, views=views, center=center, options=o, outline=outline,
                            snap=all(lv.method == "gauss_newton" for lv in levels))
    else:
        roi = np.asarray(roi, dtype=np.int64).reshape(len(views), 4)
    hi = np.array([o.bounds[0]] * 3 + [o.bounds[1]] * 3, dtype=float)
    lo = -hi
    x = np.zeros(6) if x0 is None else np.clip(np.asarray(x0, dtype=float), lo, hi)
    stages, costs, engines = [], {}, {}
    engine_global = search == "global_newton" and o.levels is None
    if tried is not None:  # the full-resolution steps were taken (side by side): on to the fallback
        if not (o.levels is None and search == "newton" and len(levels) == 1):
            raise ValueError("tried: only the automatic 'newton' search's full-resolution stage")
        r_tried, engines[levels[0].scale], spent = tried
        stages.append(r_tried)
        t_start -= spent

    def cost_at(scale: float) -> RegistrationCost:
        if scale not in costs:
            costs[scale] = RegistrationCost(renderer, frame, bone=bone, base_pose=base, center=center,
                                            roi=roi, scale=scale, terms=o.terms, views=views,
                                            others=others, profile=profile)
        return costs[scale]

    def engine_at(scale: float):
        if scale not in engines:
            from .engine import engine_cost

            if len(o.terms) != 1:
                raise ValueError("levels: the Gauss-Newton engine takes a single metric term")
            c = engine_cost(renderer, bone=bone, views=views, scale=scale, term=o.terms[0])
            c.timer = CostTimer()
            c.batches = {}
            c.profile = profile
            c.set_frame(frame, base_pose=base, center=center, roi=roi, others=others, px_mm=px_mm)
            engines[scale] = c
        return engines[scale]

    def run_level(i: int, lv: Level, x):
        sig6 = np.array([lv.sigma[0]] * 3 + [lv.sigma[1]] * 3)
        if lv.method == "gauss_newton":
            from .engine import gauss_newton_search

            kw = dict(lv.options)
            r = gauss_newton_search(engine_at(lv.scale), x, step=sig6, lower=lo, upper=hi, tol_x=lv.tol_x,
                                    max_generations=lv.max_generations, cancel=cancel, **kw)
        else:
            # the CMA-ES stage of "global_newton" scores its populations on the engine (the same
            # scores; buffers, pipeline and graph kept from frame to frame, where a RegistrationCost
            # was built per registration)
            fun = engine_at(lv.scale) if (lv.method == "cmaes" and engine_global) else cost_at(lv.scale)
            r = _run(lv.method, fun, x, sigma6=sig6, lo=lo, hi=hi, level=lv, tol=lv.tol_x,
                     seed=o.seed * 1000 + i, cancel=cancel, popsize=lv.popsize, max_gen=lv.max_generations)
        return r

    for i, lv in enumerate(levels if tried is None else ()):
        r = run_level(i, lv, x)
        stages.append(r)
        x = r.x
        if r.reason == "cancelled":
            break
    if (o.levels is None and search == "newton" and not stages[-1].converged
            and stages[-1].reason != "cancelled"):
        # beyond the full-resolution steps' reach (a large move since the last frame): again from
        # the start, half resolution first (wider steps), then full resolution
        x = np.zeros(6) if x0 is None else np.clip(np.asarray(x0, dtype=float), lo, hi)
        for i, lv in enumerate(_newton_fallback(mm_per_pixel(renderer, base, center, views) * fs)):
            lv = replace(lv, scale=lv.scale * fs)
            r = run_level(len(levels) + i, lv, x)
            stages.append(r)
            x = r.x
            if r.reason == "cancelled":
                break
        levels = (*levels, lv)
    last_gn = levels[-1].method == "gauss_newton" and levels[-1].scale == fs
    full = engine_at(fs) if (last_gn and not o.refine) else cost_at(fs)
    if o.refine and stages[-1].reason != "cancelled":
        step6 = np.array([o.refine_step[0]] * 3 + [o.refine_step[1]] * 3)
        r = _run(o.refine, full, x, sigma6=step6, lo=lo, hi=hi, level=None, tol=o.refine_tol,
                 seed=o.seed, cancel=cancel, popsize=None, max_gen=200)
        stages.append(r)
        if r.fun <= full(x[None])[0]:
            x = r.x
    last = stages[-1]
    fit = last.model if (last.method in ("quadratic", "gauss_newton") and last.model is not None
                         and (o.refine == "quadratic" or levels[-1].scale == fs)) else None
    res = result_of(stages, x, full, hi, model_score=last_gn and not o.refine,
                    timers=(*costs.values(), *engines.values()), engines=engines, fit=fit,
                    t_start=t_start)
    if o.final is None:
        return res
    from .final_stage import final_stage

    return final_stage(renderer, frame, res, bone=bone, initial_pose=base, center=center, options=o,
                       views=views, others=others)


def result_of(stages, x, full, hi, *, model_score: bool, timers, engines, fit,
              t_start: float) -> RegistrationResult:
    """The :class:`RegistrationResult` of a registration's ``stages`` ending at ``x`` (scored
    on ``full``, the full-resolution cost; ``hi`` the search box's half-widths): with
    ``model_score`` and a converged last stage with a fitted model, the model's similarity at its
    minimum (the last step's centre is within tol_x of it) and the per-view similarities at that
    centre, without a launch of its own; otherwise ``full`` scores ``x``. ``timers``: every cost
    used (their timers are summed), ``engines``: the Gauss–Newton engines by scale (their
    launches counted), ``t_start``: when the registration started (``time.perf_counter``).
    :func:`register` and the side-by-side searches of :mod:`core.tracking.joint` build their
    results here."""
    last = stages[-1]
    x = np.asarray(x, dtype=float)
    if model_score and last.converged and last.model is not None:
        score = float(1.0 - last.model.predict(x - last.model.x))
        view_scores = np.asarray(last.model.view_scores, dtype=float)
    else:
        score, view_scores = full.score_and_views(x)
    converged = last.converged and all(s.reason != "cancelled" for s in stages)
    reason = last.reason
    if np.any(np.abs(x) >= hi * (1 - 1e-6)):
        converged, reason = False, "at_bound"
    timing = {"render_s": 0.0, "metric_s": 0.0, "host_s": 0.0, "calls": 0, "evaluations": 0}
    for c in timers:
        for k, v in c.timer.to_dict().items():
            timing[k] += v
    for sc, c in engines.items():  # launches of the engine per scale (13-pose steps, 1-pose scores)
        timing[f"engine_steps_x{sc:g}"] = c.batches.get(13, 0)
        timing[f"engine_scores_x{sc:g}"] = sum(v for b, v in c.batches.items() if b != 13)
    pose = full.poses(x[None])[0]
    total = time.perf_counter() - t_start
    timing["total_s"] = total
    timing["optimizer_s"] = max(total - timing["render_s"] - timing["metric_s"] - timing["host_s"], 0.0)
    return RegistrationResult(
        pose=pose, x=x, score=score, view_scores=view_scores,
        evaluations=sum(s.evaluations for s in stages), generations=sum(s.generations for s in stages),
        time_s=total, converged=converged, reason=reason, stages=tuple(stages), timing=timing, fit=fit)
