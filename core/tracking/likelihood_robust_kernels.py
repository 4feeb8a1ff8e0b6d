"""The Warp kernels of the likelihood final stage's robust weight factors filtered on the device
(:func:`core.tracking.likelihood_kernels.robust_factors_device`, which launches them; the host's
:func:`core.tracking.final_stage.robust_factors` is the reference): the squared residual over the
used pixels, the separable Gaussian of that pair, the local RMS, its per-view median (the
segmented-sort path; the bisection path's kernels are in :mod:`core.tracking.likelihood_fast`; the
one-sort path's, :func:`_local_rms_keys_kernel` and :func:`_median_signed_kernel`, here) and the
Cauchy or Huber factor. :mod:`core.tracking.likelihood_kernels` re-exports every name."""

from __future__ import annotations

import warp as wp

from .likelihood_fast import sorted_median


@wp.kernel
def _robust_sq_kernel(e: wp.array3d(dtype=wp.float32), w: wp.array3d(dtype=wp.float32),
                      a: wp.array3d(dtype=wp.float32), b: wp.array3d(dtype=wp.float32)):
    """a = e² and b = 1 where the pixel is used (w > 0), 0 elsewhere. dim = items, H, W."""
    k, r, c = wp.tid()
    if w[k, r, c] > 0.0:
        a[k, r, c] = e[k, r, c] * e[k, r, c]
        b[k, r, c] = 1.0
    else:
        a[k, r, c] = 0.0
        b[k, r, c] = 0.0


@wp.kernel
def _blur_pair_kernel(a: wp.array3d(dtype=wp.float32), b: wp.array3d(dtype=wp.float32),
                      g: wp.array(dtype=wp.float32), axis: int, oa: wp.array3d(dtype=wp.float32),
                      ob: wp.array3d(dtype=wp.float32)):
    """oa, ob = a, b filtered by the kernel ``g`` (odd length, centred) along ``axis`` (1: rows, 2:
    columns), zero beyond the array (scipy.ndimage's mode="constant"). dim = items, H, W."""
    k, r, c = wp.tid()
    rad = (g.shape[0] - 1) // 2
    n = a.shape[2]
    if axis == 1:
        n = a.shape[1]
    sa = float(0.0)  # noqa: UP018
    sb = float(0.0)  # noqa: UP018
    for j in range(g.shape[0]):
        rr = r
        cc = c
        if axis == 1:
            rr = r + j - rad
        else:
            cc = c + j - rad
        i = rr if axis == 1 else cc
        if i >= 0 and i < n:
            sa += g[j] * a[k, rr, cc]
            sb += g[j] * b[k, rr, cc]
    oa[k, r, c] = sa
    ob[k, r, c] = sb


@wp.kernel
def _local_rms_kernel(num: wp.array3d(dtype=wp.float32), den: wp.array3d(dtype=wp.float32),
                      w: wp.array3d(dtype=wp.float32), out: wp.array3d(dtype=wp.float32)):
    """out = sqrt(num / max(den, 1e-6)) where the pixel is used, -1 elsewhere. dim = items, H, W."""
    k, r, c = wp.tid()
    if w[k, r, c] > 0.0:
        out[k, r, c] = wp.sqrt(num[k, r, c] / wp.max(den[k, r, c], 1e-6))
    else:
        out[k, r, c] = -1.0


@wp.kernel
def _robust_weight_kernel(local: wp.array3d(dtype=wp.float32), scale: wp.array(dtype=wp.float32),
                          k_: float, cauchy: int, out: wp.array3d(dtype=wp.float32)):
    """out = the robust factor of local / scale[item] (Cauchy or Huber, threshold ``k_``) where
    used (local >= 0), 0 elsewhere; a view with no scale (<= 0) keeps factor 1. dim = items, H, W."""
    k, r, c = wp.tid()
    x = local[k, r, c]
    f = float(0.0)  # noqa: UP018
    if x >= 0.0:
        s = scale[k]
        if s > 0.0:
            u = x / s
            if cauchy == 1:
                f = 1.0 / (1.0 + (u / k_) * (u / k_))
            else:
                f = wp.min(1.0, k_ / wp.max(u, 1e-12))
        else:
            f = 1.0
    out[k, r, c] = f


@wp.kernel
def _median_keys_kernel(local: wp.array3d(dtype=wp.float32), keys: wp.array(dtype=wp.float32),
                        count: wp.array(dtype=wp.int32)):
    """keys[v · H · W + r · W + c] = the local RMS where the pixel is used (local >= 0; NaN is not),
    +inf elsewhere (sorted last); count[v] += the used pixels. dim = items, H, W."""
    v, r, c = wp.tid()
    x = local[v, r, c]
    i = (v * local.shape[1] + r) * local.shape[2] + c
    if x >= 0.0:
        keys[i] = x
        wp.atomic_add(count, v, 1)
    else:
        keys[i] = wp.inf


@wp.kernel
def _median_kernel(keys: wp.array(dtype=wp.float32), count: wp.array(dtype=wp.int32), n: int,
                   scale: wp.array(dtype=wp.float32)):
    """scale[v] = the median of view v's used values (its segment of ``n`` sorted keys, the
    ``count[v]`` used ones first), as ``np.median`` takes it in float32 (the mean of the two middle
    values for an even count); 0 where there are none or it is not finite and positive. dim =
    items."""
    v = wp.tid()
    m = count[v]
    s = float(0.0)  # noqa: UP018
    if m > 0:
        x = (keys[v * n + (m - 1) // 2] + keys[v * n + m // 2]) * 0.5
        if wp.isfinite(x) and x > 0.0:
            s = x
    scale[v] = s


@wp.kernel
def _local_rms_keys_kernel(num: wp.array3d(dtype=wp.float32), den: wp.array3d(dtype=wp.float32),
                           w: wp.array3d(dtype=wp.float32), n: int, out: wp.array3d(dtype=wp.float32),
                           keys: wp.array(dtype=wp.float32)):
    """:func:`_local_rms_kernel` (``out``) and, in the same pass, the median's sort keys of one or
    two views (:data:`~core.tracking.likelihood_kernels.MEDIAN_ONE_SORT`): view v's at ``v · n +
    r · W + c``, view 0's the local RMS (+0 for a zero) and +inf where unused, view 1's their
    negatives (-0 for a zero, -inf where unused). Sorted as unsigned 32-bit integers (the same
    buffer's bits) the keys then hold view 0's values ascending, its unused last, then view 1's
    ascending (the sign bit sets them after every non-negative float; below it the bits of
    non-negative floats order as their values), its unused last. dim = items (1 or 2), H, W."""
    k, r, c = wp.tid()
    x = float(-1.0)  # noqa: UP018
    if w[k, r, c] > 0.0:
        x = wp.sqrt(num[k, r, c] / wp.max(den[k, r, c], 1e-6))
    out[k, r, c] = x
    key = float(wp.inf)
    if x > 0.0:
        key = x
    elif x >= 0.0:  # (a zero of either sign: +0, so that its negative's sign bit is set)
        key = 0.0
    sg = float(1.0)  # noqa: UP018
    if k == 1:  # (a product, not Warp's negation, which compiles as 0 - key: +0 for a zero)
        sg = -1.0
    keys[k * n + r * out.shape[2] + c] = key * sg


@wp.kernel
def _median_signed_kernel(keys: wp.array(dtype=wp.float32), n: int, scale: wp.array(dtype=wp.float32)):
    """:func:`_median_kernel` of :func:`_local_rms_keys_kernel`'s keys sorted as unsigned integers:
    view v's ``n`` sorted keys at ``v · n`` (view 1's negated back), its count of used values the
    keys before the first infinite one (by bisection). dim = items (1 or 2)."""
    v = wp.tid()
    sg = float(1.0)  # noqa: UP018
    if v == 1:
        sg = -1.0
    scale[v] = sorted_median(keys, v * n, n, sg)
