"""Running the likelihood final stage's step generators (:meth:`core.tracking.engine_likelihood.
LikelihoodEngine.refine_steps`' kind: each yields where it would wait for the device): to their end,
or several side by side so that one's host work overlaps the device's work on the others'; and the
steps' secant length (:class:`SecantScale`, :data:`~core.tracking.engine_likelihood.SECANT_STEPS`).

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
frame rendered by the model's renderer θ is 1.00 and the steps contract 0.02-0.17 a step)."""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np

__all__ = ["SecantScale", "StepClock", "run_side_by_side", "run_steps"]


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


class SecantScale:
    """A Gauss–Newton refinement's steps lengthened by the χ² curvature measured along the last
    one: after a step ``u`` from a design with ``JᵀWr = g₀`` and ``JᵀWJ = H`` to one with ``g₁``, the
    secant ``θ = (g₀ - g₁)·u / uᵀHu`` is the curvature along ``u`` over Gauss–Newton's (1 where the
    model is the frame's; module docs: 0.5-0.9 on the trial's blurred frames); the next step is
    ``δ / θ`` (:attr:`factor`; the caller's predicted decrease is ``Jrᵀ`` of it). ``θ`` is measured
    only on steps the data resolve (``uᵀHu`` at least ``min_share`` pixels' shares of χ², χ²/N) and
    kept within ``[1 / max_factor, 1]``: a step is never shortened, and at most 1.6 times Gauss–
    Newton's, so that a direction whose curvature is Gauss–Newton's (θ 1 there, the step's θ set by
    a weaker one) still converges (each step -0.6 of the one before there; 2 would not converge).
    ``owner``: an object whose ``_theta`` (the engine's: its last refinement's θ) it starts from and
    keeps up to date, or the starting θ itself; ``theta``: the starting θ instead of the owner's (the
    engine's first refinement in a frame starts from 1, its robust round from the first's θ: a frame's
    result does not depend on the frames before)."""

    def __init__(self, owner=1.0, *, theta: float | None = None, max_factor: float = 1.6,
                 min_share: float = 0.01) -> None:
        self.max_factor = float(max_factor)
        self.min_share = float(min_share)
        self._owner = None if isinstance(owner, int | float) else owner
        given = theta is not None
        if not given:
            theta = float(owner) if self._owner is None else getattr(owner, "_theta", 1.0)
        self.theta = self._clip(theta)
        if given and self._owner is not None:  # (the owner's from here: what the refinement measures)
            self._owner._theta = self.theta
        self._last = None  # (u, g0, H) of the step taken last

    def _clip(self, theta: float) -> float:
        return float(min(1.0, max(1.0 / self.max_factor, theta))) if np.isfinite(theta) else 1.0

    @property
    def factor(self) -> float:
        """The next step's length over Gauss–Newton's (``1 / θ``)."""
        return 1.0 / self.theta

    def step(self, s: dict, delta: np.ndarray, share: float) -> np.ndarray:
        """The step to take from the design whose result is ``s`` (``JJ``, ``Jr``) and Gauss–Newton
        step ``delta``: θ measured along the last step taken (where resolved), ``delta / θ``
        returned and kept as the step taken."""
        g1 = np.asarray(s["Jr"], dtype=float)
        if self._last is not None:
            u, g0, H = self._last
            den = float(u @ H @ u)
            if den > self.min_share * share and den > 0.0:
                self.theta = self._clip(float((g0 - g1) @ u) / den)
                if self._owner is not None:
                    self._owner._theta = self.theta
        u = self.factor * np.asarray(delta, dtype=float)
        self._last = (u, g1, np.asarray(s["JJ"], dtype=float))
        return u
