"""Warp kernels of :class:`core.similarity.BatchedMetric` (see :mod:`core.similarity.batched`).

Layout: ``drr`` is the renderer's ``(n_items, H, W)`` float32 array; item ``k`` is compared with
reference ``ref = k % n_refs`` (``n_refs`` = views × bones: items are ordered (pose, view,
bone)), whose ROI is ``ref_hw[ref] = (h, w)`` (``h <= H``, ``w <= W``). Per reference the host
uploads the fluoroscope ROI (``fluoro``), its gradient (``fgrad``, vec2 ``(E_u, E_v)``) and its
mask (``fmask``, 1 = usable), zero-padded to a common size.

Pixel loops are *tiled*: a launch of ``dim = (n_items, n_chunks)`` blocks; each block walks
``chunk`` consecutive pixels of one item with a stride of the block size, keeps per-thread
partial sums in registers, reduces them across the block (``wp.tile_sum`` / ``tile_min`` /
``tile_max``) and adds one value per block to the item's accumulator (float64 atomics). On the
CPU Warp runs one thread per block, which then walks the whole chunk. NaN DRR pixels read as 0
(outside Ω; 0 in gradient stencils).
"""

from __future__ import annotations

import warp as wp

vec6f = wp.types.vector(length=6, dtype=wp.float32)

#: gradient magnitudes at or below this (DRR: absolute; fluoroscope: relative, host side) are 0
ZERO_GRADIENT = wp.constant(1.0e-6)
BIG = wp.constant(1.0e30)


@wp.func
def _val(img: wp.array3d(dtype=wp.float32), k: int, r: int, c: int) -> float:
    x = img[k, r, c]
    if wp.isnan(x):
        x = 0.0
    return x


@wp.func
def _in_omega(drr: wp.array3d(dtype=wp.float32), fmask: wp.array3d(dtype=wp.uint8), k: int, ref: int,
              r: int, c: int, h: int, w: int, thr: float, dil: int) -> bool:
    inside = bool(False)
    if fmask[ref, r, c] != wp.uint8(0):
        if dil == 0:
            inside = drr[k, r, c] > thr
        else:
            for rr in range(wp.max(r - dil, 0), wp.min(r + dil, h - 1) + 1):
                for cc in range(wp.max(c - dil, 0), wp.min(c + dil, w - 1) + 1):
                    if drr[k, rr, cc] > thr:
                        inside = True
    return inside


@wp.func
def _grad(img: wp.array3d(dtype=wp.float32), k: int, r: int, c: int, h: int, w: int,
          ku: wp.mat33f, kv: wp.mat33f) -> wp.vec2f:
    """3x3 correlation gradient with replicated borders of the (h, w) ROI."""
    gu = float(0.0)
    gv = float(0.0)
    for a in range(3):
        rr = wp.clamp(r + a - 1, 0, h - 1)
        for b in range(3):
            cc = wp.clamp(c + b - 1, 0, w - 1)
            x = _val(img, k, rr, cc)
            gu += ku[a, b] * x
            gv += kv[a, b] * x
    g = wp.vec2f(gu, gv)
    if wp.length(g) <= ZERO_GRADIENT:
        g = wp.vec2f(0.0, 0.0)
    return g


@wp.func
def _cos2(gd: wp.vec2f, gf: wp.vec2f) -> float:
    den = wp.length_sq(gd) * wp.length_sq(gf)
    c2 = float(0.0)
    if den > 0.0:
        d = wp.dot(gd, gf)
        c2 = wp.min(d * d / den, 1.0)
    return c2


@wp.func
def _pair(mode: int, drr: wp.array3d(dtype=wp.float32), fluoro: wp.array3d(dtype=wp.float32),
          fgrad: wp.array3d(dtype=wp.vec2f), fshift: float, k: int, ref: int, r: int, c: int,
          h: int, w: int, ku: wp.mat33f, kv: wp.mat33f) -> wp.vec2f:
    """(a, b): intensities (mode 0; F shifted by its ROI mean), gradient magnitudes (mode 1) or
    the gradients' u (mode 2) or v (mode 3) components."""
    out = wp.vec2f(0.0, 0.0)
    if mode == 0:
        out = wp.vec2f(_val(drr, k, r, c), fluoro[ref, r, c] - fshift)
    elif mode == 1:
        out = wp.vec2f(wp.length(_grad(drr, k, r, c, h, w, ku, kv)), wp.length(fgrad[ref, r, c]))
    else:
        gd = _grad(drr, k, r, c, h, w, ku, kv)
        gf = fgrad[ref, r, c]
        out = wp.vec2f(gd[mode - 2], gf[mode - 2])
    return out


@wp.kernel
def blur_kernel(src: wp.array3d(dtype=wp.float32), dst: wp.array3d(dtype=wp.float32),
                weights: wp.array(dtype=wp.float32), ref_hw: wp.array(dtype=wp.vec2i), n_refs: int,
                axis: int):
    """One pass of a separable Gaussian blur within each item's (h, w) ROI, replicated borders
    (scipy's ``mode="nearest"``), NaN read as 0; pixels outside the ROI become 0. dim = items, H, W."""
    k, r, c = wp.tid()
    ref = k % n_refs
    h = ref_hw[ref][0]
    w = ref_hw[ref][1]
    acc = float(0.0)
    if r < h and c < w:
        rad = (weights.shape[0] - 1) // 2
        for j in range(weights.shape[0]):
            if axis == 0:
                acc += weights[j] * _val(src, k, wp.clamp(r + j - rad, 0, h - 1), c)
            else:
                acc += weights[j] * _val(src, k, r, wp.clamp(c + j - rad, 0, w - 1))
    dst[k, r, c] = acc


@wp.kernel
def stats_kernel(drr: wp.array3d(dtype=wp.float32), fluoro: wp.array3d(dtype=wp.float32),
                 fgrad: wp.array3d(dtype=wp.vec2f), fmask: wp.array3d(dtype=wp.uint8),
                 ref_hw: wp.array(dtype=wp.vec2i), fshift: wp.array(dtype=wp.float32), n_refs: int,
                 thr: float, dil: int, mode: int, ku: wp.mat33f, kv: wp.mat33f, chunk: int,
                 acc: wp.array2d(dtype=wp.float64)):
    """acc[k] += (N, Σa, Σb, Σa², Σb², Σab) over Ω."""
    k, ch, lane = wp.tid()
    bd = wp.block_dim()
    ref = k % n_refs
    h = ref_hw[ref][0]
    w = ref_hw[ref][1]
    W = drr.shape[2]
    start = ch * chunk
    stop = wp.min(drr.shape[1] * W, start + chunk)
    s = vec6f()
    for p in range(start + lane, stop, bd):
        r = p // W
        c = p - r * W
        if r < h and c < w:
            if _in_omega(drr, fmask, k, ref, r, c, h, w, thr, dil):
                ab = _pair(mode, drr, fluoro, fgrad, fshift[ref], k, ref, r, c, h, w, ku, kv)
                a = ab[0]
                b = ab[1]
                s += vec6f(1.0, a, b, a * a, b * b, a * b)
    t = wp.tile_sum(wp.tile(s, preserve_type=True))
    if lane == 0:
        x = t[0]
        for m in range(6):
            wp.atomic_add(acc, k, m, wp.float64(x[m]))


@wp.kernel
def range_kernel(drr: wp.array3d(dtype=wp.float32), fluoro: wp.array3d(dtype=wp.float32),
                 fgrad: wp.array3d(dtype=wp.vec2f), fmask: wp.array3d(dtype=wp.uint8),
                 ref_hw: wp.array(dtype=wp.vec2i), fshift: wp.array(dtype=wp.float32), n_refs: int,
                 thr: float, dil: int, mode: int, ku: wp.mat33f, kv: wp.mat33f, chunk: int,
                 rng: wp.array2d(dtype=wp.float32), count: wp.array(dtype=wp.float64)):
    """rng[k] = (min a, max a, min b, max b) over Ω (initialised to ±BIG); count[k] += |Ω|."""
    k, ch, lane = wp.tid()
    bd = wp.block_dim()
    ref = k % n_refs
    h = ref_hw[ref][0]
    w = ref_hw[ref][1]
    W = drr.shape[2]
    start = ch * chunk
    stop = wp.min(drr.shape[1] * W, start + chunk)
    amin = float(BIG)
    amax = float(-BIG)
    bmin = float(BIG)
    bmax = float(-BIG)
    n = float(0.0)
    for p in range(start + lane, stop, bd):
        r = p // W
        c = p - r * W
        if r < h and c < w:
            if _in_omega(drr, fmask, k, ref, r, c, h, w, thr, dil):
                ab = _pair(mode, drr, fluoro, fgrad, fshift[ref], k, ref, r, c, h, w, ku, kv)
                amin = wp.min(amin, ab[0])
                amax = wp.max(amax, ab[0])
                bmin = wp.min(bmin, ab[1])
                bmax = wp.max(bmax, ab[1])
                n += 1.0
    t0 = wp.tile_min(wp.tile(amin))
    t1 = wp.tile_max(wp.tile(amax))
    t2 = wp.tile_min(wp.tile(bmin))
    t3 = wp.tile_max(wp.tile(bmax))
    tn = wp.tile_sum(wp.tile(n))
    if lane == 0:
        wp.atomic_min(rng, k, 0, t0[0])
        wp.atomic_max(rng, k, 1, t1[0])
        wp.atomic_min(rng, k, 2, t2[0])
        wp.atomic_max(rng, k, 3, t3[0])
        wp.atomic_add(count, k, wp.float64(tn[0]))


@wp.kernel
def init_range_kernel(rng: wp.array2d(dtype=wp.float32)):
    k = wp.tid()
    rng[k, 0] = BIG
    rng[k, 1] = -BIG
    rng[k, 2] = BIG
    rng[k, 3] = -BIG


@wp.kernel
def gi_kernel(drr: wp.array3d(dtype=wp.float32), fgrad: wp.array3d(dtype=wp.vec2f),
              fmask: wp.array3d(dtype=wp.uint8), ref_hw: wp.array(dtype=wp.vec2i), n_refs: int,
              thr: float, dil: int, ku: wp.mat33f, kv: wp.mat33f, chunk: int,
              stats: wp.array2d(dtype=wp.float64), acc: wp.array2d(dtype=wp.float64)):
    """acc[k, 0] += Σ_Ω cos(2Δ) min(|g_D| / m_D, |g_F| / m_F), means from the stats pass."""
    k, ch, lane = wp.tid()
    bd = wp.block_dim()
    ref = k % n_refs
    h = ref_hw[ref][0]
    w = ref_hw[ref][1]
    W = drr.shape[2]
    start = ch * chunk
    stop = wp.min(drr.shape[1] * W, start + chunk)
    md = float(stats[k, 1])
    mf = float(stats[k, 2])
    s = float(0.0)
    if md > 0.0 and mf > 0.0:
        nn = float(stats[k, 0])
        md = md / nn
        mf = mf / nn
        for p in range(start + lane, stop, bd):
            r = p // W
            c = p - r * W
            if r < h and c < w:
                if _in_omega(drr, fmask, k, ref, r, c, h, w, thr, dil):
                    gd = _grad(drr, k, r, c, h, w, ku, kv)
                    gf = fgrad[ref, r, c]
                    m = wp.min(wp.length(gd) / md, wp.length(gf) / mf)
                    s += (2.0 * _cos2(gd, gf) - 1.0) * m
    t = wp.tile_sum(wp.tile(s))
    if lane == 0:
        wp.atomic_add(acc, k, 0, wp.float64(t[0]))


#: bins of GO's magnitude histograms (median estimate)
MEDIAN_BINS = 1024
_MED = wp.constant(MEDIAN_BINS)
_MED2 = wp.constant(2 * MEDIAN_BINS)


@wp.kernel
def magnitude_hist_kernel(drr: wp.array3d(dtype=wp.float32), fgrad: wp.array3d(dtype=wp.vec2f),
                          fmask: wp.array3d(dtype=wp.uint8), ref_hw: wp.array(dtype=wp.vec2i),
                          n_refs: int, thr: float, dil: int, ku: wp.mat33f, kv: wp.mat33f, chunk: int,
                          rng: wp.array2d(dtype=wp.float32), hist: wp.array(dtype=wp.int32)):
    """Histograms over [0, max] of |g_D| (``hist[k * 2 MED + i]``) and |g_F| (``+ MED``) on Ω,
    accumulated per block in shared memory."""
    k, ch, lane = wp.tid()
    bd = wp.block_dim()
    ref = k % n_refs
    h = ref_hw[ref][0]
    w = ref_hw[ref][1]
    W = drr.shape[2]
    start = ch * chunk
    stop = wp.min(drr.shape[1] * W, start + chunk)
    th = wp.tile_zeros(shape=_MED2, dtype=wp.int32, storage="shared")
    top_d = rng[k, 1]
    top_f = rng[k, 3]
    n_iter = (chunk + bd - 1) // bd
    for it in range(n_iter):
        p = start + it * bd + lane
        okd = bool(False)
        okf = bool(False)
        jd = int(0)
        jf = int(0)
        if p < stop:
            r = p // W
            c = p - r * W
            if r < h and c < w:
                if _in_omega(drr, fmask, k, ref, r, c, h, w, thr, dil):
                    a = wp.length(_grad(drr, k, r, c, h, w, ku, kv))
                    b = wp.length(fgrad[ref, r, c])
                    if top_d > 0.0:
                        jd = wp.clamp(int(a / top_d * float(_MED)), 0, _MED - 1)
                        okd = True
                    if top_f > 0.0:
                        jf = _MED + wp.clamp(int(b / top_f * float(_MED)), 0, _MED - 1)
                        okf = True
        wp.tile_scatter_add(th, jd, 1, okd)
        wp.tile_scatter_add(th, jf, 1, okf)
    wp.tile_atomic_add(hist, th, offset=k * _MED2)


@wp.kernel
def median_kernel(hist: wp.array(dtype=wp.int32), rng: wp.array2d(dtype=wp.float32),
                  count: wp.array(dtype=wp.float64), med: wp.array2d(dtype=wp.float32)):
    """Median of each histogram (linear within the bin holding the middle); dim = (n_items, 2)."""
    k, i = wp.tid()
    nb = _MED
    base = k * _MED2 + i * _MED
    top = rng[k, 1 + 2 * i]
    target = float(count[k]) * 0.5
    cum = float(0.0)
    out = float(0.0)
    done = int(0)
    if top > 0.0:
        for j in range(nb):
            cnt = float(hist[base + j])
            if done == 0 and cum + cnt >= target and cnt > 0.0:
                out = (float(j) + (target - cum) / cnt) * top / float(nb)
                done = 1
            cum += cnt
    med[k, i] = out


@wp.kernel
def go_kernel(drr: wp.array3d(dtype=wp.float32), fgrad: wp.array3d(dtype=wp.vec2f),
              fmask: wp.array3d(dtype=wp.uint8), ref_hw: wp.array(dtype=wp.vec2i), n_refs: int,
              thr: float, dil: int, ku: wp.mat33f, kv: wp.mat33f, chunk: int, go_mean: float,
              med: wp.array2d(dtype=wp.float32), acc: wp.array2d(dtype=wp.float64)):
    """acc[k] += (|S|, Σ_S centred log weight) with S = Ω ∩ above-median magnitudes in both."""
    k, ch, lane = wp.tid()
    bd = wp.block_dim()
    ref = k % n_refs
    h = ref_hw[ref][0]
    w = ref_hw[ref][1]
    W = drr.shape[2]
    start = ch * chunk
    stop = wp.min(drr.shape[1] * W, start + chunk)
    td = med[k, 0]
    tf = med[k, 1]
    s = wp.vec2f(0.0, 0.0)
    for p in range(start + lane, stop, bd):
        r = p // W
        c = p - r * W
        if r < h and c < w:
            if _in_omega(drr, fmask, k, ref, r, c, h, w, thr, dil):
                gd = _grad(drr, k, r, c, h, w, ku, kv)
                gf = fgrad[ref, r, c]
                if wp.length(gd) > td and wp.length(gf) > tf:
                    delta = wp.acos(wp.sqrt(_cos2(gd, gf)))
                    wgt = (2.0 - wp.log(1.0 + delta)) * 0.5
                    s += wp.vec2f(1.0, (wgt - go_mean) / (1.0 - go_mean))
    t = wp.tile_sum(wp.tile(s, preserve_type=True))
    if lane == 0:
        x = t[0]
        wp.atomic_add(acc, k, 0, wp.float64(x[0]))
        wp.atomic_add(acc, k, 1, wp.float64(x[1]))


@wp.func
def _bin(x: float, lo: float, hi: float, nb: int, linear: int) -> wp.vec2f:
    """(lower bin, weight of the next bin) as in core.similarity.information._bin_weights."""
    i0 = float(0.0)
    f = float(0.0)
    if hi > lo:
        t = (x - lo) / (hi - lo) * float(nb - 1)
        if linear == 0:
            i0 = wp.clamp(wp.floor(t + 0.5), 0.0, float(nb - 1))
        else:
            i0 = wp.clamp(wp.floor(t), 0.0, float(nb - 2))
            f = wp.clamp(t - i0, 0.0, 1.0)
    return wp.vec2f(i0, f)


#: largest number of MI histogram bins per image (shared-memory tiles are sized for it)
MAX_BINS = 64
_MB = wp.constant(MAX_BINS)
_MB2 = wp.constant(MAX_BINS * MAX_BINS)
_MB_BAND = wp.constant(2 * MAX_BINS)


@wp.kernel
def joint_hist_kernel(drr: wp.array3d(dtype=wp.float32), fluoro: wp.array3d(dtype=wp.float32),
                      fmask: wp.array3d(dtype=wp.uint8), ref_hw: wp.array(dtype=wp.vec2i),
                      fshift: wp.array(dtype=wp.float32), n_refs: int, thr: float, dil: int, nb: int,
                      linear: int, chunk: int, rng: wp.array2d(dtype=wp.float32),
                      joint: wp.array(dtype=wp.float32), selfd: wp.array(dtype=wp.float32),
                      selff: wp.array(dtype=wp.float32)):
    """Partial-volume joint histogram of (D, F) on Ω (``joint[k * MB² + i * MB + j]``) and the two
    self-joint band histograms (``self[k * 2 MB + i]`` diagonal, ``+ MB`` first off-diagonal),
    accumulated per block in shared memory and added to global memory once per block."""
    k, ch, lane = wp.tid()
    bd = wp.block_dim()
    ref = k % n_refs
    h = ref_hw[ref][0]
    w = ref_hw[ref][1]
    W = drr.shape[2]
    start = ch * chunk
    stop = wp.min(drr.shape[1] * W, start + chunk)
    tj = wp.tile_zeros(shape=_MB2, dtype=wp.float32, storage="shared")
    td = wp.tile_zeros(shape=_MB_BAND, dtype=wp.float32, storage="shared")
    tf = wp.tile_zeros(shape=_MB_BAND, dtype=wp.float32, storage="shared")
    lo_d = rng[k, 0]
    hi_d = rng[k, 1]
    lo_f = rng[k, 2]
    hi_f = rng[k, 3]
    n_iter = (chunk + bd - 1) // bd
    for it in range(n_iter):  # uniform trip count: every thread reaches the cooperative adds
        p = start + it * bd + lane
        ok = bool(False)
        ia = int(0)
        ib = int(0)
        fa = float(0.0)
        fb = float(0.0)
        if p < stop:
            r = p // W
            c = p - r * W
            if r < h and c < w:
                if _in_omega(drr, fmask, k, ref, r, c, h, w, thr, dil):
                    bdv = _bin(_val(drr, k, r, c), lo_d, hi_d, nb, linear)
                    bfv = _bin(fluoro[ref, r, c] - fshift[ref], lo_f, hi_f, nb, linear)
                    ia = int(bdv[0])
                    ib = int(bfv[0])
                    fa = bdv[1]
                    fb = bfv[1]
                    ok = True
        ja = wp.min(ia + 1, nb - 1)
        jb = wp.min(ib + 1, nb - 1)
        wp.tile_scatter_add(tj, ia * _MB + ib, (1.0 - fa) * (1.0 - fb), ok)
        wp.tile_scatter_add(tj, ia * _MB + jb, (1.0 - fa) * fb, ok)
        wp.tile_scatter_add(tj, ja * _MB + ib, fa * (1.0 - fb), ok)
        wp.tile_scatter_add(tj, ja * _MB + jb, fa * fb, ok)
        wp.tile_scatter_add(td, ia, (1.0 - fa) * (1.0 - fa), ok)
        wp.tile_scatter_add(td, _MB + ia, fa * (1.0 - fa), ok)
        wp.tile_scatter_add(td, ja, fa * fa, ok)
        wp.tile_scatter_add(tf, ib, (1.0 - fb) * (1.0 - fb), ok)
        wp.tile_scatter_add(tf, _MB + ib, fb * (1.0 - fb), ok)
        wp.tile_scatter_add(tf, jb, fb * fb, ok)
    wp.tile_atomic_add(joint, tj, offset=k * _MB2)
    wp.tile_atomic_add(selfd, td, offset=k * _MB_BAND)
    wp.tile_atomic_add(selff, tf, offset=k * _MB_BAND)


@wp.func
def _plogp(x: float, n: float) -> float:
    out = float(0.0)
    if x > 0.0:
        p = x / n
        out = -p * wp.log(p)
    return out


@wp.func
def _self_entropies(band: wp.array(dtype=wp.float32), k: int, nb: int, n: float) -> wp.vec2f:
    """(H_X, H_XX) from a self-joint band histogram."""
    base = k * _MB_BAND
    hx = float(0.0)
    hxx = float(0.0)
    for i in range(nb):
        d = band[base + i]
        o = band[base + _MB + i]
        m = d + o
        if i > 0:
            m += band[base + _MB + i - 1]
        hx += _plogp(m, n)
        hxx += _plogp(d, n) + 2.0 * _plogp(o, n)
    return wp.vec2f(hx, hxx)


@wp.kernel
def entropy_kernel(joint: wp.array(dtype=wp.float32), selfd: wp.array(dtype=wp.float32),
                   selff: wp.array(dtype=wp.float32), nb: int, count: wp.array(dtype=wp.float64),
                   ent: wp.array2d(dtype=wp.float64)):
    """ent[k] = (H_D, H_F, H_DF, H_DD, H_FF) in nats."""
    k = wp.tid()
    n = float(count[k])
    if n > 0.0:
        base = k * _MB2
        hab = float(0.0)
        for i in range(nb):
            for j in range(nb):
                hab += _plogp(joint[base + i * _MB + j], n)
        sd = _self_entropies(selfd, k, nb, n)
        sf = _self_entropies(selff, k, nb, n)
        ent[k, 0] = wp.float64(sd[0])
        ent[k, 1] = wp.float64(sf[0])
        ent[k, 2] = wp.float64(hab)
        ent[k, 3] = wp.float64(sd[1])
        ent[k, 4] = wp.float64(sf[1])
    else:
        for m in range(5):
            ent[k, m] = wp.float64(0.0)


# kinds of the finalize kernel
K_NCC, K_SID, K_GC, K_GD, K_GI, K_GO, K_MI, K_NMI = 0, 1, 2, 3, 4, 5, 6, 7
#: GC of the gradient components: the mean of the Pearson correlations of the u components (sums
#: in ``stats``, :func:`stats_kernel` mode 2) and of the v components (``extra``, mode 3)
K_GCC = 8


@wp.func
def _pearson(a: wp.array2d(dtype=wp.float64), k: int) -> wp.float64:
    # The sums come from float32 lanes: a variance below ~1e-5 of the raw second moment is
    # rounding, not signal (one pixel, a constant image), and then the score is 0 as in numpy;
    # without that guard a one-pixel Ω scored ~9.
    n = a[k, 0]
    out = wp.float64(0.0)
    tol = wp.float64(1.0e-5)
    if n > wp.float64(1.5):
        saa = a[k, 3] - a[k, 1] * a[k, 1] / n
        sbb = a[k, 4] - a[k, 2] * a[k, 2] / n
        sab = a[k, 5] - a[k, 1] * a[k, 2] / n
        den = wp.sqrt(wp.max(saa, wp.float64(0.0)) * wp.max(sbb, wp.float64(0.0)))
        if saa > tol * a[k, 3] and sbb > tol * a[k, 4] and den > wp.float64(0.0):
            out = wp.clamp(sab / den, wp.float64(-1.0), wp.float64(1.0))
    return out


@wp.func
def _concordance(a: wp.array2d(dtype=wp.float64), k: int, shift: wp.float64) -> wp.float64:
    n = a[k, 0]
    out = wp.float64(0.0)
    if n > wp.float64(0.0):
        ma = a[k, 1] / n
        mb = a[k, 2] / n + shift
        saa = wp.max(a[k, 3] - a[k, 1] * a[k, 1] / n, wp.float64(0.0))
        sbb = wp.max(a[k, 4] - a[k, 2] * a[k, 2] / n, wp.float64(0.0))
        sab = a[k, 5] - a[k, 1] * a[k, 2] / n
        den = saa + sbb + n * (ma - mb) * (ma - mb)
        if den > wp.float64(0.0):
            out = wp.float64(2.0) * sab / den
    return out


@wp.func
def _mi(e: wp.array2d(dtype=wp.float64), k: int, normalized: int) -> wp.float64:
    ha = e[k, 0]
    hb = e[k, 1]
    hab = e[k, 2]
    haa = e[k, 3]
    hbb = e[k, 4]
    zero = wp.float64(0.0)
    two = wp.float64(2.0)
    out = zero
    if ha > zero and hb > zero and hab > zero and haa > zero and hbb > zero:
        if normalized == 1:
            da = two * ha / haa - wp.float64(1.0)
            db = two * hb / hbb - wp.float64(1.0)
            if da > zero and db > zero:
                out = wp.max((ha + hb) / hab - wp.float64(1.0), zero) / wp.sqrt(da * db)
        else:
            sa = two * ha - haa
            sb = two * hb - hbb
            if sa > zero and sb > zero:
                out = wp.max(ha + hb - hab, zero) / wp.sqrt(sa * sb)
    return out


@wp.kernel
def finalize_kernel(kind: int, n_per_pose: int, stats: wp.array2d(dtype=wp.float64),
                    extra: wp.array2d(dtype=wp.float64), count: wp.array(dtype=wp.float64),
                    fshift: wp.array(dtype=wp.float32),
                    n_refs: int, n_lb_fraction: float, weights: wp.array(dtype=wp.float32),
                    out: wp.array(dtype=wp.float32)):
    """Per pose b: item scores to out[B + k], their weighted mean to out[b]."""
    b = wp.tid()
    n_pose = out.shape[0] // (n_per_pose + 1)
    total = float(0.0)
    wsum = float(0.0)
    for j in range(n_per_pose):
        k = b * n_per_pose + j
        s = wp.float64(0.0)
        if kind == K_NCC or kind == K_GC:
            s = _pearson(stats, k)
        elif kind == K_GCC:
            s = wp.float64(0.5) * (_pearson(stats, k) + _pearson(extra, k))
        elif kind == K_SID:
            s = _concordance(stats, k, wp.float64(fshift[k % n_refs]))
        elif kind == K_GD:
            s = _concordance(stats, k, wp.float64(0.0))
        elif kind == K_GI:
            if stats[k, 0] > wp.float64(0.0):
                s = extra[k, 0] / stats[k, 0]
        elif kind == K_GO:
            nsel = extra[k, 0]
            if nsel > wp.float64(0.0):
                s = extra[k, 1] / wp.max(nsel, wp.float64(n_lb_fraction) * count[k])
        elif kind == K_MI:
            s = _mi(extra, k, 0)
        else:
            s = _mi(extra, k, 1)
        out[n_pose + k] = float(s)
        total += weights[j] * float(s)
        wsum += weights[j]
    out[b] = total / wsum
