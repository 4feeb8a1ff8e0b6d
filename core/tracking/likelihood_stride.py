"""The likelihood final stage's sandwich over a sub-lattice of the region's pixels
(:data:`core.tracking.likelihood_confidence.SANDWICH_STRIDE`): the residual's autocovariance and the
meat summed over the pixels ``i`` whose row and column are multiples of ``stride`` — their partners
``i + Δ`` still every pixel of the lag window — so both passes do ``1 / stride²`` of the work.

The autocovariance ``C(Δ)`` is the mean product of the pairs at lag ``Δ``: over the sub-lattice it is
the same mean over a quarter of the pairs (``stride`` 2), unbiased, its noise a little larger (over
10⁵ pixels a view). The meat ``Σ_i J̃_i (Σ_Δ C(Δ) J̃_{i+Δ})ᵀ`` over the sub-lattice is multiplied by
``stride²`` (:meth:`~core.tracking.likelihood_confidence._Confidence.sandwich_result`): the sum of a
product of the bone's high-passed derivative images, smooth over the high-pass's σ (4 px at 1024²),
estimated from one pixel in ``stride²``. What it changed: the flag's docs.

The kernels are :func:`~core.tracking.likelihood_fast.autocov_rows_kernel` and
:func:`~core.tracking.likelihood_kernels.meat_kernel` with the pixel index taken over the sub-lattice
(``stride`` 1: their pixels, in their order); they live in a module of their own so that the others'
compiled code stays as it is.
"""

from __future__ import annotations

import warp as wp

from .likelihood_fast import AUTOCOV_GROUP, vec9d
from .likelihood_kernels import mat66f, vec6f

__all__ = ["autocov_stride_kernel", "meat_stride_kernel", "stride_cells"]


def stride_cells(shape_hw, stride: int) -> int:
    """The sub-lattice's pixel count over a ``(H, W)`` buffer (the kernels' chunks are of these)."""
    s = int(stride)
    return (-(-int(shape_hw[0]) // s)) * (-(-int(shape_hw[1]) // s))


@wp.kernel
def autocov_stride_kernel(e: wp.array3d(dtype=wp.float32), wgt: wp.array3d(dtype=wp.float32),
                          ref_hw: wp.array(dtype=wp.vec2i), lag: int, groups: int, chunk: int, stride: int,
                          acc: wp.array3d(dtype=wp.float64)):
    """:func:`~core.tracking.likelihood_fast.autocov_rows_kernel` over the pixels ``i`` of the
    sub-lattice of ``stride`` (their partners at every lag of the window): ``acc[v, l]`` += the
    products ``e_i e_{i+Δ_l}`` and the count of those pairs of usable pixels. dim = (views,
    (lag + 1) · groups, chunks over :func:`stride_cells`)."""
    v, q, ch, lane = wp.tid()
    bd = wp.block_dim()
    h = ref_hw[v][0]
    w = ref_hw[v][1]
    n = 2 * lag + 1
    a = q // groups
    g0 = (q - a * groups) * AUTOCOV_GROUP
    dr = a - lag
    last = n
    if dr == 0:
        last = lag + 1
    Ws = (e.shape[2] + stride - 1) // stride
    Hs = (e.shape[1] + stride - 1) // stride
    start = ch * chunk
    stop = wp.min(Hs * Ws, start + chunk)
    s = vec9d()
    m = vec9d()
    for p in range(start + lane, stop, bd):
        rs = p // Ws
        r = rs * stride
        c = (p - rs * Ws) * stride
        rr = r + dr
        if r < h and c < w and rr >= 0 and rr < h:
            if wgt[v, r, c] > 0.0:
                x = e[v, r, c]
                for k in range(AUTOCOV_GROUP):
                    b = g0 + k
                    cc = c + b - lag
                    if b < last and cc >= 0 and cc < w:
                        if wgt[v, rr, cc] > 0.0:
                            s[k] = s[k] + wp.float64(x * e[v, rr, cc])
                            m[k] = m[k] + wp.float64(1.0)
    ts = wp.tile_sum(wp.tile(s, preserve_type=True))
    tm = wp.tile_sum(wp.tile(m, preserve_type=True))
    if lane == 0:
        xs = ts[0]
        xm = tm[0]
        for k in range(AUTOCOV_GROUP):
            b = g0 + k
            if b < last:
                wp.atomic_add(acc, v, a * n + b, 0, xs[k])
                wp.atomic_add(acc, v, a * n + b, 1, xm[k])


@wp.kernel
def meat_stride_kernel(jt: wp.array3d(dtype=vec6f), cw: wp.array2d(dtype=wp.float32),
                       ref_hw: wp.array(dtype=wp.vec2i), lag: int, chunk: int, stride: int,
                       acc: wp.array2d(dtype=wp.float64), half: int):
    """:func:`~core.tracking.likelihood_kernels.meat_kernel` over the pixels ``i`` of the sub-lattice of
    ``stride`` (``J̃_{i+Δ}`` at every lag): ``acc[v]`` += ``Σ_i J̃_i (Σ_Δ C(Δ) J̃_{i+Δ})ᵀ`` (not scaled
    by ``stride²``: the caller does). dim = (views, chunks over :func:`stride_cells`)."""
    v, ch, lane = wp.tid()
    bd = wp.block_dim()
    h = ref_hw[v][0]
    w = ref_hw[v][1]
    n = 2 * lag + 1
    Ws = (jt.shape[2] + stride - 1) // stride
    Hs = (jt.shape[1] + stride - 1) // stride
    start = ch * chunk
    stop = wp.min(Hs * Ws, start + chunk)
    s = mat66f()
    for p in range(start + lane, stop, bd):
        rs = p // Ws
        r = rs * stride
        c = (p - rs * Ws) * stride
        if r < h and c < w:
            ji = jt[v, r, c]
            if wp.length_sq(ji) > 0.0:
                u = vec6f()
                a0 = wp.max(0, lag - r)
                a1 = wp.min(n, h - r + lag)
                b0 = wp.max(0, lag - c)
                b1 = wp.min(n, w - c + lag)
                if half != 0:
                    a0 = wp.max(a0, lag)
                for a in range(a0, a1):
                    rr = r + a - lag
                    bs = b0
                    if half != 0 and a == lag:
                        bs = wp.max(b0, lag)
                    for b in range(bs, b1):
                        f = cw[v, a * n + b]
                        if half != 0 and (a != lag or b != lag):
                            f = 2.0 * f
                        u += f * jt[v, rr, c + b - lag]
                s += wp.outer(ji, u)
    t = wp.tile_sum(wp.tile(s, preserve_type=True))
    if lane == 0:
        x = t[0]
        for i in range(6):
            for j in range(6):
                wp.atomic_add(acc, v, i * 6 + j, wp.float64(x[i, j]))
