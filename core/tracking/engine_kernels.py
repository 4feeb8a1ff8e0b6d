"""Device kernels of the Gauss–Newton engine (:mod:`core.tracking.engine`).

* :func:`moments_kernel` — per view the 9 × 9 moment matrix of ``z = (1, a, b, δ_1 … δ_6)`` of a
  13-pose step (the engine's module docs); the quantity is the intensity (mode 0), the gradient
  magnitude (1) or one gradient component (2: u, 3: v; GC of the components launches it twice);
* :func:`subtract_kernel` — the neighbours' DRRs taken from the fluoroscope regions (joint
  tracking);
* :func:`fluoro_gradient_kernel` — the 3 × 3 gradient of the smoothed fluoroscope regions;
* :func:`keep_kernel` — the band at the round field's rim taken out of the usable pixels;
* :func:`fluoro_roi_kernel`, :func:`fluoro_shift_kernel` — the device preparation of the
  full-resolution fluoroscope regions (line integrals, usable pixels, their statistics) from
  the fluence uploaded as it is;
* :func:`pose_table_kernel` — the DRR item table of the engine's poses from their parameters
  (the arithmetic of :func:`core.tracking.engine_render.host_poses` and
  :func:`~core.tracking.engine_render.render_items`, in float64), so that a step's poses, DRRs
  and metric are one CUDA graph.
"""

from __future__ import annotations

import warp as wp

from ..similarity import _kernels as K

__all__ = ["GEO_LEN", "LI_FLOOR", "N_POSES", "fluoro_gradient_kernel", "fluoro_roi_kernel",
           "fluoro_shift_kernel", "keep_kernel", "moments_kernel", "pose_table_kernel", "subtract_kernel"]

N_POSES = 13  # poses per step: the centre and ±h_k e_k

vec9f = wp.types.vector(length=9, dtype=wp.float32)
mat99f = wp.types.matrix(shape=(9, 9), dtype=wp.float32)


@wp.func
def _bq(mode: int, img: wp.array3d(dtype=wp.float32), k: int, r: int, c: int, h: int, w: int,
        ku: wp.mat33f, kv: wp.mat33f) -> float:
    """The DRR quantity b of item k at (r, c): intensity (mode 0), gradient magnitude (1) or the
    gradient's u (2) or v (3) component."""
    out = float(0.0)  # noqa: UP018 (a Warp variable, not a constant)
    if mode == 0:
        out = K._val(img, k, r, c)
    elif mode == 1:
        out = wp.length(K._grad(img, k, r, c, h, w, ku, kv))
    else:
        out = K._grad(img, k, r, c, h, w, ku, kv)[mode - 2]
    return out


@wp.kernel
def moments_kernel(drr: wp.array3d(dtype=wp.float32), fluoro: wp.array3d(dtype=wp.float32),
                   fgrad: wp.array3d(dtype=wp.vec2f), fmask: wp.array3d(dtype=wp.uint8),
                   ref_hw: wp.array(dtype=wp.vec2i), fshift: wp.array(dtype=wp.float32), n_refs: int,
                   thr: float, dil: int, mode: int, ku: wp.mat33f, kv: wp.mat33f, chunk: int,
                   acc: wp.array2d(dtype=wp.float64)):
    """acc[v] += Σ_Ω z zᵀ (row-major 9 × 9), z = (1, a, b_0, b_1 - b_2, …, b_11 - b_12) of view v;
    item j of view v is j · n_refs + v; Ω is that of the centre item (j = 0). dim = (views, chunks)."""
    v, ch, lane = wp.tid()
    bd = wp.block_dim()
    h = ref_hw[v][0]
    w = ref_hw[v][1]
    W = drr.shape[2]
    start = ch * chunk
    stop = wp.min(drr.shape[1] * W, start + chunk)
    s = mat99f()
    for p in range(start + lane, stop, bd):
        r = p // W
        c = p - r * W
        if r < h and c < w:
            if K._in_omega(drr, fmask, v, v, r, c, h, w, thr, dil):
                a = float(0.0)  # noqa: UP018
                if mode == 0:
                    a = fluoro[v, r, c] - fshift[v]
                elif mode == 1:
                    a = wp.length(fgrad[v, r, c])
                else:
                    a = fgrad[v, r, c][mode - 2]
                z = vec9f()
                z[0] = 1.0
                z[1] = a
                z[2] = _bq(mode, drr, v, r, c, h, w, ku, kv)
                for j in range(6):
                    bp = _bq(mode, drr, (2 * j + 1) * n_refs + v, r, c, h, w, ku, kv)
                    bm = _bq(mode, drr, (2 * j + 2) * n_refs + v, r, c, h, w, ku, kv)
                    z[3 + j] = bp - bm
                s += wp.outer(z, z)
    t = wp.tile_sum(wp.tile(s, preserve_type=True))
    if lane == 0:
        x = t[0]
        for i in range(9):
            for j in range(9):
                wp.atomic_add(acc, v, i * 9 + j, wp.float64(x[i, j]))


@wp.kernel
def subtract_kernel(src: wp.array3d(dtype=wp.float32), drr: wp.array3d(dtype=wp.float32), n_bones: int,
                    out: wp.array3d(dtype=wp.float32)):
    """out[v] = src[v] - Σ_n drr[v · n_bones + n] (one pose's items, ordered view, bone).
    dim = (views, H, W)."""
    v, r, c = wp.tid()
    acc = float(0.0)  # noqa: UP018
    for n in range(n_bones):
        acc += K._val(drr, v * n_bones + n, r, c)
    out[v, r, c] = src[v, r, c] - acc


@wp.kernel
def keep_kernel(mask: wp.array3d(dtype=wp.uint8), keep: wp.array3d(dtype=wp.uint8)):
    """mask = 0 where keep is 0 (the band at the round field's rim out of the domain). dim = (views,
    H, W)."""
    v, r, c = wp.tid()
    if keep[v, r, c] == wp.uint8(0):
        mask[v, r, c] = wp.uint8(0)


@wp.kernel
def fluoro_gradient_kernel(f: wp.array3d(dtype=wp.float32), ref_hw: wp.array(dtype=wp.vec2i),
                           fmax: wp.array(dtype=wp.float32), ku: wp.mat33f, kv: wp.mat33f,
                           noise: int, e1: wp.array(dtype=wp.float32), ys: wp.array3d(dtype=wp.float32),
                           out: wp.array3d(dtype=wp.vec2f)):
    """3 × 3 gradient of each fluoroscope ROI (replicated borders), 0 where its length is below
    ``ZERO_GRADIENT · max(1, max |f|)`` (as :class:`core.similarity.BatchedMetric` prepares it on
    the host) and outside the ROI. With ``noise`` the gradient is shortened to the debiased
    magnitude ``sqrt(max(|g|² - E, 0))`` (:func:`core.similarity.gradient.debiased_magnitude`),
    ``E = e1[v] · exp(ys[v, r, c])``: the noise's expected squared gradient at full fluence over
    the fluence of the smoothed, unsubtracted line integrals ``ys``
    (:func:`core.tracking.cost.noise_maps`). dim = (views, H, W)."""
    v, r, c = wp.tid()
    h = ref_hw[v][0]
    w = ref_hw[v][1]
    g = wp.vec2f(0.0, 0.0)
    if r < h and c < w:
        gu = float(0.0)  # noqa: UP018
        gv = float(0.0)  # noqa: UP018
        for a in range(3):
            rr = wp.clamp(r + a - 1, 0, h - 1)
            for b in range(3):
                cc = wp.clamp(c + b - 1, 0, w - 1)
                x = f[v, rr, cc]
                gu += ku[a, b] * x
                gv += kv[a, b] * x
        g = wp.vec2f(gu, gv)
        if wp.length(g) <= K.ZERO_GRADIENT * wp.max(1.0, fmax[v]):
            g = wp.vec2f(0.0, 0.0)
        elif noise != 0:
            m2 = wp.length_sq(g)
            e = e1[v] * wp.exp(ys[v, r, c])
            g = g * wp.sqrt(wp.max(m2 - e, 0.0) / m2)
    out[v, r, c] = g


_LANES = 128  # threads per (view, chunk) of fluoro_roi_kernel
LI_FLOOR = wp.constant(1.0 / 4096.0)  # core.tracking.cost's line-integral floor


@wp.kernel
def fluoro_roi_kernel(src: wp.array3d(dtype=wp.float32), given: wp.array3d(dtype=wp.uint8),
                      info: wp.array2d(dtype=wp.int32), lo: float, hi: float, p: int, check: int, chunk: int,
                      raw: wp.array3d(dtype=wp.float32), fmask: wp.array3d(dtype=wp.uint8),
                      fmax: wp.array(dtype=wp.float32), msum: wp.array2d(dtype=wp.float64)):
    """Each view's search region in DRR polarity ``-ln clip(I, 1/4096, 1)`` and its usable pixels,
    as :meth:`core.tracking.cost.FrameImages.region` computes them on the host: ``src[v]`` holds
    the fluence of the region grown by ``p`` pixels (clipped to the image) and ``given[v]`` the
    frame's own mask there; ``info[v] = (h, w, oy, ox, hs, ws, has_given, _)`` (the region's size,
    its offset in ``src``, the staged size). With ``check``, a pixel is usable when every pixel
    within L1 distance ``p`` inside the image lies in ``(lo, hi)`` (the cross erosion iterated
    ``p`` times, outside the image counted usable). ``fmax[v]`` = max over the region,
    ``msum[v] = (usable pixels, Σ usable values)``. dim = (views, chunks, _LANES)."""
    v, ch, lane = wp.tid()
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
    s = float(0.0)  # noqa: UP018
    mx = float(0.0)  # noqa: UP018
    for q in range(start + lane, stop, _LANES):
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
            mx = wp.max(mx, x)
            if ok != 0:
                n += 1.0
                s += x
        raw[v, r, c] = x
        fmask[v, r, c] = wp.uint8(ok)
    if mx > 0.0:
        wp.atomic_max(fmax, v, mx)
    if n > 0.0:
        wp.atomic_add(msum, v, 0, wp.float64(n))
        wp.atomic_add(msum, v, 1, wp.float64(s))


@wp.kernel
def fluoro_shift_kernel(msum: wp.array2d(dtype=wp.float64), mode: int, fshift: wp.array(dtype=wp.float32),
                        count: wp.array(dtype=wp.int32)):
    """NCC: the mean of each view's usable values (0 for GC); the usable pixels' count. dim = views."""
    v = wp.tid()
    n = msum[v, 0]
    m = float(0.0)  # noqa: UP018
    if mode == 0 and n > wp.float64(0.0):
        m = float(msum[v, 1] / n)
    fshift[v] = m
    count[v] = int(n)


#: pose_table_kernel's geometry: base rotation (9), translation (3), centre (3), index rows (12);
#: the ROIs follow
GEO_LEN = wp.constant(27)
_DEG = wp.constant(wp.float64(0.017453292519943295))  # numpy.radians' factor, pi / 180


@wp.kernel
def pose_table_kernel(X: wp.array2d(dtype=wp.float64), geo: wp.array(dtype=wp.float64),
                      src: wp.array2d(dtype=wp.float64), view_ids: wp.array(dtype=wp.int32), bone: int,
                      items: wp.array2d(dtype=wp.float32)):
    """Row ``b · n_views + v`` of the DRR item table (:data:`core.render._kernels.ITEM_COLS`
    columns: view, bone, the source in index coordinates, index-from-physical ∘ inverse pose,
    the ROI) of pose ``b``: ``x = X[b]`` (mm, degrees about the centre, relative to the base
    pose; Rodrigues' formula) in view ``v`` (``src[v]``: its homogeneous source). ``geo``: the base
    pose's rotation (row-major) and translation, the centre, the bone's index-from-physical rows
    (3 × 4, row-major), then each view's ROI ``(u0, v0, w, h)``. dim = (poses, views)."""
    b, v = wp.tid()
    nv = src.shape[0]
    r0 = X[b, 3] * _DEG
    r1 = X[b, 4] * _DEG
    r2 = X[b, 5] * _DEG
    th = wp.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
    one = wp.float64(1.0)
    zero = wp.float64(0.0)
    Rd = wp.mat33d(one, zero, zero, zero, one, zero, zero, zero, one)
    if th >= wp.float64(1.0e-8):
        k0 = r0 / th
        k1 = r1 / th
        k2 = r2 / th
        Kx = wp.mat33d(zero, -k2, k1, k2, zero, -k0, -k1, k0, zero)
        Rd = Rd + wp.sin(th) * Kx + (one - wp.cos(th)) * (Kx @ Kx)
    Rb = wp.mat33d(geo[0], geo[1], geo[2], geo[3], geo[4], geo[5], geo[6], geo[7], geo[8])
    tb = wp.vec3d(geo[9], geo[10], geo[11])
    ce = wp.vec3d(geo[12], geo[13], geo[14])
    R = Rd @ Rb
    t = (Rb @ ce + tb) + wp.vec3d(X[b, 0], X[b, 1], X[b, 2]) - R @ ce
    T = wp.mat33d(geo[15], geo[16], geo[17], geo[19], geo[20], geo[21], geo[23], geo[24], geo[25])
    Tt = wp.vec3d(geo[18], geo[22], geo[26])
    M = T @ wp.transpose(R)
    tt = Tt - M @ t
    p = M @ wp.vec3d(src[v, 0], src[v, 1], src[v, 2]) + tt * src[v, 3]
    i = b * nv + v
    items[i, 0] = wp.float32(view_ids[v])
    items[i, 1] = wp.float32(bone)
    for a in range(3):
        items[i, 2 + a] = wp.float32(p[a])
        for c in range(3):
            items[i, 5 + 3 * a + c] = wp.float32(M[a, c])
    for a in range(4):
        items[i, 14 + a] = wp.float32(geo[GEO_LEN + 4 * v + a])
