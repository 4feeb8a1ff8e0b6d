"""Host work run while the device works on one bone's final stage, and the next frame's search prepared
ahead (:func:`core.tracking.register.register`'s helpers).

:func:`stage_idle` hands one bone's registrations a callable run while the device works on their final
stage (where the host waits otherwise): :func:`core.tracking.trial.track` puts the next frame on the device
there (:data:`core.tracking.trial.NEXT_FRAME_AHEAD`) and prepares the next frame's search from this frame's
searched pose (:data:`core.tracking.search_ahead.SEARCH_AHEAD`; :func:`core.tracking.register.prepare_search`,
which leaves its pixel size and search regions here, :func:`keep`, for :func:`take`).
"""

from __future__ import annotations

from contextlib import contextmanager
from contextvars import ContextVar

from .likelihood_steps import run_steps

__all__ = ["final_stage_idle", "forget", "keep", "stage_idle", "take"]

#: What to run while the device works on the final stage (:func:`stage_idle`); None: nothing.
_STAGE_IDLE: ContextVar = ContextVar("register_stage_idle", default=None)

_AHEAD: dict = {}  # prepare_search's (renderer id, bone, pose, centre, views) -> (options, px_mm, roi)


@contextmanager
def stage_idle(fn):
    """Within the block, one bone's registrations (:func:`core.tracking.register.register`) call
    ``fn(res)`` (``res``: the search's result, before the stage) once, while the device works on their
    final stage's first step (where the host would otherwise wait: the stage's generator yields there,
    :func:`core.tracking.final_stage.final_stage_steps`), then let it go; where it returns a generator, one
    piece of it (up to its next ``yield``) runs at each of the stage's waits and the rest after the stage.
    ``fn`` must not change what the registration reads (e.g. the next frame's upload, the next frame's
    search prepared: :func:`core.tracking.register.prepare_search`). A study's wrapper of
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


def forget() -> None:
    """Drop what :func:`keep` kept."""
    _AHEAD.clear()


def keep(renderer, bone: int, base, center, views: tuple, options, px_mm: float, roi) -> None:
    """What :func:`core.tracking.register.prepare_search` prepared for ``bone`` from pose ``base``."""
    _AHEAD[(id(renderer), int(bone), base.tobytes(), center.tobytes(), tuple(views))] = (options, px_mm, roi)


def take(renderer, bone: int, base, center, views: tuple, options, others):
    """:func:`keep`'s ``(px_mm, roi)`` for a registration of ``bone`` from ``base`` with these ``options``
    (the same object) and no neighbours, or None; taken once."""
    if not _AHEAD or others is not None:
        return None
    hit = _AHEAD.pop((id(renderer), int(bone), base.tobytes(), center.tobytes(), tuple(views)), None)
    return None if hit is None or hit[0] is not options else hit[1:]
