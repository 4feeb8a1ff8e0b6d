"""The likelihood final stage's regions made on the device with a count of usable pixels per thread
block (:data:`core.tracking.likelihood_frames.ROI_BLOCK_COUNT`).

:func:`~core.tracking.engine_kernels.fluoro_roi_kernel` (the tracker's engine's, which the stage used)
ends every thread with three atomics on its view's three totals (the region's maximum, the usable
pixels' count and sum): some 10⁴ atomics on six addresses per bone-frame at 1024², which serialise
(0.14 ms of the stage's set-up on one NVIDIA H100; with 512-pixel chunks, eight times as many, 0.37 ms).
The stage reads only the count (``n_pixels``). :func:`roi_count_kernel` makes the same line integrals and
usable pixels (each pixel's arithmetic as there) and sums the count over its thread block first (a tile
reduction, then one atomic a block): the same images, the same count (whole numbers, exact in float32
within a block and in float64 after); neither the maximum nor the sum is made.
"""

from __future__ import annotations

import warp as wp

from .engine_kernels import LI_FLOOR

__all__ = ["roi_count_kernel"]


@wp.kernel
def roi_count_kernel(src: wp.array3d(dtype=wp.float32), given: wp.array3d(dtype=wp.uint8),
                     info: wp.array2d(dtype=wp.int32), lo: float, hi: float, p: int, check: int, chunk: int,
                     raw: wp.array3d(dtype=wp.float32), fmask: wp.array3d(dtype=wp.uint8),
                     msum: wp.array2d(dtype=wp.float64)):
    """:func:`~core.tracking.engine_kernels.fluoro_roi_kernel`'s ``raw`` and ``fmask`` (its docs: the
    region in DRR polarity, its usable pixels) and ``msum[v, 0]`` += the usable pixels, counted per thread
    block. dim = (views, chunks) tiled, ``chunk`` pixels a block."""
    v, ch, lane = wp.tid()
    bd = wp.block_dim()
    h = info[v, 0]
    w = info[v, 1]
    oy = info[v, 2]
    ox = info[v, 3]
    hs = info[v, 4]
    ws = info[v, 5]
    W = raw.shape[2]
    start = ch * chunk
    stop = wp.min(raw.shape[1] * W, start + chunk)
    n = float(0.0)  # noqa: UP018 (Warp variables, not constants)
    for q in range(start + lane, stop, bd):
        r = q // W
        c = q - r * W
        x = float(0.0)  # noqa: UP018
        ok = int(0)  # noqa: UP018, RUF046
        if r < h and c < w:
            rr = r + oy
            cc = c + ox
            x = -wp.log(wp.clamp(src[v, rr, cc], LI_FLOOR, 1.0))
            ok = int(1)  # noqa: UP018, RUF046
            if check != 0:
                for dr in range(-p, p + 1):
                    y = rr + dr
                    if y >= 0 and y < hs:
                        a = p - wp.abs(dr)
                        for dc in range(-a, a + 1):
                            z = cc + dc
                            if z >= 0 and z < ws:
                                u = src[v, y, z]
                                if not (u > lo and u < hi):
                                    ok = int(0)  # noqa: UP018, RUF046
            if info[v, 6] != 0:
                if given[v, rr, cc] == wp.uint8(0):
                    ok = int(0)  # noqa: UP018, RUF046
            if ok != 0:
                n += 1.0
        raw[v, r, c] = x
        fmask[v, r, c] = wp.uint8(ok)
    t = wp.tile_sum(wp.tile(n))
    if lane == 0:
        total = t[0]
        if total > 0.0:
            wp.atomic_add(msum, v, 0, wp.float64(total))
