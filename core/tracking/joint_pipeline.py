"""Joint registration's searches and final stages in one pipeline (:func:`run_pipelined`).

:func:`core.tracking.joint.register_together` runs the bones' Gauss–Newton searches side by side and,
with a final stage (``RegistrationOptions.final``), the bones' stages side by side after them
(:func:`core.tracking.final_stage.final_stages`). Run one after the other, the two loops meet at a
barrier: the host waits for the last search's step while it has nothing else to do, and the first
stage's set-up (its regions, fluence and neighbours on the host, about a millisecond a bone at 1024²)
then runs while the device has nothing to do. Here each bone's stage starts as soon as its own search
has ended — its set-up and first step enqueued while the device still works on the other bones'
search steps — and one loop takes, in the order they were enqueued, both the searches' steps and the
stages' (each stage a generator of :func:`~core.tracking.final_stage.final_stage_steps` that yields
where it would wait for the device, as :func:`~core.tracking.engine_likelihood.run_side_by_side`
drives them).

The same values: a bone's stage starts from its own search's result and its neighbours at the poses
the round began with, whatever the other bones' searches do; each
search and each stage works on its own engine and buffers, the device in the order of one stream, a
stage keeping its own copy of the rendered images (``side_by_side``) as it does among the other
stages. A bone whose search did not converge goes on with the half-resolution fallback of
:func:`~core.tracking.register.register` after the loop (before, the stages waited for it; the same
values: its engines are its own). Used where ``final_stages`` and ``final_stage`` are the module's own
functions, told by identity (a study's wrapper sees every call: then as before; one that only times the
calls and passes them on unchanged, marked with :func:`timing_only`, is looked through), and every job's
bone differs.
"""

from __future__ import annotations

import time
from collections.abc import Callable

__all__ = ["PIPELINED_STAGES", "applies", "run_pipelined", "timing_only"]

#: Run joint registration's searches and final stages in one pipeline (module docs); off: the stages
#: after every search, side by side (as before).
PIPELINED_STAGES = True


def timing_only(wrapper: Callable) -> Callable:
    """Mark ``wrapper`` — a study's :func:`functools.wraps` wrapper of ``final_stages`` that passes every
    call on unchanged (its ``__wrapped__`` the function it calls), timing it — as one :func:`applies`
    looks through; returns it."""
    wrapper._timing_only = True
    return wrapper


def _own(f, own) -> bool:
    """Whether ``f`` is ``own``, or wrappers marked :func:`timing_only` around it."""
    while f is not own:
        if not getattr(f, "_timing_only", False):
            return False
        f = getattr(f, "__wrapped__", None)
    return True


def applies(jobs) -> bool:
    """Whether :func:`run_pipelined` gives what the searches then ``final_stages`` give: the switch
    on, the final stage module's own ``final_stages`` (by identity; a :func:`timing_only` wrapper of it
    looked through) and ``final_stage`` (no study's wrapper), every job's bone its own."""
    if not PIPELINED_STAGES:
        return False
    from . import final_stage as fst

    return (fst.final_stage is fst._PLAIN_FINAL_STAGE and _own(fst.final_stages, fst._PLAIN_FINAL_STAGES)
            and len({int(j.bone) for j in jobs}) == len(jobs))


def run_pipelined(renderer, frame, jobs, o, lanes: dict, queue: list, out: list, *, t_loop: float, fs: float,
                  hi, views, submit: Callable, collect: Callable, result: Callable, cancel=None,
                  profile: bool = False, idle: Callable[[], None] | None = None,
                  done: Callable[[int, object], None] | None = None) -> list:
    """The searches of ``lanes`` (``k`` → the lane of ``jobs[k]``; ``queue``: the lanes with a step in
    flight, in the order enqueued) to their ends, each converged bone's final stage started there,
    every step taken as it comes (module docs); fills and returns ``out`` (per job its
    :class:`~core.tracking.register.RegistrationResult` or the OutsideViewError raised).
    ``submit``, ``collect``, ``result``: :mod:`core.tracking.joint`'s ``_submit``, ``_collect`` and
    ``_result``; ``idle``: the caller's host work, called before each wait for a search's step;
    ``done(k, result)``: the caller's host work on a stage's result, called as the stage ends while
    other steps are in flight (the checks of :mod:`core.tracking.frame_step`)."""
    from .cost import OutsideViewError
    from .final_stage import final_stage_steps
    from .likelihood_steps import StepClock
    from .register import register

    n = max(len(lanes), 1)
    todo = [("s", k) for k in queue]  # the steps in flight: ("s", lane) a search's, ("g", k) a stage's
    gens: dict = {}
    clocks: dict = {}
    fallback: list = []
    errors: dict = {}

    def advance(k: int) -> None:  # a stage's host work up to its next wait (run_side_by_side's clock)
        c = clocks[k]
        t = time.perf_counter()
        c.t = t
        try:
            next(gens[k])
            todo.append(("g", k))
        except StopIteration as stop:
            out[k] = stop.value
            if done is not None and todo:  # (the other steps in flight meanwhile)
                done(k, out[k])
        finally:
            c.spent += time.perf_counter() - t
            c.t = time.perf_counter()

    def ended(k: int) -> None:  # a search at its end: its stage started, or the fallback noted
        ln = lanes[k]
        r = ln.lm.result()
        ln.stages.append(r)
        spent = ln.own_s + (time.perf_counter() - t_loop) / n
        if not (r.converged or r.reason == "cancelled"):
            fallback.append((k, r, spent))
            return
        job = jobs[k]  # the stage with the neighbours at this round's poses (final_stages' call)
        clocks[k] = c = StepClock()
        c.spent = 0.0
        gens[k] = final_stage_steps(renderer, frame, result(ln, fs, hi, ln.cost, spent), bone=job.bone,
                                    initial_pose=job.initial_pose, center=job.center, options=o, views=views,
                                    others=job.others, clock=c, side_by_side=True)
        advance(k)

    flying = {k for _, k in todo}
    for k in lanes:  # (a search that ended before its first step)
        if k not in flying:
            ended(k)
    while todo:
        kind, k = todo.pop(0)
        if kind == "g":
            advance(k)
            continue
        if idle is not None:
            idle()
        ln = lanes[k]
        try:
            ev = collect(ln)
        except OutsideViewError as exc:
            errors[k] = exc
            continue
        ln.lm.tell(ln.cost.newton(ln.x, ln.lm.h, ev))
        if submit(ln, cancel):
            todo.append(("s", k))
        else:
            ended(k)
    for k, exc in errors.items():
        out[k] = exc
    for k, r, spent in fallback:  # beyond the full-resolution steps' reach (register_together's fallback)
        job = jobs[k]
        try:
            out[k] = register(renderer, frame, bone=job.bone, initial_pose=job.initial_pose,
                              center=job.center, options=o, others=job.others, cancel=cancel, profile=profile,
                              outline=job.outline, roi=job.roi, tried=(r, lanes[k].cost, spent))
        except OutsideViewError as exc:
            out[k] = exc
    return out
