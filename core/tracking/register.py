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
  frame; only ``gc`` and ``ncc`` single-term costs. On pixels coarser than 0.6 mm at the bone
  (256² views of a foot and coarser) wider half-steps and a gradient corrected for the metric
  domain's change with the pose (:func:`~core.tracking.register_options.newton_step`). Its
  widened form ``"global_newton"`` (first frames, retries) scores the CMA-ES populations on the
  engine too.

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
in the bone's volume box grown by 1 mm. Before it the ``"newton"`` search stops at a looser
tolerance (:data:`~core.tracking.register_options.STAGE_SEARCH_TOL`, 0.5 mm and degrees, against
its own 0.02): the stage only needs a start inside its basin. By default the pixels are weighted robustly
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

The levels and options (:class:`Level`, :func:`default_levels`, :class:`RegistrationOptions`) live
in :mod:`core.tracking.register_options` (importable from here too).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from . import optimize as opt
from .cost import CostTimer, FrameImages, RegistrationCost, mm_per_pixel, search_roi
from .quadratic import quadratic_search
from .register_ahead import final_stage_idle
from .register_options import (  # noqa: F401
    FINAL_STEP,
    Level,
    RegistrationOptions,
    before_stage,
    default_levels,
    newton_step,
)

__all__ = ["Level", "RegistrationOptions", "RegistrationResult", "default_levels", "mm_per_pixel",
           "register"]

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

#: Study switch (off): with a final stage, the ``"newton"`` search's registration (one bone's; not joint
#: tracking's side-by-side searches) runs the stage straight from the initial pose (the tracker's
#: prediction) and scores the similarity once at the stage's pose; only where the stage's move is not
#: taken (failed, or beyond its reach) does the search run, then the stage again. The stage's move then
#: counts from the prediction (its confidence's move term, the frame step's move check, and a rejected
#: move keeps the prediction): :func:`_stage_first`. Measured and left off: on one NVIDIA H100 (the talus
#: alone, 1024², 100 frames, ``talus bench track --final likelihood,likelihood_first``) 52.6 → 46.7
#: evaluations a frame (the stage needs more steps from the prediction) but 7.94 → 7.81 ms a frame after
#: the first, within the runs' spread, and 97 % of frames converged against 99 %
#: (``resources/benchmarks/tracking_bench_stage_first_h100.json``).
STAGE_FIRST = False

#: With a final stage, the ``"newton"`` search's registration uploads the stage's fluence rows while the
#: device works on its first step (:func:`core.tracking.final_stage.stage_prefetch` in :func:`register`'s
#: ``idle`` slot, before the caller's own idle work): the stage's regions at the initial pose grown by
#: :data:`~core.tracking.final_stage.PREFETCH_REACH_MM`, which the stage takes on the device where they
#: cover its regions at the searched pose, else it uploads its own (the same values either way: the same
#: poses, scores and confidences). On one NVIDIA H100 (97b2893, ``stage_one_bone --variants
#: base,prefetch,after``, the talus at 1024², 40 frames, 3 repeats alternated;
#: ``tracking_stage_one_bone_97b2893_h100.json``) one
#: bone's stage took 3.34-4.16 ms a bone-frame with it against 4.30-4.67 without (its set-up 0.42-0.63
#: against 1.05-1.15 ms; every stage took the rows), the frame after the first 7.66-8.97 against
#: 8.58-8.90 ms: on. Joint registration does not prefetch: at f4b86cd, where it did
#: (``joint._prefetching``, since removed), ``talus bench track --cases three --final likelihood`` with the
#: switch off, then on, in one call ran three bones jointly at 44.0 frames/s without it and 38.5 with it
#: (runs 2.19-2.59 s against 2.50-2.62 s; the same poses): its host work sat on the critical path and its
#: copies queued behind the searches' steps on the same stream.
STAGE_PREFETCH = True

#: One bone's registration (the ``"newton"`` and ``"global_newton"`` searches over every view of a
#: :class:`~core.tracking.cost.FrameImages`) puts the whole frame on the device once
#: (:func:`core.tracking.engine_upload.share`, as joint registration does) and its search regions and its
#: final stage's are read there: no pinned copy of either's rows on the host, no prefetch of the stage's
#: rows (:data:`STAGE_PREFETCH` is then skipped), the next frame's pinned copy made ahead in the feed's
#: worker; the same pixels through the same kernels, so the same results to the bit. Off: each uploads its
#: own rows, as before. On since it was timed on one NVIDIA H100 (with :data:`core.tracking.trial.
#: NEXT_FRAME_AHEAD`; ``resources/benchmarks/tracking_share_frame_h100.json``: the benchmark's one bone with
#: the stage, frame_profile's alternated rounds 7.82/6.97/7.78 ms a frame off against 5.88/6.92/5.99 with
#: both, and ``talus bench track --cases one`` 89.6 frames/s off against 128.3 and 125.4 on, the same poses).
#: The global search (``"global_newton"``: a first frame, a retry) shares the frame only before its first
#: full-resolution preparation, its pinned copy made meanwhile beside the CMA-ES stage
#: (:data:`core.tracking.engine_upload.FILL_ASIDE`), and has its next pyramid level's regions made in the view
#: threads during that stage (:data:`core.tracking.engine_frames.PYRAMID_AHEAD`; both timed in
#: ``resources/benchmarks/tracking_first_host_cpu.json``).
SHARE_FRAME = True

def _automatic_levels(mm_px: float, fs: float, sigma, search: str) -> tuple[Level, ...]:
    """:func:`default_levels` at ``mm_px`` (mm per DRR pixel at the final scale ``fs``), scaled by
    ``fs``. The ``"newton"`` search's levels depend on the pixel size only through
    :func:`~core.tracking.register_options.newton_step` (Gauss–Newton steps at full resolution):
    they are made once per (sigma, fs, half-steps) and kept (the same frozen levels; checked as
    default_levels checks its arguments)."""
    if search != "newton":
        return tuple(replace(lv, scale=lv.scale * fs)
                     for lv in default_levels(mm_px, sigma=sigma, search=search))
    if not (np.isfinite(mm_px) and mm_px > 0):
        raise ValueError(f"mm_per_px: expected a positive pixel size, got {mm_px!r}")
    # (the function: a test may patch it; the half-steps and options: coarse pixels', newton_step)
    step, extra = newton_step(mm_px)
    key = (default_levels, tuple(float(a) for a in sigma), float(fs), step, tuple(sorted(extra.items())))
    hit = _LEVELS.get(key)
    if hit is None:
        if len(_LEVELS) >= 16:
            _LEVELS.clear()
        hit = _LEVELS[key] = tuple(replace(lv, scale=lv.scale * fs)
                                   for lv in default_levels(mm_px, sigma=sigma, search=search))
    return hit


_STAGED: dict = {}  # id(levels) -> (levels, key, their before_stage levels) (_staged_levels)


def _staged_levels(levels: tuple, o: RegistrationOptions) -> tuple:
    """``before_stage`` of each of the automatic ``levels`` (kept per levels tuple, the options' final scale
    and the stage's tolerance: the same frozen levels from frame to frame, not made anew each time)."""
    from . import register_options as ro

    key = (before_stage, o.final_scale, ro.STAGE_SEARCH_TOL)
    hit = _STAGED.get(id(levels))
    if hit is not None and hit[0] is levels and hit[1] == key:
        return hit[2]
    out = tuple(before_stage(lv, o) for lv in levels)
    if len(_STAGED) >= 16:
        _STAGED.clear()
    _STAGED[id(levels)] = (levels, key, out)
    return out


def _newton_fallback(mm_per_px: float, coarsest_mm: float = 1.2) -> tuple[Level, ...]:
    """The levels of the ``"newton"`` search's second attempt: Gauss–Newton steps at the
    second-finest pyramid scale (half-steps and trust twice as wide), then at full resolution; at
    a single scale, full resolution with twice the half-steps first (on coarse pixels twice
    :func:`~core.tracking.register_options.newton_step`'s, with its scores' gradient)."""
    fin, extra = newton_step(mm_per_px)
    s = 2.0 if 2.0 * mm_per_px <= coarsest_mm else 1.0
    first = Level(scale=s, method="gauss_newton", sigma=(2 * fin[0], 2 * fin[1]), max_generations=6,
                  tol_x=0.05, options=extra if s == 1.0 else {})
    return first, Level(scale=1.0, method="gauss_newton", sigma=fin, max_generations=8, tol_x=0.02,
                        options=extra)


def search_region(renderer, pose, bone: int, *, views, center, options: RegistrationOptions, outline=None,
                  snap: bool = True) -> np.ndarray:
    """The full-resolution search regions ``(n_views, 4)`` of a registration of ``bone`` about
    ``pose`` (:func:`core.tracking.cost.search_roi` reaching the option's bounds; with ``snap``, on
    the 16-pixel grid the Gauss–Newton engine's buffers keep from frame to frame)."""
    o = options
    return search_roi(renderer, pose, bone, views=views, center=center,
                      reach_mm=o.bounds[0] + math.radians(o.bounds[1]) * 30.0, margin_px=o.margin_px,
                      points=outline, grid=16 if snap else 0)  # (snap_roi's lattice, in the same pass)


def register(renderer, frame: FrameImages, *, bone: int, initial_pose, center,
             options: RegistrationOptions | None = None, views: Sequence[int] | None = None,
             others=None, cancel: Callable[[], bool] | None = None, profile: bool = False,
             x0=None, outline=None, roi=None, tried=None, idle=None) -> RegistrationResult:
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
    idle : callable, optional
        Host work of the caller's that needs nothing of this registration (e.g. the tracker's checks
        prepared ahead): run once, while the device works on the first Gauss–Newton step (on a CUDA
        device the host would otherwise wait there), or, without such a step, before the result is
        made. The same registration.

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
        if search == "newton" and o.final is not None:  # a stage follows: its basin is enough
            levels = _staged_levels(levels, o)
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

    aside = None  # the frame's pinned copy being made aside (engine_upload.fill_aside), shared before a full
    # resolution preparation reads it

    def hold() -> None:
        nonlocal aside
        if aside is not None:
            from . import engine_upload

            a, aside = aside, None
            a.wait()
            engine_upload.share(renderer.device, frame)

    def cost_at(scale: float) -> RegistrationCost:
        if not scale > 1:
            hold()
        if scale not in costs:
            costs[scale] = RegistrationCost(renderer, frame, bone=bone, base_pose=base, center=center,
                                            roi=roi, scale=scale, terms=o.terms, views=views,
                                            others=others, profile=profile)
        return costs[scale]

    def engine_at(scale: float):
        if not scale > 1:
            hold()
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
        nonlocal idle
        sig6 = np.array([lv.sigma[0]] * 3 + [lv.sigma[1]] * 3)
        if lv.method == "gauss_newton":
            from .engine import gauss_newton_search

            kw = dict(lv.options)
            if idle is not None:  # while the device works on the first step
                kw["idle"], idle = idle, None
            r = gauss_newton_search(engine_at(lv.scale), x, step=sig6, lower=lo, upper=hi, tol_x=lv.tol_x,
                                    max_generations=lv.max_generations, cancel=cancel, **kw)
        else:
            # the CMA-ES stage of "global_newton" scores its populations on the engine (the same
            # scores; buffers, pipeline and graph kept from frame to frame, where a RegistrationCost
            # was built per registration)
            fun = engine_at(lv.scale) if (lv.method == "cmaes" and engine_global) else cost_at(lv.scale)
            if lv.method == "cmaes" and engine_global and aside is not None:
                aside.start()  # the frame's pinned copy made while the CMA-ES stage runs (its pyramid made)
            if lv.method == "cmaes" and engine_global and i + 1 < len(levels):
                nxt = levels[i + 1]  # the next level's pyramid made while the CMA-ES stage runs
                if nxt.method == "gauss_newton" and nxt.scale > 1 and nxt.scale not in engines:
                    from .engine_frames import pyramid_ahead

                    pyramid_ahead(frame, views, roi, nxt.scale)
            r = _run(lv.method, fun, x, sigma6=sig6, lo=lo, hi=hi, level=lv, tol=lv.tol_x,
                     seed=o.seed * 1000 + i, cancel=cancel, popsize=lv.popsize, max_gen=lv.max_generations)
        return r

    held = False
    if SHARE_FRAME and search in ("newton", "global_newton") and views == tuple(range(frame.n_views)):
        from . import engine_upload  # the whole frame on the device (one bone's; joint's shared it)

        if engine_global and tried is None and levels[0].scale > 1:  # (the coarse levels read pyramids)
            aside = engine_upload.fill_aside(renderer.device, frame)
        if aside is None:
            held = engine_upload.share(renderer.device, frame) is not None
    try:
        if STAGE_PREFETCH and o.final is not None and search == "newton" and tried is None and not held:
            idle = _with_stage_prefetch(idle, renderer, frame, bone=bone, pose=base, center=center, options=o,
                                        views=views)
        if (STAGE_FIRST and o.final is not None and search == "newton" and o.levels is None and tried is None
                and x0 is None):
            if idle is not None:
                idle, f = None, idle
                f()
            got = _stage_first(renderer, frame, engine_at(fs), bone=bone, base=base, center=center, options=o,
                               views=views, others=others, t_start=t_start)
            if got is not None:
                return got
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
                lv = before_stage(replace(lv, scale=lv.scale * fs), o)
                r = run_level(len(levels) + i, lv, x)
                stages.append(r)
                x = r.x
                if r.reason == "cancelled":
                    break
            levels = (*levels, lv)
        hold()  # (a run that stopped before its full-resolution levels: the frame shared as before the stage)
    except BaseException:  # (a level raised or was cancelled: the copy made aside waited for, the frame
        if aside is not None:  # no longer counted as coming, so no pinned set stays reserved for it)
            a, aside = aside, None
            a.drop()
        raise
    if idle is not None:  # no Gauss-Newton step ran it
        idle, f = None, idle
        f()
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
    return final_stage_idle(renderer, frame, res, bone=bone, initial_pose=base, center=center, options=o,
                        views=views, others=others)


def _with_stage_prefetch(idle, renderer, frame, **kw):
    """:data:`STAGE_PREFETCH`'s idle work: the final stage's fluence rows uploaded
    (:func:`core.tracking.final_stage.stage_prefetch`, keywords ``kw``), then the caller's ``idle``."""

    def work() -> None:
        from .final_stage import stage_prefetch

        stage_prefetch(renderer, frame, **kw)
        if idle is not None:
            idle()

    return work


def _stage_first(renderer, frame, eng, *, bone: int, base, center, options, views, others, t_start: float):
    """:data:`STAGE_FIRST`: the final stage from ``base`` (x = 0) and the similarity at its pose (one
    evaluation on the full-resolution engine ``eng``); None where the stage's move was not taken."""
    from .final_stage import final_stage

    r0 = opt.OptimizeResult(np.zeros(6), float("nan"), 0, 0, 0.0, True, "stage_first", "none", None)
    keys = ("render_s", "metric_s", "host_s", "calls", "evaluations")
    res0 = RegistrationResult(pose=base.copy(), x=np.zeros(6), score=float("nan"),
                              view_scores=np.full(len(views), np.nan), evaluations=0, generations=0,
                              time_s=time.perf_counter() - t_start, converged=True, reason="stage_first",
                              stages=(r0,), timing={k: 0.0 for k in keys}, fit=None)
    st = final_stage(renderer, frame, res0, bone=bone, initial_pose=base, center=center, options=options,
                     views=views, others=others)
    if not (st.timing or {}).get("likelihood_taken"):
        return None
    score, vs = eng.score_and_views(st.x)
    timing = dict(st.timing)
    for k, v in eng.timer.to_dict().items():
        timing[k] = timing.get(k, 0.0) + v
    total = time.perf_counter() - t_start
    timing["total_s"] = total
    timing["optimizer_s"] = max(total - timing["render_s"] - timing["metric_s"] - timing["host_s"]
                                - timing.get("likelihood_s", 0.0), 0.0)
    return replace(st, score=score, view_scores=np.asarray(vs, dtype=float), evaluations=st.evaluations + 1,
                   time_s=total, timing=timing)


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
        if x is last.x and last.method == "gauss_newton":  # its value there (LevenbergMarquardt.result)
            score = float(1.0 - last.fun)
        else:
            score = float(1.0 - last.model.predict(x - last.model.x))
        view_scores = np.asarray(last.model.view_scores, dtype=float)
    else:
        score, view_scores = full.score_and_views(x)
    converged = last.converged and all(s.reason != "cancelled" for s in stages)
    reason = last.reason
    if np.logical_or.reduce(np.abs(x) >= hi * (1 - 1e-6), axis=None):  # (np.any's ufunc)
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
