"""The Warp kernels of :mod:`core.tracking.engine_likelihood` (its module docs describe the
quantities: the expected-count weights, the weighted moment tables, the residual and its
projections, the residual's autocovariance and the sandwich's meat) and the robust weight factors
of :mod:`core.tracking.final_stage` filtered on the device (:func:`robust_factors_device`; its
kernels in :mod:`core.tracking.likelihood_robust_kernels`, re-exported here).
:mod:`core.tracking.engine_likelihood` re-exports every name."""

from __future__ import annotations

import numpy as np
import warp as wp

from ..similarity import _kernels as K
from .likelihood_fast import (  # noqa: F401
    _centre,
    _delta,
    _hp,
    _median_keys_only_kernel,
    _median_sorted_kernel,
    moments_z,
)
from .likelihood_robust_kernels import (  # (their names here as before)
    _blur_pair_kernel,
    _local_rms_kernel,
    _local_rms_keys_kernel,
    _median_kernel,
    _median_keys_kernel,
    _median_signed_kernel,
    _robust_sq_kernel,
    _robust_weight_kernel,
)

__all__ = ["regressor_kernels", "robust_factors_device", "robust_one_sort_applies", "robust_sort"]

NZ = 12  # z = (y, D, δ_1..δ_6, 1, u, v, O)
NA = 5  # A = (D, 1, u, v, O): the linear terms residual_kernel reads
vec12f = wp.types.vector(length=NZ, dtype=wp.float32)
mat12f = wp.types.matrix(shape=(NZ, NZ), dtype=wp.float32)
vec5f = wp.types.vector(length=NA, dtype=wp.float32)
vec6f = wp.types.vector(length=6, dtype=wp.float32)
mat66f = wp.types.matrix(shape=(6, 6), dtype=wp.float32)
vec2d = wp.types.vector(length=2, dtype=wp.float64)


@wp.kernel
def psf_kernel(src: wp.array3d(dtype=wp.float32), dst: wp.array3d(dtype=wp.float32),
               psf: wp.array2d(dtype=wp.float32), ref_hw: wp.array(dtype=wp.vec2i), n_refs: int):
    """dst = psf ∗ src within each item's (h, w) region (a convolution, borders replicated, NaN
    read as 0; 0 outside). dim = items, H, W."""
    k, r, c = wp.tid()
    ref = k % n_refs
    h = ref_hw[ref][0]
    w = ref_hw[ref][1]
    acc = float(0.0)  # noqa: UP018 (a Warp variable, not a constant)
    if r < h and c < w:
        ry = (psf.shape[0] - 1) // 2
        rx = (psf.shape[1] - 1) // 2
        for a in range(psf.shape[0]):
            rr = wp.clamp(r - (a - ry), 0, h - 1)
            for b in range(psf.shape[1]):
                acc += psf[a, b] * K._val(src, k, rr, wp.clamp(c - (b - rx), 0, w - 1))
    dst[k, r, c] = acc


@wp.kernel
def weights_kernel(low: wp.array3d(dtype=wp.float32), mask: wp.array3d(dtype=wp.uint8),
                   out: wp.array3d(dtype=wp.float32)):
    """The expected counts exp(-low) where mask, else 0 (low: the smoothed line integrals). dim =
    items, H, W."""
    k, r, c = wp.tid()
    w = float(0.0)  # noqa: UP018
    if mask[k, r, c] != wp.uint8(0):
        w = wp.exp(-low[k, r, c])
    out[k, r, c] = w


@wp.kernel
def others_kernel(img: wp.array3d(dtype=wp.float32), n_bones: int, li: wp.array3d(dtype=wp.float32),
                  ref_hw: wp.array(dtype=wp.vec2i), gain: int, y: wp.array3d(dtype=wp.float32),
                  o: wp.array3d(dtype=wp.float32)):
    """The neighbours' DRRs ``img`` (one pose's items, ordered view, bone) summed in bone order and
    made finite as the host did (``np.nan_to_num`` of the sum: NaN 0, ±inf ±float32 max): with
    ``gain`` kept apart (``o``; ``y`` = the line integrals ``li``), else taken from them (``y = li
    - sum``, ``o`` = 0); 0 outside view v's (h, w) region. dim = (views, H, W)."""
    v, r, c = wp.tid()
    yv = float(0.0)  # noqa: UP018
    ov = float(0.0)  # noqa: UP018
    if r < ref_hw[v][0] and c < ref_hw[v][1]:
        s = img[v * n_bones, r, c]
        for n in range(1, n_bones):
            s = s + img[v * n_bones + n, r, c]
        if wp.isnan(s):
            s = 0.0
        elif wp.isinf(s):
            s = wp.sign(s) * 3.4028234663852886e38
        if gain != 0:
            yv = li[v, r, c]
            ov = s
        else:
            yv = li[v, r, c] - s
    y[v, r, c] = yv
    o[v, r, c] = ov


@wp.kernel
def _times_kernel(a: wp.array3d(dtype=wp.float32), b: wp.array3d(dtype=wp.float32),
                  out: wp.array3d(dtype=wp.float32)):
    """out = a · b. dim = items, H, W."""
    k, r, c = wp.tid()
    out[k, r, c] = a[k, r, c] * b[k, r, c]


#: :func:`robust_factors_device` sorts each view's keys on its own and counts its used pixels in
#: them (no segmented sort, no atomic a pixel; the same median: :mod:`core.tracking.likelihood_fast`);
#: off: one segmented sort, the count taken as the keys are written, as first measured
MEDIAN_BISECT = True
#: With one or two views (a biplane rig), :func:`robust_factors_device`'s keys written by the local RMS's
#: own kernel (:func:`~core.tracking.likelihood_robust_kernels._local_rms_keys_kernel`: view 1's negated)
#: and both views sorted by one radix sort of their bits as unsigned integers, which orders view 0's
#: values, then view 1's, each ascending with its unused pixels last: the same sorted values, so the same
#: median (:func:`~core.tracking.likelihood_robust_kernels._median_signed_kernel`), with one launch and
#: one sort fewer (each sort's host call 80 µs on one NVIDIA H100's host, ``stage_one_bone``'s profile
#: at 97b2893). Off: :data:`MEDIAN_BISECT`'s sort a view.
MEDIAN_ONE_SORT = True


def robust_one_sort_applies(n_views: int) -> bool:
    """Whether :func:`robust_factors_device` takes :data:`MEDIAN_ONE_SORT`'s path for ``n_views``."""
    return bool(MEDIAN_ONE_SORT and n_views <= 2)


def robust_sort(bufs: dict, shape: tuple, device) -> None:
    """:data:`MEDIAN_ONE_SORT`'s sort of the keys in ``bufs`` (:func:`robust_factors_device`'s) of the
    regions' ``shape`` (views, H, W): their bits as unsigned integers, one radix sort."""
    nv, n = shape[0], shape[1] * shape[2]
    keys, vals = bufs["rf_keys"], bufs["rf_vals"]
    bits = bufs.get("rf_bits")
    if bits is None or bits.ptr != keys.ptr or bits.shape != keys.shape:
        bits = bufs["rf_bits"] = wp.array(ptr=keys.ptr, dtype=wp.uint32, shape=keys.shape, device=device)
    wp.utils.radix_sort_pairs(bits, vals, nv * n)


def robust_factors_device(e, w, k: float, *, sigma_px: float = 2.0, kind: str = "cauchy",
                          device=None, bufs: dict | None = None, launch=None):
    """:func:`core.tracking.final_stage.robust_factors` on the device: ``e``, ``w`` ``(views, H, W)``
    Warp arrays (the weighted residual and the weights; a pixel is used where ``w > 0``); the
    factors as a Warp array of that shape. The local RMS is filtered on the device (separable, the
    same Gaussian as the host's) and its per-view median taken there too (the views' used values
    sorted: both in one radix sort, :data:`MEDIAN_ONE_SORT`, else a sort a view or a segmented sort;
    the value of ``np.median``): no
    synchronisation. ``bufs``: the caller's buffers, reused from call to call; ``launch``: the
    caller's ``launch(name, kernel, dim, inputs)`` (recorded launches,
    :meth:`~core.tracking.likelihood_launches._Launches._launch`; default :func:`warp.launch`)."""
    from ..similarity.batched import gaussian_weights  # scipy's gaussian_filter taps (truncate 4)

    device = device if device is not None else e.device
    bufs = {} if bufs is None else bufs
    if launch is None:
        def launch(_name, kernel, dim, inputs):
            wp.launch(kernel, dim=dim, inputs=inputs, device=device)
    shape = tuple(e.shape)

    def buf(name, shp=shape, dtype=wp.float32):
        b = bufs.get(name)
        if b is None or tuple(b.shape) != tuple(shp):
            b = bufs[name] = wp.zeros(shp, dtype=dtype, device=device)
        return b

    nv, n = shape[0], shape[1] * shape[2]
    a, b, ta, tb = buf("rf_a"), buf("rf_b"), buf("rf_ta"), buf("rf_tb")
    g = bufs.get(("rf_taps", float(sigma_px)))
    if g is None:
        g = bufs[("rf_taps", float(sigma_px))] = wp.array(gaussian_weights(sigma_px, truncate=4.0),
                                                          dtype=wp.float32, device=device)
    launch("rf_sq", _robust_sq_kernel, shape, [e, w, a, b])
    launch("rf_blur1", _blur_pair_kernel, shape, [a, b, g, 1, ta, tb])
    launch("rf_blur2", _blur_pair_kernel, shape, [ta, tb, g, 2, a, b])
    local = buf("rf_local")
    keys = buf("rf_keys", (2 * nv * n,))
    vals = buf("rf_vals", (2 * nv * n,), wp.int32)
    scale = buf("rf_scale", (nv,))
    out = buf("rf_out")
    if robust_one_sort_applies(nv):  # both views' keys in one sort of their bits (MEDIAN_ONE_SORT)
        launch("rf_local_keys", _local_rms_keys_kernel, shape, [a, b, w, n, local, keys])
        robust_sort(bufs, shape, device)
        launch("rf_median1", _median_signed_kernel, (nv,), [keys, n, scale])
    else:
        launch("rf_local", _local_rms_kernel, shape, [a, b, w, local])
        count = buf("rf_count", (nv,), wp.int32)
        seg = bufs.get(("rf_seg", nv, n))
        if seg is None:
            starts = np.arange(nv + 1, dtype=np.int32) * n  # the views' segments of the keys
            seg = bufs[("rf_seg", nv, n)] = (wp.array(starts[:-1], dtype=wp.int32, device=device),
                                             wp.array(starts[1:], dtype=wp.int32, device=device))
        if MEDIAN_BISECT:  # each view's n keys at 2n·v, sorted on their own (their scratch after them)
            launch("rf_keys", _median_keys_only_kernel, shape, [local, 2 * n, keys])
            vkey = (keys.ptr, vals.ptr, nv, n)  # (each view's slices of these buffers, made once)
            hit = bufs.get("rf_views")
            if hit is None or hit[0] != vkey:
                parts = [(keys[2 * n * v:2 * n * (v + 1)], vals[2 * n * v:2 * n * (v + 1)])
                         for v in range(nv)]
                hit = bufs["rf_views"] = (vkey, parts)
            for kv, vv in hit[1]:
                wp.utils.radix_sort_pairs(kv, vv, n)
            launch("rf_median", _median_sorted_kernel, (nv,), [keys, n, 2 * n, scale])
        else:
            count.zero_()
            wp.launch(_median_keys_kernel, dim=shape, inputs=[local, keys, count], device=device)
            wp.utils.segmented_sort_pairs(keys, vals, nv * n, seg[0], seg[1])
            wp.launch(_median_kernel, dim=nv, inputs=[keys, count, n, scale], device=device)
    launch("rf_weight", _robust_weight_kernel, shape, [local, scale, float(k), int(kind == "cauchy"), out])
    return out


@wp.kernel
def highpass_kernel(y: wp.array3d(dtype=wp.float32), low: wp.array3d(dtype=wp.float32), hp: float,
                    out: wp.array3d(dtype=wp.float32)):
    """out = y - hp · low. dim = items, H, W."""
    k, r, c = wp.tid()
    out[k, r, c] = y[k, r, c] - hp * low[k, r, c]


@wp.kernel
def wls_moments_kernel(drr: wp.array3d(dtype=wp.float32), low: wp.array3d(dtype=wp.float32), hp: float,
                       y: wp.array3d(dtype=wp.float32), wgt: wp.array3d(dtype=wp.float32),
                       oth: wp.array3d(dtype=wp.float32), ref_hw: wp.array(dtype=wp.vec2i), n_refs: int,
                       chunk: int, acc: wp.array2d(dtype=wp.float64), diff: int):
    """acc[v] += Σ w z zᵀ (row-major 12 × 12), z = (y, D_0, D_1 - D_2, …, D_11 - D_12, 1, u, v, O)
    of view v (item j of view v is j · n_refs + v; D high-passed; O the neighbours' high-passed
    DRRs, 0 without; ``diff`` 1: the images in :func:`~core.tracking.likelihood_fast.
    design_diff_kernel`'s layout). dim = (views, chunks)."""
    v, ch, lane = wp.tid()
    bd = wp.block_dim()
    h = ref_hw[v][0]
    w = ref_hw[v][1]
    W = y.shape[2]
    start = ch * chunk
    stop = wp.min(y.shape[1] * W, start + chunk)
    su = 2.0 / float(wp.max(w - 1, 1))
    sv = 2.0 / float(wp.max(h - 1, 1))
    s = mat12f()
    for p in range(start + lane, stop, bd):
        r = p // W
        c = p - r * W
        if r < h and c < w:
            wt = wgt[v, r, c]
            if wt > 0.0:
                z = moments_z(drr, low, hp, y, oth, n_refs, v, r, c, su, sv, diff)
                s += wt * wp.outer(z, z)
    t = wp.tile_sum(wp.tile(s, preserve_type=True))
    if lane == 0:
        x = t[0]
        for i in range(NZ):
            for j in range(NZ):
                wp.atomic_add(acc, v, i * NZ + j, wp.float64(x[i, j]))


@wp.kernel
def residual_kernel(drr: wp.array3d(dtype=wp.float32), low: wp.array3d(dtype=wp.float32), hp: float,
                    y: wp.array3d(dtype=wp.float32), wgt: wp.array3d(dtype=wp.float32),
                    oth: wp.array3d(dtype=wp.float32), ref_hw: wp.array(dtype=wp.vec2i), n_refs: int,
                    lin: wp.array2d(dtype=wp.float32), e: wp.array3d(dtype=wp.float32),
                    jt: wp.array3d(dtype=vec6f), with_jt: int, diff: int):
    """The weighted residual e = √w (y - A coef) and projected Jacobian J̃_k = √w a (D_k - A β_k)
    of view v at the centre pose; ``lin[v]`` = (coef (5), a, 1/2h (6), β (5 × 6)) with A =
    (D, 1, u, v, O) (unused terms with coefficients 0); ``with_jt`` 0: ``e`` alone (``jt`` not
    written; ``diff``: as :func:`wls_moments_kernel`'s). dim = (views, H, W)."""
    v, r, c = wp.tid()
    h = ref_hw[v][0]
    w = ref_hw[v][1]
    ev = float(0.0)  # noqa: UP018
    jv = vec6f()
    if r < h and c < w:
        wt = wgt[v, r, c]
        if wt > 0.0:
            sw = wp.sqrt(wt)
            a = vec5f()  # (D, 1, u, v, O)
            a[0] = _centre(drr, low, hp, v, r, c)
            a[1] = 1.0
            a[2] = float(c) * 2.0 / float(wp.max(w - 1, 1)) - 1.0
            a[3] = float(r) * 2.0 / float(wp.max(h - 1, 1)) - 1.0
            a[4] = oth[v, r, c]
            fit = float(0.0)  # noqa: UP018
            for q in range(NA):
                fit += lin[v, q] * a[q]
            ev = sw * (y[v, r, c] - fit)
            for k in range(6 * with_jt):
                dk = _delta(drr, low, hp, k, n_refs, v, r, c, diff) * lin[v, NA + 1 + k]
                proj = float(0.0)  # noqa: UP018
                for q in range(NA):
                    proj += lin[v, NA + 7 + q * 6 + k] * a[q]
                jv[k] = sw * lin[v, NA] * (dk - proj)
    e[v, r, c] = ev
    if with_jt != 0:
        jt[v, r, c] = jv


@wp.kernel
def autocov_kernel(e: wp.array3d(dtype=wp.float32), wgt: wp.array3d(dtype=wp.float32),
                   ref_hw: wp.array(dtype=wp.vec2i), lag: int, chunk: int, acc: wp.array3d(dtype=wp.float64)):
    """acc[v, l] += (Σ e_i e_{i+Δ_l}, pairs) over the pairs of usable pixels at lag
    Δ_l = (l // (2 lag + 1) - lag, l % (2 lag + 1) - lag) (rows, columns). dim = (views, lags, chunks):
    the first (2 lag + 1)² // 2 + 1 lags suffice (lag -Δ has the same pairs: :func:`taper_kernel`
    mirrors them)."""
    v, li, ch, lane = wp.tid()
    bd = wp.block_dim()
    h = ref_hw[v][0]
    w = ref_hw[v][1]
    n = 2 * lag + 1
    dr = li // n - lag
    dc = li - (li // n) * n - lag
    W = e.shape[2]
    start = ch * chunk
    stop = wp.min(e.shape[1] * W, start + chunk)
    s = vec2d()
    for p in range(start + lane, stop, bd):
        r = p // W
        c = p - r * W
        rr = r + dr
        cc = c + dc
        if r < h and c < w and rr >= 0 and rr < h and cc >= 0 and cc < w:
            if wgt[v, r, c] > 0.0 and wgt[v, rr, cc] > 0.0:
                s += vec2d(wp.float64(e[v, r, c] * e[v, rr, cc]), wp.float64(1.0))
    t = wp.tile_sum(wp.tile(s, preserve_type=True))
    if lane == 0:
        x = t[0]
        wp.atomic_add(acc, v, li, 0, x[0])
        wp.atomic_add(acc, v, li, 1, x[1])


@wp.kernel
def taper_kernel(acc: wp.array3d(dtype=wp.float64), taper: wp.array(dtype=wp.float64),
                 cw: wp.array2d(dtype=wp.float32)):
    """cw[v, l] = the tapered autocovariance at lag l: the mean product ``acc[v, l, 0] / max(pairs,
    1)`` times ``taper[l]`` (in float64, as the host took it, then float32). ``acc`` holds the first
    half of the lags (and lag 0; :func:`autocov_kernel`): lag l beyond it is lag nl - 1 - l's
    mirror, written into ``acc`` here too. dim = (views, lags)."""
    v, li = wp.tid()
    nl = cw.shape[1]
    k = li
    if li > nl // 2:
        k = nl - 1 - li
        acc[v, li, 0] = acc[v, k, 0]
        acc[v, li, 1] = acc[v, k, 1]
    c = acc[v, k, 0] / wp.max(acc[v, k, 1], wp.float64(1.0))
    cw[v, li] = wp.float32(c * taper[li])


@wp.kernel
def meat_kernel(jt: wp.array3d(dtype=vec6f), cw: wp.array2d(dtype=wp.float32),
                ref_hw: wp.array(dtype=wp.vec2i), lag: int, chunk: int, acc: wp.array2d(dtype=wp.float64),
                half: int):
    """acc[v] += Σ_i J̃_i (Σ_Δ C(Δ) J̃_{i+Δ})ᵀ (row-major 6 × 6; ``cw[v]`` the tapered
    autocovariance per lag). ``half`` 1: the lags after lag 0 (in row-major order) only, each
    counted twice, lag 0 once — a matrix whose symmetric part is the same (``C(-Δ) = C(Δ)``, the
    pairs of usable pixels at ``-Δ`` those at ``Δ`` swapped: the terms of ``-Δ`` are the
    transposes of those of ``Δ``), in half the products. dim = (views, chunks)."""
    v, ch, lane = wp.tid()
    bd = wp.block_dim()
    h = ref_hw[v][0]
    w = ref_hw[v][1]
    n = 2 * lag + 1
    W = jt.shape[2]
    start = ch * chunk
    stop = wp.min(jt.shape[1] * W, start + chunk)
    s = mat66f()
    for p in range(start + lane, stop, bd):
        r = p // W
        c = p - r * W
        if r < h and c < w:
            ji = jt[v, r, c]
            if wp.length_sq(ji) > 0.0:
                u = vec6f()
                # the lags whose pixel is in the region (rows a0..a1, columns b0..b1; the terms and
                # their order those of testing every lag)
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


@wp.kernel
def regressor_sum_kernel(img: wp.array3d(dtype=wp.float32), n_bones: int, ref_hw: wp.array(dtype=wp.vec2i),
                         each: int, out: wp.array3d(dtype=wp.float32)):
    """The extra regressors' images from ``img`` (one pose's items of ``n_bones`` volumes, ordered
    view, volume; NaN read as 0): their sum into ``out[v]`` (``each`` 0) or volume n's into
    ``out[n · views + v]`` (``each`` 1); 0 outside view v's (h, w) region. dim = (views, H, W)."""
    v, r, c = wp.tid()
    nv = ref_hw.shape[0]
    inside = r < ref_hw[v][0] and c < ref_hw[v][1]
    s = float(0.0)  # noqa: UP018
    for n in range(n_bones):
        x = float(0.0)  # noqa: UP018
        if inside:
            x = img[v * n_bones + n, r, c]
            if not wp.isfinite(x):
                x = 0.0
        if each != 0:
            out[n * nv + v, r, c] = x
        else:
            s += x
    if each == 0:
        out[v, r, c] = s


@wp.kernel
def fluence_psf_kernel(src: wp.array3d(dtype=wp.float32), dst: wp.array3d(dtype=wp.float32),
                       psf: wp.array2d(dtype=wp.float32), ref_hw: wp.array(dtype=wp.vec2i), n_refs: int):
    """dst = -log(psf ∗ exp(-src)) within each item's (h, w) region (the line integrals ``src``
    blurred as fluence: borders replicated; 0 outside). dim = items, H, W."""
    k, r, c = wp.tid()
    ref = k % n_refs
    h = ref_hw[ref][0]
    w = ref_hw[ref][1]
    out = float(0.0)  # noqa: UP018
    if r < h and c < w:
        ry = (psf.shape[0] - 1) // 2
        rx = (psf.shape[1] - 1) // 2
        acc = float(0.0)  # noqa: UP018
        for a in range(psf.shape[0]):
            rr = wp.clamp(r - (a - ry), 0, h - 1)
            for b in range(psf.shape[1]):
                acc += psf[a, b] * wp.exp(-src[k, rr, wp.clamp(c - (b - rx), 0, w - 1)])
        out = -wp.log(wp.max(acc, 1e-12))
    dst[k, r, c] = out


_REGRESSOR_KERNELS: dict = {}


def regressor_kernels(q: int) -> tuple:
    """``(moments, residual)``: :func:`wls_moments_kernel` and :func:`residual_kernel` with ``q``
    extra regressors a view (``q`` 0: those two themselves). The table's ``z`` gains
    ``T_1 … T_q`` after ``O`` (``12 + q`` entries) and ``A = (D, 1, u, v, O, T_1 … T_q)`` (``lin``:
    ``coef (5 + q), a, 1/2h (6), β ((5 + q) × 6)``); both take ``reg`` (``q · views`` items,
    item ``j · views + v`` regressor j of view v, as given: :meth:`~core.tracking.engine_likelihood.
    LikelihoodEngine.set_frame`) after ``oth``, and ``diff`` last. The other terms and their sums are
    those of the plain kernels."""
    q = int(q)
    if q == 0:
        return wls_moments_kernel, residual_kernel
    hit = _REGRESSOR_KERNELS.get(q)
    if hit is not None:
        return hit
    nz, na = NZ + q, NA + q
    vz = wp.types.vector(length=nz, dtype=wp.float32)
    mz = wp.types.matrix(shape=(nz, nz), dtype=wp.float32)
    va = wp.types.vector(length=na, dtype=wp.float32)

    @wp.kernel(module="unique")
    def moments(drr: wp.array3d(dtype=wp.float32), low: wp.array3d(dtype=wp.float32), hp: float,
                y: wp.array3d(dtype=wp.float32), wgt: wp.array3d(dtype=wp.float32),
                oth: wp.array3d(dtype=wp.float32), reg: wp.array3d(dtype=wp.float32),
                ref_hw: wp.array(dtype=wp.vec2i), n_refs: int, chunk: int, acc: wp.array2d(dtype=wp.float64),
                diff: int):
        v, ch, lane = wp.tid()
        bd = wp.block_dim()
        h = ref_hw[v][0]
        w = ref_hw[v][1]
        W = y.shape[2]
        start = ch * chunk
        stop = wp.min(y.shape[1] * W, start + chunk)
        su = 2.0 / float(wp.max(w - 1, 1))
        sv = 2.0 / float(wp.max(h - 1, 1))
        s = mz()
        for p in range(start + lane, stop, bd):
            r = p // W
            c = p - r * W
            if r < h and c < w:
                wt = wgt[v, r, c]
                if wt > 0.0:
                    z0 = moments_z(drr, low, hp, y, oth, n_refs, v, r, c, su, sv, diff)
                    z = vz()
                    for j in range(NZ):
                        z[j] = z0[j]
                    for j in range(q):
                        z[NZ + j] = reg[j * n_refs + v, r, c]
                    s += wt * wp.outer(z, z)
        t = wp.tile_sum(wp.tile(s, preserve_type=True))
        if lane == 0:
            x = t[0]
            for i in range(nz):
                for j in range(nz):
                    wp.atomic_add(acc, v, i * nz + j, wp.float64(x[i, j]))

    @wp.kernel(module="unique")
    def residual(drr: wp.array3d(dtype=wp.float32), low: wp.array3d(dtype=wp.float32), hp: float,
                 y: wp.array3d(dtype=wp.float32), wgt: wp.array3d(dtype=wp.float32),
                 oth: wp.array3d(dtype=wp.float32), reg: wp.array3d(dtype=wp.float32),
                 ref_hw: wp.array(dtype=wp.vec2i), n_refs: int, lin: wp.array2d(dtype=wp.float32),
                 e: wp.array3d(dtype=wp.float32), jt: wp.array3d(dtype=vec6f), with_jt: int, diff: int):
        v, r, c = wp.tid()
        h = ref_hw[v][0]
        w = ref_hw[v][1]
        ev = float(0.0)  # noqa: UP018
        jv = vec6f()
        if r < h and c < w:
            wt = wgt[v, r, c]
            if wt > 0.0:
                sw = wp.sqrt(wt)
                a = va()  # (D, 1, u, v, O, T_1 … T_q)
                a[0] = _centre(drr, low, hp, v, r, c)
                a[1] = 1.0
                a[2] = float(c) * 2.0 / float(wp.max(w - 1, 1)) - 1.0
                a[3] = float(r) * 2.0 / float(wp.max(h - 1, 1)) - 1.0
                a[4] = oth[v, r, c]
                for j in range(q):
                    a[5 + j] = reg[j * n_refs + v, r, c]
                fit = float(0.0)  # noqa: UP018
                for k in range(na):
                    fit += lin[v, k] * a[k]
                ev = sw * (y[v, r, c] - fit)
                for k in range(6 * with_jt):
                    dk = _delta(drr, low, hp, k, n_refs, v, r, c, diff) * lin[v, na + 1 + k]
                    proj = float(0.0)  # noqa: UP018
                    for m in range(na):
                        proj += lin[v, na + 7 + m * 6 + k] * a[m]
                    jv[k] = sw * lin[v, na] * (dk - proj)
        e[v, r, c] = ev
        if with_jt != 0:
            jt[v, r, c] = jv

    hit = _REGRESSOR_KERNELS[q] = (moments, residual)
    return hit
