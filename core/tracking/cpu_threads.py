"""The Gauss–Newton engine's metric launches on several CPU threads.

Warp runs a CPU kernel on one core; a launch is a ctypes call, which releases the GIL, so
launches issued from several Python threads run in parallel. :func:`split_cpu_launches` turns
the recorded metric launches of :class:`core.tracking.engine.GaussNewtonCost` (its ``_Pipeline``:
two blur passes, the per-item statistics, the scores, the Gauss–Newton moments) into steps that
do the same work on up to ``threads`` threads:

* ``blur_kernel`` is split into runs of whole items (at multiples of its ``n_refs``, so each item
  sees the same view data), each run its own recorded launch on views (slices) of the item
  arrays; every pixel is computed as in one launch, so the results are bit-identical.
* ``moments_kernel`` reads only the smoothed DRRs and writes only its own moments: it runs beside
  the statistics (``stats_kernel``), not after them. An item's sums are accumulated by one
  thread in the same order as before, so the results are bit-identical.
* everything else (``finalize_kernel`` …) runs as recorded, in order.

Tile kernels are never split, and two of them run side by side only when they belong to
different Warp modules: on the CPU a Warp module keeps its tile scratch memory behind one static
pointer (Warp 1.19, ``native/tile.h``: not thread-local), so two tile kernels of one module in
two threads would share it. Kernels that use no tiles never read that pointer.

Kernels are recognised by name; a launch of any other kernel is kept as it is. The DRR launch of
the renderer is split by :class:`core.render.DRRRenderer` itself (``cpu_threads``); the engine
splits its CPU pipelines over the renderer's ``cpu_threads`` when it records them.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np
import warp as wp

from ..render.drr import run_parallel

__all__ = ["split_cpu_launches"]

#: kernels without tiles that may be split: name -> (arguments sliced along the items axis, the
#: argument the split aligns to)
ITEM_SPLIT = {
    "blur_kernel": (("src", "dst"), "n_refs"),
}
#: the tile kernel the next entry may run beside, and what follows it until then
STATS = "stats_kernel"
#: kernels that may run beside the statistics (they read the blurred DRRs and write arrays of
#: their own)
BESIDE = ("moments_kernel",)


class _Parallel:
    """Launches run in parallel threads (:func:`core.render.drr.run_parallel`)."""

    def __init__(self, cmds: Sequence) -> None:
        self.cmds = list(cmds)

    def launch(self) -> None:
        run_parallel(self.cmds)


class _Serial:
    """Launches run one after the other."""

    def __init__(self, cmds: Sequence) -> None:
        self.cmds = list(cmds)

    def launch(self) -> None:
        for c in self.cmds:
            c.launch()


def _name(cmd) -> str:
    return str(getattr(cmd.kernel, "key", "")).split(".")[-1]


def _split(cmd, parts: int) -> list:
    """``cmd`` as up to ``parts`` launches over contiguous runs of items, or ``[cmd]``."""
    if parts < 2:
        return [cmd]
    sliced, align_arg = ITEM_SPLIT[_name(cmd)]
    labels = [a.label for a in cmd.kernel.adj.args]
    args = list(cmd.fwd_args or [])
    if len(args) != len(labels) or not all(s in labels for s in (*sliced, align_arg)):
        return [cmd]
    align = int(args[labels.index(align_arg)])
    shape = tuple(int(x) for x in cmd.bounds.shape)
    n = shape[0]
    if align < 1 or n % align or n // align < 2:
        return [cmd]
    groups = n // align
    k = min(parts, groups)
    bounds = [int(x) * align for x in np.linspace(0, groups, k + 1).round()]
    out = []
    for a, b in itertools.pairwise(bounds):
        inputs = [x[a:b] if lab in sliced else x for lab, x in zip(labels, args, strict=True)]
        out.append(wp.launch(cmd.kernel, dim=(b - a, *shape[1:]), inputs=inputs, device=cmd.device,
                             block_dim=cmd.block_dim, record_cmd=True))
    return out


def split_cpu_launches(launches: Sequence, threads: int) -> list:
    """Steps (objects with ``launch()``) doing the work of the recorded CPU ``launches`` run in
    order, on up to ``threads`` threads (module docs); ``launches`` itself when ``threads`` < 2."""
    launches = list(launches)
    if threads < 2 or not launches or any(c.device.is_cuda for c in launches):
        return launches
    steps: list = []
    i = 0
    while i < len(launches):
        cmd = launches[i]
        name = _name(cmd)
        if name == STATS:
            # the statistics and what follows them, with a kernel that may run beside them
            j = i + 1
            while j < len(launches) and _name(launches[j]) not in (*BESIDE, *ITEM_SPLIT, STATS):
                j += 1
            beside = launches[j] if j < len(launches) and _name(launches[j]) in BESIDE else None
            if beside is None or beside.kernel.module is cmd.kernel.module:  # one tile arena
                steps.append(cmd)
                i += 1
                continue
            steps.append(_Serial([_Parallel([cmd, beside]), *launches[i + 1:j]]))
            i = j + 1
        elif name in ITEM_SPLIT:
            parts = _split(cmd, threads)
            steps.append(_Parallel(parts) if len(parts) > 1 else cmd)
            i += 1
        else:
            steps.append(cmd)
            i += 1
    return steps
