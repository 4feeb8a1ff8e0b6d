"""Several bones' Gauss–Newton registrations in lockstep (joint tracking's rounds).

In a round of joint tracking (:func:`core.tracking.trial.track`, ``mode="joint"``) every bone is
registered with its neighbours' DRRs subtracted. With the Gauss–Newton search
(``search="newton"``) :func:`register_together` runs those registrations side by side: each
bone's fluoroscope regions are prepared (its neighbours subtracted at the poses the round
started from), then every bone's 13-pose step (one DRR launch, one metric graph) is enqueued,
and the host takes the bones' results in turn, each as soon as its own step is done (an event
recorded after it): its Levenberg–Marquardt state
(:class:`~core.tracking.engine_search.LevenbergMarquardt`) takes the step and its next step is
enqueued while the device works on the other bones' steps — the device is kept busy and the
host's arithmetic overlaps it, where one bone after another left the device idle while the host
worked and the host idle while the device did. A bone's iterates are those of
:func:`core.tracking.register.register` with the same inputs (the same search, the same
engine); only the waits are shared. Where the full-resolution steps do not
converge, that bone is registered again by :func:`~core.tracking.register.register` (its
half-resolution fallback).

:func:`restarts_together` runs several searches of one bone in one frame the same way (the
restarts of :func:`core.tracking.verify.verify_start`), each on a sibling of the engine that
shares the regions prepared once.

The bones of a round all start from the estimates the round began with (the previous round's,
or the guesses), where the one-after-another rounds let a bone see the poses its predecessors
had just found in the same round; the second round sees every bone's first-round pose either
way.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import warp as wp

from .cost import CostTimer, OutsideViewError, search_roi
from .engine import engine_cost, step_design, supports
from .engine_search import LevenbergMarquardt
from .register import RegistrationOptions, RegistrationResult, _snap, default_levels, result_of

__all__ = ["JointJob", "lockstep_applies", "register_together", "restarts_together"]


@dataclass
class JointJob:
    """One bone's registration in a round: volume ``bone`` of the renderer from
    ``initial_pose`` (the search box's centre), rotation ``center``, ``outline`` (bone-frame
    points for the ROIs) and ``others`` (poses, bones) subtracted."""

    bone: int
    initial_pose: np.ndarray
    center: np.ndarray
    outline: np.ndarray | None = None
    others: tuple | None = None


def lockstep_applies(options: RegistrationOptions) -> bool:
    """Whether :func:`register_together` runs these options (the automatic ``"newton"`` search of
    a cost the engine scores, no refinement)."""
    return (options.search == "newton" and options.levels is None and options.refine is None
            and supports(options.terms))


@dataclass
class _Lane:
    job: JointJob
    cost: object
    lm: LevenbergMarquardt
    lo: np.ndarray
    hi: np.ndarray
    own_s: float  # the bone's own set-up time
    x: np.ndarray | None = None
    event: object = None  # recorded after the bone's step in flight (CUDA)


def _submit(ln: _Lane, cancel) -> bool:
    """Enqueue the next step of a bone's search (and record its event); False when it has ended."""
    x = ln.lm.ask(cancel)
    if x is None:
        return False
    ln.x = x
    ln.cost.submit(step_design(x, ln.lm.h))
    dev = ln.cost.device
    if dev.is_cuda:
        if ln.event is None:
            ln.event = wp.Event(dev)
        wp.record_event(ln.event)
    return True


def register_together(renderer, frame, jobs: Sequence[JointJob], options: RegistrationOptions, *,
                      profile: bool = False, cancel: Callable[[], bool] | None = None) -> list:
    """Register every job in ``frame`` (module docs); per job a
    :class:`~core.tracking.register.RegistrationResult`, or the
    :class:`~core.tracking.cost.OutsideViewError` its registration raised."""
    from .register import register

    if not lockstep_applies(options):
        raise ValueError("options: register_together runs the automatic 'newton' search of a gc or ncc cost")
    o = options
    fs = o.final_scale
    views = tuple(range(frame.n_views))
    out: list = [None] * len(jobs)
    lanes: dict[int, _Lane] = {}
    queue: list[int] = []
    for k, job in enumerate(jobs):
        t0 = time.perf_counter()
        base = np.asarray(job.initial_pose, dtype=float)
        center = np.asarray(job.center, dtype=float)
        # the single Gauss-Newton level of "newton" (default_levels does not depend on the pixel size there)
        lv = default_levels(1.0, sigma=o.sigma, search="newton")[-1]
        try:
            roi = search_roi(renderer, base, job.bone, views=views, center=center,
                             reach_mm=o.bounds[0] + math.radians(o.bounds[1]) * 30.0, margin_px=o.margin_px,
                             points=job.outline)
            roi = _snap(roi, renderer, views)
            c = engine_cost(renderer, bone=job.bone, views=views, scale=lv.scale * fs, term=o.terms[0])
            c.timer = CostTimer()
            c.batches = {}
            c.profile = profile
            c.set_frame(frame, base_pose=base, center=center, roi=roi, others=job.others)
        except OutsideViewError as exc:
            out[k] = exc
            continue
        hi = np.array([o.bounds[0]] * 3 + [o.bounds[1]] * 3, dtype=float)
        sig6 = np.array([lv.sigma[0]] * 3 + [lv.sigma[1]] * 3)
        lm = LevenbergMarquardt(np.zeros(6), step=sig6, lower=-hi, upper=hi, tol_x=lv.tol_x,
                                max_generations=lv.max_generations)
        lanes[k] = ln = _Lane(job, c, lm, -hi, hi, time.perf_counter() - t0)
        # the bone's first step in flight while the next bone's regions are prepared
        if _submit(ln, cancel):
            queue.append(k)
        ln.own_s = time.perf_counter() - t0
    t_loop = time.perf_counter()
    # the host takes each bone's result as soon as its own step is done (its event) and enqueues
    # its next step while the device works on the other bones' steps
    while queue:
        k = queue.pop(0)
        ln = lanes[k]
        try:
            ev = _collect(ln)
        except OutsideViewError as exc:
            out[k] = exc
            del lanes[k]
            continue
        ln.lm.tell(ln.cost.newton(ln.x, ln.lm.h, ev))
        if _submit(ln, cancel):
            queue.append(k)
    share = (time.perf_counter() - t_loop) / max(len(lanes), 1)  # the shared iterations, split evenly
    for k, ln in lanes.items():
        r = ln.lm.result()
        if r.converged or r.reason == "cancelled":
            out[k] = _result(ln, r, fs, ln.own_s + share)
        else:  # beyond the full-resolution steps' reach: the one-bone search with its fallback
            job = ln.job
            try:
                out[k] = register(renderer, frame, bone=job.bone, initial_pose=job.initial_pose,
                                  center=job.center, options=o, others=job.others, cancel=cancel,
                                  profile=profile, outline=job.outline)
            except OutsideViewError as exc:
                out[k] = exc
    return out


def _collect(ln):
    """The evaluation of a lane's (or restart's) step in flight, once its event has completed (the
    wait counted as metric time)."""
    t0 = time.perf_counter()
    if ln.event is not None:
        wp.synchronize_event(ln.event)
    ln.cost.timer.metric += time.perf_counter() - t0
    return ln.cost.collect()


def _result(ln: _Lane, r, fs: float, spent: float) -> RegistrationResult:
    """The :class:`~core.tracking.register.RegistrationResult` that
    :func:`~core.tracking.register.register` builds from a converged (or cancelled) single
    Gauss-Newton level; ``spent``: the bone's wall time."""
    return result_of((r,), r.x, ln.cost, ln.hi, model_score=True, timers=(ln.cost,),
                     engines={fs: ln.cost}, fit=r.model, t_start=time.perf_counter() - spent)


@dataclass
class _Restart:
    k: int
    xs: np.ndarray  # the start of the current level
    li: int = 0
    lm: LevenbergMarquardt | None = None
    cost: object = None
    x: np.ndarray | None = None
    event: object = None
    stages: list | None = None
    costs: dict | None = None  # scale -> this search's sibling cost


def restarts_together(renderer, frame, *, bone: int, base, center, x0s, options: RegistrationOptions,
                      views: Sequence[int] | None = None, others=None, outline=None, profile: bool = False,
                      cancel: Callable[[], bool] | None = None) -> list[RegistrationResult]:
    """Several registrations of one bone in one frame from the same ``base`` (the search box's
    centre) and the starts ``x0s`` (mm, degrees), ``options.levels`` all Gauss–Newton levels:
    per start the :class:`~core.tracking.register.RegistrationResult` of
    :func:`~core.tracking.register.register` ``(..., initial_pose=base, x0=x0)``, the searches
    in lockstep on siblings of the engine (:meth:`~core.tracking.engine.GaussNewtonCost.sibling`:
    the regions prepared once per level). Raises OutsideViewError like
    :func:`~core.tracking.register.register`."""
    o = options
    levels = tuple(o.levels or ())
    if not levels or any(lv.method != "gauss_newton" for lv in levels) or o.refine is not None \
            or not supports(o.terms):
        raise ValueError("options: restarts_together runs given Gauss-Newton levels of a gc or ncc cost")
    t_start = time.perf_counter()
    base = np.asarray(base, dtype=float)
    center = np.asarray(center, dtype=float)
    views = tuple(range(frame.n_views)) if views is None else tuple(views)
    fs = o.final_scale
    roi = search_roi(renderer, base, bone, views=views, center=center,
                     reach_mm=o.bounds[0] + math.radians(o.bounds[1]) * 30.0, margin_px=o.margin_px,
                     points=outline)
    roi = _snap(roi, renderer, views)
    hi = np.array([o.bounds[0]] * 3 + [o.bounds[1]] * 3, dtype=float)
    lo = -hi
    engines: dict = {}

    def engine_at(scale: float):
        if scale not in engines:  # prepared once for every search
            c = engine_cost(renderer, bone=bone, views=views, scale=scale, term=o.terms[0])
            c.timer = CostTimer()
            c.batches = {}
            c.profile = profile
            c.set_frame(frame, base_pose=base, center=center, roi=roi, others=others)
            engines[scale] = c
        return engines[scale]

    def start_level(ln: _Restart) -> None:
        lv = levels[ln.li]
        ln.cost = ln.costs[lv.scale] = engine_at(lv.scale).sibling(ln.k)
        sig6 = np.array([lv.sigma[0]] * 3 + [lv.sigma[1]] * 3)
        ln.lm = LevenbergMarquardt(ln.xs, step=sig6, lower=lo, upper=hi, tol_x=lv.tol_x,
                                   max_generations=lv.max_generations, **dict(lv.options))

    lanes = [_Restart(k, np.clip(np.asarray(x0, dtype=float), lo, hi), stages=[], costs={})
             for k, x0 in enumerate(x0s)]
    queue: list[int] = []

    def push(k: int) -> None:
        """Enqueue lane ``k``'s next step; a search that has ended moves on to the next level."""
        ln = lanes[k]
        while True:
            if _submit(ln, cancel):
                queue.append(k)
                return
            r = ln.lm.result()
            ln.stages.append(r)
            ln.xs = np.asarray(r.x, dtype=float)
            if r.reason == "cancelled" or ln.li == len(levels) - 1:
                return
            ln.li += 1
            start_level(ln)

    for ln in lanes:
        start_level(ln)
        push(ln.k)
    while queue:
        k = queue.pop(0)
        ln = lanes[k]
        ev = _collect(ln)
        ln.lm.tell(ln.cost.newton(ln.x, ln.lm.h, ev))
        push(k)
    share = (time.perf_counter() - t_start) / max(len(lanes), 1)
    return [_restart_result(ln, levels, fs, hi, engine_at, share) for ln in lanes]


def _restart_result(ln: _Restart, levels, fs: float, hi: np.ndarray, engine_at, spent: float):
    """What :func:`~core.tracking.register.register` returns for the stages of one restart."""
    t_start = time.perf_counter() - spent
    last = ln.stages[-1]
    full = ln.costs.get(fs)
    if full is None:  # ended before the full-resolution level (cancelled)
        full = ln.costs[fs] = engine_at(fs).sibling(ln.k)
    last_gn = levels[-1].scale == fs
    return result_of(ln.stages, last.x, full, hi, model_score=last_gn, timers=ln.costs.values(),
                     engines=ln.costs, fit=last.model if (last.model is not None and last_gn) else None,
                     t_start=t_start)
