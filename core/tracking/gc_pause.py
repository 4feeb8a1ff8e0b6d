"""The cyclic garbage collector around a tracking run: its objects of before the run frozen
(:func:`frozen`) and its collections counted (:class:`GcWatch`).

A tracking process holds a few hundred thousand objects the collector follows (Warp's kernels and
their syntax trees, ``inspect`` signatures, modules: 242 000-247 000 after a one-bone warm-up on this
2-core x86_64 machine, Python 3.11), made before the run and alive through it. Each full collection
walks all of them: 150-222 ms on this machine, shared, 0.001 ms with them frozen
(``resources/benchmarks/tracking_host_pauses_cpu.json``, :mod:`core.studies.tracking.host_pauses`). On
this machine's CPU path a run of 8 frames made 1-2 young collections and no full one; a full one that
falls inside a 100-frame run of ~0.6 s (one NVIDIA H100) would cost it ~0.5-2 ms a frame, missed by a
median of per-frame registration times. :func:`gc.freeze` moves every object alive at the run's start
out of the collector's generations (:func:`gc.unfreeze` after the run puts them back): the
collections during the run walk the run's own objects only. What is collected and when changes
nothing the tracker computes (the same poses and flags, tests); objects of before the run that
become garbage during it are collected after it.
"""

from __future__ import annotations

import gc
import time
from contextlib import contextmanager

__all__ = ["GcWatch", "frozen"]


@contextmanager
def frozen(on: bool = True):
    """Within the block, the objects alive at its start frozen (:func:`gc.freeze`), unfrozen after.
    Nothing done where ``on`` is false or something else has frozen objects already (its freeze is
    left as it is: a process that froze its start-up objects, another run in progress)."""
    if not on or gc.get_freeze_count():
        yield
        return
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


class GcWatch:
    """Collections per generation and the seconds they took, within a ``with`` block
    (:data:`gc.callbacks`)."""

    def __init__(self) -> None:
        self.collections = [0, 0, 0]
        self.pause_s = [0.0, 0.0, 0.0]
        self._t0 = 0.0

    def _cb(self, phase: str, info: dict) -> None:
        if phase == "start":
            self._t0 = time.perf_counter()
        else:
            g = min(int(info.get("generation", 0)), 2)
            self.collections[g] += 1
            self.pause_s[g] += time.perf_counter() - self._t0

    def __enter__(self) -> GcWatch:
        gc.callbacks.append(self._cb)
        return self

    def __exit__(self, *exc) -> None:
        if self._cb in gc.callbacks:
            gc.callbacks.remove(self._cb)

    def to_dict(self) -> dict:
        """``collections`` (generations 0, 1, 2) and ``pause_ms`` (each, and ``total``)."""
        return {"collections": list(self.collections), "pause_ms": [1e3 * s for s in self.pause_s],
                "pause_ms_total": 1e3 * sum(self.pause_s)}
