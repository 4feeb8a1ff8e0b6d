"""Joint tracking's final stages with the neighbours at this frame's searched poses
(:data:`core.tracking.frame_step.STAGE_AT_SEARCHED`, off by default).

In a lockstep round (:func:`core.tracking.joint.register_together`) every bone's similarity search
runs to its end before any final stage; the stages then run side by side
(:func:`core.tracking.final_stage.final_stages`), each subtracting its neighbours at the poses the
round began with — with one round (the default since 8dbdcc2) their constant-velocity predictions.
Inside :func:`searched_stages` each side-by-side stage subtracts instead, for a neighbour staged in
the same call, the pose that neighbour's own search found in this frame (:func:`searched_others`);
a neighbour not staged there (its search fell back to half resolution, which runs its own stage)
keeps its pose, as do retried registrations and the stage-move check's confirmation.

The switch is a context variable read by a wrapper of :func:`~core.tracking.final_stage.final_stages`
put into that module the first time the block is entered (``register_together`` looks the function
up at each call); outside the block, or in another thread, the wrapper passes the calls on unchanged.
Its natural home is ``register_together`` itself (the stage's ``others`` of each job); it lives here,
as a wrapper, so that ``register_together`` stays unchanged while the switch is off.

Off by default. At 1024² (one NVIDIA H100, the acceptance study with ``--final likelihood`` at 9c2906d,
``resources/benchmarks/tracking_acceptance_seed{0,3,4}_final_searched_9c2906d_h100.json`` against
``…_final_c7320cb_h100.json``) it took seed 4's silent tibia frames jointly from 2 to 1 (the tibia's
rotation 1.89 → 1.83× its bound), moved seed 0's ratios by at most 0.02, but gave seed 3's tibia 2 silent
frames jointly where it had none. At 512² the measurement was mixed too
(:mod:`core.studies.tracking.stage_neighbours`, acceptance scene at 512², 1 mm voxels, seed 4 frames
84-95 and 0-9, seed 0 frames 40-51; this 2-core x86_64
machine, shared; ``resources/benchmarks/tracking_stage_neighbours_cpu.json``). Over the three stretches
it cut the frames over 4× the bound left unflagged from 4 to 2 and the joint-against-sequential
comparisons that missed the acceptance margin from 2 to 0 (seed 4's calcaneus 3.03 / 1.81 → 2.80 / 1.71 ×
its bound, mm / °), but seed 4's talus rotation got worse (1.65 → 1.74 ×; paired +0.021°
[+0.008, +0.039]), as it did with the search's older 0.25 tolerance, and the tibia's first frames a
little (+0.0009 mm, +0.005°). Single noise draws; the 1024² run decides.
"""

from __future__ import annotations

import threading
from contextlib import contextmanager
from contextvars import ContextVar

import numpy as np

__all__ = ["searched_others", "searched_stages"]

_ON: ContextVar = ContextVar("joint_stage_searched", default=False)
_INSTALL = threading.Lock()  # (two threads entering the block at once: one wrapper, not one around another)


def searched_others(calls, poses=None) -> list:
    """``calls`` of :func:`~core.tracking.final_stage.final_stages` (per bone ``(res, kwargs)``) with
    each call's ``others`` poses replaced, for a neighbour that is one of the calls' bones, by that
    bone's ``res.pose`` (its search's pose in this frame; ``poses``: the calls' bones' poses to use
    instead, in the calls' order); other neighbours keep theirs. The input is not changed."""
    poses = [res.pose for res, _ in calls] if poses is None else poses
    found = {int(kw["bone"]): np.asarray(P, dtype=float) for (_, kw), P in zip(calls, poses, strict=True)}
    out = []
    for res, kw in calls:
        oth = kw.get("others")
        if oth is not None:
            P = np.asarray(oth[0], dtype=float).reshape(-1, 4, 4)
            ids = list(oth[1])
            kw = {**kw, "others": (np.stack([found.get(int(b), P[j]) for j, b in enumerate(ids)]), ids)}
        out.append((res, kw))
    return out


def _install() -> None:
    from . import final_stage as fst

    with _INSTALL:
        if getattr(fst.final_stages, "_searched_switch", False):
            return
        plain = fst.final_stages

        def final_stages(renderer, frame, calls):
            return plain(renderer, frame, searched_others(calls) if _ON.get() else calls)

        final_stages.__doc__ = plain.__doc__
        final_stages._searched_switch = True
        final_stages._plain = plain  # (off, the calls pass to it unchanged: joint_pipeline.applies)
        fst.final_stages = final_stages


@contextmanager
def searched_stages(on: bool = True):
    """Inside the block (``on``), in this thread, joint registration's side-by-side final stages
    subtract each staged neighbour at its searched pose (module docs); ``on`` False: nothing changes."""
    if not on:
        yield
        return
    _install()
    token = _ON.set(True)
    try:
        yield
    finally:
        _ON.reset(token)
