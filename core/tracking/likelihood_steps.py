"""Running the likelihood final stage's step generators (:meth:`core.tracking.engine_likelihood.
LikelihoodEngine.refine_steps`' kind: each yields where it would wait for the device): to their end,
or several side by side so that one's host work overlaps the device's work on the others'.

Why the steps are short (``python -m core.studies.tracking.stage_contraction``, this 2-core x86_64
machine, shared; held-out seed 4 at 512², 1 mm): the frame is blurrier than the model — the
intensifier's PSF, glare and the distortion correction's resampling blur the image, the DRR is not
blurred (no PSF estimated) — so along a pose direction ``e`` the χ² curvature is ``a·⟨ȳ', D'⟩``, the
blurred image's derivative against the DRR's, below Gauss–Newton's ``a²⟨D', D'⟩`` (``JᵀWJ``), and the
high-pass weighs the frequencies the blur takes most. The gradient's slope along a pose axis over
±0.05 mm / ° against ``JᵀWJ``'s diagonal (θ): 1.00 on the calcaneus's noise-free frame 30 of the
bones alone and 1.01-1.03 with the soft tissue and walkway (Gauss–Newton in 3-4 steps, each 0.02-0.2 of
the one before), 0.78-0.91 through the blur and glare, 0.69-0.87 through the trial's whole chain,
0.52-0.86 on the noisy frame (steps 0.6-0.7 of the one before; the weakest direction of ``JᵀWJ``
0.57). The moments' arithmetic is right (``JᵀWJ`` and ``JᵀWr`` from the same differences: on a
frame rendered by the model's renderer θ is 1.00 and the steps contract 0.02-0.17 a step). The steps
lengthened by the secant θ measured along the step before (``SECANT_STEPS``, ae5c64b) and a stop that
needed a contracted step (``STOP_CONTRACT``) were tried and removed: neither paid (README, *Why the
stage's Gauss–Newton steps contract slowly* and *Speed and the goals at d262386*)."""

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

