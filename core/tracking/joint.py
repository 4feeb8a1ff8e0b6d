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
converge, that bone goes on with the half-resolution fallback of
:func:`~core.tracking.register.register` (``tried``: the full-resolution steps already taken are
not taken again). A job's search regions are filled in (:attr:`JointJob.roi`), so that the
round after keeps them.

:func:`restarts_together` runs several searches of one bone in one frame the same way (the
restarts of :func:`core.tracking.verify.verify_start`), each on a sibling of the engine that
shares the regions prepared once.

The bones of a round all start from the estimates the round began with (the previous round's,
or the guesses), where the one-after-another rounds let a bone see the poses its predecessors
had just found in the same round; the second round sees every bone's first-round pose either
way. With one round (``TrackingOptions.joint_rounds``' default since 8dbdcc2) none does: in lockstep
every bone, and its final stage, subtracts its neighbours at their predictions.

A first frame's bones (no tracked pose yet) are registered here from the first frame's second round on:
round 0 registers them one after another. The second round subtracts every neighbour at its round-0 pose,
so the error of the bone registered first (nothing subtracted) goes into the others' second round (the
talus of the three-bone 128² scene 0.11-0.12° off); the bones whose neighbours moved in it are registered
here once more, the neighbours at their new poses (0.003-0.005°;
:data:`core.tracking.frame_step.FIRST_FRAME_AGAIN_MOVED`). One bone at a time instead, as sequential
tracking's second pass (:data:`~core.tracking.frame_step.FIRST_FRAME_AS_PASS`, off: 0.004-0.006°), the
first frame took twice as long at 1024² on one NVIDIA H100.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import warp as wp

from . import engine_upload, joint_pipeline
from .cost import CostTimer, OutsideViewError, mm_per_pixel
from .engine import engine_cost, step_design, supports
from .engine_search import LevenbergMarquardt
from .register import (
    RegistrationOptions,
    RegistrationResult,
    before_stage,
    default_levels,
    result_of,
    search_region,
)

__all__ = ["JointJob", "lockstep_applies", "register_together", "restarts_together"]


@dataclass
class JointJob:
    """One bone's registration in a round: volume ``bone`` of the renderer from
    ``initial_pose`` (the search box's centre), rotation ``center``, ``outline`` (bone-frame
    points for the ROIs) and ``others`` (poses, bones) subtracted. ``roi``: the search regions
    (full-resolution ``(u0, v0, w, h)`` per view); None: computed about ``initial_pose`` as
    :func:`~core.tracking.register.register` computes them, and filled in here (joint tracking's
    second round keeps the first round's: the bone moved little, and its neighbours' poses are
    what changed)."""

    bone: int
    initial_pose: np.ndarray
    center: np.ndarray
    outline: np.ndarray | None = None
    others: tuple | None = None
    roi: np.ndarray | None = None


def lockstep_applies(options: RegistrationOptions) -> bool:
    """Whether :func:`register_together` runs these options (the automatic ``"newton"`` search of
    a cost the engine scores, no refinement)."""
    return (options.search == "newton" and options.levels is None and options.refine is None
            and supports(options.terms))


@dataclass
class _Search:
    """One Levenberg–Marquardt search of a bone's lane (:func:`register_together`) or of a restart
    (:func:`restarts_together`), level after level: the current level ``li`` of ``levels``, its
    state ``lm`` and cost, the start ``xs`` of the level, the stages done and the cost per scale."""

    k: int
    xs: np.ndarray
    levels: tuple = ()
    li: int = 0
    lm: LevenbergMarquardt | None = None
    cost: object = None
    x: np.ndarray | None = None
    event: object = None  # recorded after the step in flight (CUDA)
    stages: list = field(default_factory=list)
    costs: dict = field(default_factory=dict)  # scale -> this search's cost
    own_s: float = 0.0  # a lane's own set-up time


def _submit(ln: _Search, cancel) -> bool:
    """Enqueue the next step of a search (and record its event); False when it has ended."""
    x = ln.lm.ask(cancel)
    if x is None:
        return False
    ln.x = x
    ln.cost.submit(step_design(x, ln.lm.h))
    dev = ln.cost.device
    if dev.is_cuda:
        if ln.event is None:
            ln.event = wp.Event(dev)
        dev.stream.record_event(ln.event)  # (the stream the step went on)
    return True


def _collect(ln: _Search):
    """The evaluation of a search's step in flight, once its event has completed (the wait
    counted as metric time)."""
    t0 = time.perf_counter()
    if ln.event is not None:
        wp.synchronize_event(ln.event)
    ln.cost.timer.metric += time.perf_counter() - t0
    return ln.cost.collect()


def _drive(searches, queue: list, push: Callable[[int], None], errors: dict | None = None,
           idle: Callable[[], None] | None = None) -> None:
    """The host's loop: take each search's step as soon as its own step is done (its event),
    tell it, and ``push`` it on (its next step enqueued while the device works on the other
    searches' steps). With ``errors``, a search whose step raised OutsideViewError ends there
    (the error kept under its key); otherwise the error propagates. ``idle``: host work of the
    caller's, called before each wait (while the device works on the steps in flight)."""
    while queue:
        if idle is not None:
            idle()
        k = queue.pop(0)
        ln = searches[k]
        try:
            ev = _collect(ln)
        except OutsideViewError as exc:
            if errors is None:
                raise
            errors[k] = exc
            continue
        ln.lm.tell(ln.cost.newton(ln.x, ln.lm.h, ev))
        push(k)


def _result(ln: _Search, fs: float, hi: np.ndarray, full, spent: float) -> RegistrationResult:
    """What :func:`~core.tracking.register.register` returns for the stages of a search (``full``:
    its full-resolution cost; ``spent``: its wall time)."""
    last = ln.stages[-1]
    last_gn = ln.levels[ln.li].scale == fs  # the level of the last stage
    return result_of(ln.stages, last.x, full, hi, model_score=last_gn, timers=ln.costs.values(),
                     engines=ln.costs, fit=last.model if (last.model is not None and last_gn) else None,
                     t_start=time.perf_counter() - spent)


def register_together(renderer, frame, jobs: Sequence[JointJob], options: RegistrationOptions, *,
                      profile: bool = False, cancel: Callable[[], bool] | None = None,
                      idle: Callable[[], None] | None = None,
                      done: Callable[[int, object], None] | None = None) -> list:
    """Register every job in ``frame`` (module docs); per job a
    :class:`~core.tracking.register.RegistrationResult`, or the
    :class:`~core.tracking.cost.OutsideViewError` its registration raised. Jobs without
    ``roi`` get theirs filled in. ``idle``: host work of the caller's that uses neither the
    device nor these bones' engines, called before each wait for a step (a piece at a time: the
    previous round's checks, :mod:`core.tracking.frame_step`). ``done(k, result)``: host work of the
    caller's on job ``k``'s result, called where that result is final while other jobs' steps are
    still in flight (the stages in one pipeline, :mod:`core.tracking.joint_pipeline`; the caller
    still gets every result in the list)."""
    from .final_stage import final_stages
    from .register import register

    if not lockstep_applies(options):
        raise ValueError("options: register_together runs the automatic 'newton' search of a gc or ncc cost")
    o = options
    fs = o.final_scale
    views = tuple(range(frame.n_views))
    hi = np.array([o.bounds[0]] * 3 + [o.bounds[1]] * 3, dtype=float)
    out: list = [None] * len(jobs)
    lanes: dict[int, _Search] = {}
    queue: list[int] = []

    def push(k: int) -> None:
        if _submit(lanes[k], cancel):
            queue.append(k)

    if len(jobs) > 1:  # the whole frame on the device once, every bone's regions read there (engine_upload)
        engine_upload.share(renderer.device, frame)
    for k, job in enumerate(jobs):
        t0 = time.perf_counter()
        base = np.asarray(job.initial_pose, dtype=float)
        center = np.asarray(job.center, dtype=float)
        try:
            if job.roi is None:
                job.roi = search_region(renderer, base, job.bone, views=views, center=center, options=o,
                                        outline=job.outline)
            c = engine_cost(renderer, bone=job.bone, views=views, scale=fs, term=o.terms[0])
            c.timer = CostTimer()
            c.batches = {}
            c.profile = profile
            px = mm_per_pixel(renderer, base, center, views)
            c.set_frame(frame, base_pose=base, center=center, roi=job.roi, others=job.others, px_mm=px)
        except OutsideViewError as exc:
            out[k] = exc
            continue
        # the single Gauss-Newton level of "newton" (wider half-steps on coarse pixels, newton_step)
        # (with a final stage after it, its looser tolerance: before_stage)
        lv = before_stage(replace(default_levels(px * fs, sigma=o.sigma, search="newton")[-1], scale=fs), o)
        sig6 = np.array([lv.sigma[0]] * 3 + [lv.sigma[1]] * 3)
        lm = LevenbergMarquardt(np.zeros(6), step=sig6, lower=-hi, upper=hi, tol_x=lv.tol_x,
                                max_generations=lv.max_generations, **dict(lv.options))
        lanes[k] = _Search(k, np.zeros(6), (lv,), lm=lm, cost=c, costs={fs: c})
        push(k)  # the bone's first step in flight while the next bone's regions are prepared
        lanes[k].own_s = time.perf_counter() - t0
    t_loop = time.perf_counter()
    if o.final is not None and joint_pipeline.applies(jobs):  # each bone's stage from its search's end
        return joint_pipeline.run_pipelined(renderer, frame, jobs, o, lanes, queue, out, t_loop=t_loop,
                                            fs=fs, hi=hi, views=views, submit=_submit, collect=_collect,
                                            result=_result, cancel=cancel, profile=profile, idle=idle,
                                            done=done)
    errors: dict = {}
    _drive(lanes, queue, push, errors, idle)
    share = (time.perf_counter() - t_loop) / max(len(lanes), 1)  # the shared iterations, split evenly
    staged: list = []  # the converged bones' final stages, run side by side (final_stages)
    for k, ln in lanes.items():
        if k in errors:
            out[k] = errors[k]
            continue
        r = ln.lm.result()
        ln.stages.append(r)
        if r.converged or r.reason == "cancelled":
            job = jobs[k]  # with the option's final stage (neighbours at this round's poses)
            staged.append((k, (_result(ln, fs, hi, ln.cost, ln.own_s + share),
                               {"bone": job.bone, "initial_pose": job.initial_pose, "center": job.center,
                                "options": o, "views": views, "others": job.others})))
            continue
        # beyond the full-resolution steps' reach: the one-bone search's half-resolution fallback,
        # from these full-resolution steps (not taken again)
        job = jobs[k]
        try:
            out[k] = register(renderer, frame, bone=job.bone, initial_pose=job.initial_pose,
                              center=job.center, options=o, others=job.others, cancel=cancel,
                              profile=profile, outline=job.outline, roi=job.roi,
                              tried=(r, ln.cost, ln.own_s + share))
        except OutsideViewError as exc:
            out[k] = exc
    for (k, _), res in zip(staged, final_stages(renderer, frame, [c for _, c in staged]), strict=True):
        out[k] = res
    return out


def restarts_together(renderer, frame, *, bone: int, base, center, x0s, options: RegistrationOptions,
                      views: Sequence[int] | None = None, others=None, outline=None, profile: bool = False,
                      cancel: Callable[[], bool] | None = None,
                      settle: tuple[float, float] | None = None) -> list[RegistrationResult]:
    """Several registrations of one bone in one frame from the same ``base`` (the search box's
    centre) and the starts ``x0s`` (mm, degrees), ``options.levels`` all Gauss–Newton levels:
    per start the :class:`~core.tracking.register.RegistrationResult` of
    :func:`~core.tracking.register.register` ``(..., initial_pose=base, x0=x0)``, the searches
    in lockstep on siblings of the engine (:meth:`~core.tracking.engine.GaussNewtonCost.sibling`:
    the regions prepared once per level). Raises OutsideViewError like
    :func:`~core.tracking.register.register`.

    ``settle`` (mm, degrees): a search whose level before the last converges within it of
    ``base`` stops there (the restarts of :func:`core.tracking.verify.verify_start`: one that
    came back to the checked pose would end on the checked optimum at full resolution too; the
    check needs only its score, which the full-resolution cost gives at the point where it
    stopped, one launch instead of its full-resolution steps)."""
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
    roi = search_region(renderer, base, bone, views=views, center=center, options=o, outline=outline)
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

    def start_level(ln: _Search) -> None:
        lv = levels[ln.li]
        ln.cost = ln.costs[lv.scale] = engine_at(lv.scale).sibling(ln.k)
        sig6 = np.array([lv.sigma[0]] * 3 + [lv.sigma[1]] * 3)
        ln.lm = LevenbergMarquardt(ln.xs, step=sig6, lower=lo, upper=hi, tol_x=lv.tol_x,
                                   max_generations=lv.max_generations, **dict(lv.options))

    searches = [_Search(k, np.clip(np.asarray(x0, dtype=float), lo, hi), levels) for k, x0 in enumerate(x0s)]
    queue: list[int] = []

    def push(k: int) -> None:
        """Enqueue search ``k``'s next step; a search that has ended moves on to the next level."""
        ln = searches[k]
        while True:
            if _submit(ln, cancel):
                queue.append(k)
                return
            r = ln.lm.result()
            ln.stages.append(r)
            ln.xs = np.asarray(r.x, dtype=float)
            if r.reason == "cancelled" or ln.li == len(levels) - 1:
                return
            if (settle is not None and r.converged and np.linalg.norm(ln.xs[:3]) <= settle[0]
                    and np.linalg.norm(ln.xs[3:]) <= settle[1]):
                return  # back at the checked pose
            ln.li += 1
            start_level(ln)

    for ln in searches:
        start_level(ln)
        push(ln.k)
    _drive(searches, queue, push)
    share = (time.perf_counter() - t_start) / max(len(searches), 1)
    out = []
    for ln in searches:
        full = ln.costs.get(fs)
        if full is None:  # ended before the full-resolution level (settled, cancelled)
            full = ln.costs[fs] = engine_at(fs).sibling(ln.k)
        out.append(_result(ln, fs, hi, full, share))
    return out
