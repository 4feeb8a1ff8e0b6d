"""Host work run while the device works on one bone's final stage (:func:`core.tracking.register.register`'s
helper).

:func:`stage_idle` hands one bone's registrations a callable run while the device works on their final
stage (where the host waits otherwise): :func:`core.tracking.trial.track` puts the next frame on the device
there (:data:`core.tracking.trial.NEXT_FRAME_AHEAD`). Tried and removed: the next frame's search prepared
there from this frame's searched pose (``search_ahead.SEARCH_AHEAD``, 680f52a): not exact (a relative σ
check flipped on the tests' walking talus), and no faster on one NVIDIA H100 than the shared upload alone
(``resources/benchmarks/tracking_share_frame_h100.json``).
"""

from __future__ import annotations

from contextlib import contextmanager
from contextvars import ContextVar

from .likelihood_steps import run_steps

__all__ = ["final_stage_idle", "stage_idle"]

#: What to run while the device works on the final stage (:func:`stage_idle`); None: nothing.
_STAGE_IDLE: ContextVar = ContextVar("register_stage_idle", default=None)


@contextmanager
def stage_idle(fn):
    """Within the block, one bone's registrations (:func:`core.tracking.register.register`) call
    ``fn(res)`` (``res``: the search's result, before the stage) once, while the device works on their
    final stage's first step (where the host would otherwise wait: the stage's generator yields there,
    :func:`core.tracking.final_stage.final_stage_steps`), then let it go; where it returns a generator, one
    piece of it (up to its next ``yield``) runs at each of the stage's waits and the rest after the stage.
    ``fn`` must not change what the registration reads (e.g. the next frame's upload). A study's wrapper of
    :func:`~core.tracking.final_stage.final_stage` is called as before, without it."""
    token = _STAGE_IDLE.set([fn] if fn is not None else None)
    try:
        yield
    finally:
        _STAGE_IDLE.reset(token)


def final_stage_idle(renderer, frame, res, **kw):
    """:func:`core.tracking.final_stage.final_stage`, with :func:`stage_idle`'s work at its waits for the
    device (the same stage: the same generator run to its end)."""
    from . import final_stage as fst

    slot = _STAGE_IDLE.get()
    if not slot or fst.final_stage is not fst._PLAIN_FINAL_STAGE:
        return fst.final_stage(renderer, frame, res, **kw)
    steps = fst.final_stage_steps(renderer, frame, res, **kw)
    try:
        next(steps)
    except StopIteration as stop:
        return stop.value
    fn = slot.pop() if slot else None
    work = fn(res) if fn is not None else None
    if not hasattr(work, "__next__"):
        return run_steps(steps)
    while True:  # a piece of the work at each wait of the stage
        if work is not None:
            try:
                next(work)
            except StopIteration:
                work = None
        try:
            next(steps)
        except StopIteration as stop:
            for _ in work or ():
                pass
            return stop.value

