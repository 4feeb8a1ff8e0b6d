"""Running the likelihood final stage's step generators (:meth:`core.tracking.engine_likelihood.
LikelihoodEngine.refine_steps`' kind: each yields where it would wait for the device): to their end,
or several side by side so that one's host work overlaps the device's work on the others'."""

from __future__ import annotations

import time
from collections.abc import Sequence

__all__ = ["StepClock", "run_side_by_side", "run_steps"]


def run_steps(steps):
    """The value of a generator of :meth:`LikelihoodEngine.refine_steps`' kind run to its end."""
    while True:
        try:
            next(steps)
        except StopIteration as stop:
            return stop.value


class StepClock:
    """The time a generator of :func:`run_side_by_side` ran (its own host work and its waits):
    :meth:`seconds` so far. Started at creation; without the driver it counts the wall time."""

    def __init__(self) -> None:
        self.spent = 0.0
        self.t = time.perf_counter()

    def seconds(self) -> float:
        return self.spent + time.perf_counter() - self.t


def run_side_by_side(steps: Sequence, clocks: Sequence[StepClock] | None = None) -> list:
    """The values of generators of :meth:`LikelihoodEngine.refine_steps`' kind run side by side:
    each runs until it would wait for the device (its work enqueued), then the next; the first to
    have enqueued is the first resumed, so that one's host work (taking its result, solving,
    enqueuing its next step) runs while the device works through the others'. ``clocks``: each
    generator's :class:`StepClock`, advanced by the time it ran (the loop's wall time split among
    them)."""
    n = len(steps)
    out: list = [None] * n
    live = list(range(n))
    for c in clocks or ():
        c.spent = 0.0
    while live:
        nxt = []
        for k in live:
            t = time.perf_counter()
            if clocks is not None:
                clocks[k].t = t
            try:
                next(steps[k])
                nxt.append(k)
            except StopIteration as stop:
                out[k] = stop.value
            finally:
                if clocks is not None:
                    clocks[k].spent += time.perf_counter() - t
                    clocks[k].t = time.perf_counter()
        live = nxt
    return out
