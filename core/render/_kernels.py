"""Warp kernels for DRR ray casting (see :mod:`core.render.drr` for the model).

One thread renders one pixel of one *item*; an item is one (pose, view, bone) triple. Per item
the host uploads one row of ``items`` (float32, exact for the small integers it holds):

* ``[0]`` camera index, ``[1]`` volume index;
* ``[2:5]`` the X-ray source in the bone's *voxel index* space (i, j, k);
* ``[5:14]`` row-major 3x3 map from lab directions to index-space directions;
* ``[14:18]`` ``(u0, v0, w, h)``: the item's region of the full-resolution image, pixels.

Per camera: ``cam_M = R^T K^-1`` (pixel (u, v, 1) -> lab direction). Per volume: its size
(nx, ny, nz) and the z offset of its block in the atlas; blocks carry one voxel of zero padding
on every side, so the attenuation field is the trilinear interpolant of the voxels with zeros
outside the volume, and a ray is clipped to the padded box ``[-1, n]`` in index units.

The line integral uses the midpoint rule with ``n = ceil(L / step)`` equal steps over the clipped
chord of length ``L`` (mm), so every ray is sampled with a step of at most ``step`` mm.
"""

from __future__ import annotations

import warp as wp


@wp.func
def _clip_ray(org: wp.vec3f, dir: wp.vec3f, lo: wp.vec3f, hi: wp.vec3f):
    """Slab test: parametric entry/exit (t0, t1) of ``org + t * dir`` in the box [lo, hi]."""
    t0 = float(-1.0e30)
    t1 = float(1.0e30)
    for a in range(3):
        d = dir[a]
        if wp.abs(d) < 1.0e-12:
            if org[a] < lo[a] or org[a] > hi[a]:
                t0 = 1.0
                t1 = 0.0
        else:
            ta = (lo[a] - org[a]) / d
            tb = (hi[a] - org[a]) / d
            t0 = wp.max(t0, wp.min(ta, tb))
            t1 = wp.min(t1, wp.max(ta, tb))
    t0 = wp.max(t0, 0.0)
    return t0, t1


ITEM_COLS = 18


@wp.func
def _item_mat(items: wp.array2d(dtype=wp.float32), i: int) -> wp.mat33f:
    return wp.mat33f(
        items[i, 5], items[i, 6], items[i, 7],
        items[i, 8], items[i, 9], items[i, 10],
        items[i, 11], items[i, 12], items[i, 13],
    )


BRICK = 4  # voxels per empty-space brick edge


@wp.func
def _empty_steps(bricks: wp.array3d(dtype=wp.uint8), p: wp.vec3f, zoff: int, dmax_step: float) -> int:
    """Samples, from this one on, that are provably 0 (exact empty-space skipping); 0 if none.

    The padded atlas is cut into bricks of ``BRICK``³ voxels; brick ``b`` covers atlas voxels
    ``[4b, 4b + 3]`` and is *occupied* when any voxel in ``[4b - 1, 4b + 4]`` (its trilinear
    support) is non-zero. ``bricks`` holds the chessboard distance Db (in bricks, capped at 255)
    to the nearest occupied brick. A point in an empty brick (Db >= 1) that moves by at most
    ``BRICK * (Db - 1)`` voxels per axis stays in empty bricks, so the current sample and the
    next ``floor(BRICK * (Db - 1) / dmax_step)`` ones are exactly zero.
    """
    # atlas voxel coordinates (voxel centres at integers) -> brick index
    bx = wp.clamp(int(wp.floor((p[0] + 1.5) * 0.25)), 0, bricks.shape[2] - 1)
    by = wp.clamp(int(wp.floor((p[1] + 1.5) * 0.25)), 0, bricks.shape[1] - 1)
    bz = wp.clamp(int(wp.floor((p[2] + 1.5 + float(zoff)) * 0.25)), 0, bricks.shape[0] - 1)
    d = int(bricks[bz, by, bx])
    if d == 0:
        return 0
    return 1 + int(float(BRICK * (d - 1)) / dmax_step)


@wp.func
def _setup(items: wp.array2d(dtype=wp.float32), item: int, row: int, col: int, scale: float,
           cam_M: wp.array(dtype=wp.mat33f), vol_dims: wp.array(dtype=wp.vec3i)):
    """(org_idx, dir_idx per mm, t0, t1) of one pixel's ray, clipped to the padded volume box."""
    u = items[item, 14] + (float(col) + 0.5) * scale - 0.5
    v = items[item, 15] + (float(row) + 0.5) * scale - 0.5
    d_lab = wp.normalize(cam_M[int(items[item, 0])] * wp.vec3f(u, v, 1.0))
    d_idx = _item_mat(items, item) * d_lab
    dims = vol_dims[int(items[item, 1])]
    org = wp.vec3f(items[item, 2], items[item, 3], items[item, 4])
    lo = wp.vec3f(-1.0, -1.0, -1.0)
    hi = wp.vec3f(float(dims[0]), float(dims[1]), float(dims[2]))
    t0, t1 = _clip_ray(org, d_idx, lo, hi)
    return org, d_idx, t0, t1


@wp.func
def _outside(items: wp.array2d(dtype=wp.float32), item: int, row: int, col: int, scale: float) -> bool:
    return float(col) * scale >= items[item, 16] or float(row) * scale >= items[item, 17]


@wp.kernel
def drr_texture_kernel(
    atlas: wp.Texture3D,
    bricks: wp.array3d(dtype=wp.uint8),
    scale: float,
    step_mm: float,
    value_scale: float,
    items: wp.array2d(dtype=wp.float32),
    cam_M: wp.array(dtype=wp.mat33f),
    vol_dims: wp.array(dtype=wp.vec3i),
    vol_zoff: wp.array(dtype=wp.int32),
    out: wp.array3d(dtype=wp.float32),
):
    item, row, col = wp.tid()
    if _outside(items, item, row, col, scale):
        out[item, row, col] = 0.0
        return
    org, d_idx, t0, t1 = _setup(items, item, row, col, scale, cam_M, vol_dims)
    acc = float(0.0)
    if t1 > t0:
        n = int(wp.ceil((t1 - t0) / step_mm))
        dt = (t1 - t0) / float(n)
        zoff = vol_zoff[int(items[item, 1])]
        dp = d_idx * dt
        dmax_step = wp.max(wp.max(wp.abs(dp[0]), wp.abs(dp[1])), wp.abs(dp[2]))
        p0 = org + d_idx * (t0 + 0.5 * dt)
        # texel (i, j, k) of the padded block is centred at (i + 1.5, j + 1.5, zoff + k + 1.5)
        shift = wp.vec3f(1.5, 1.5, float(zoff) + 1.5)
        m = int(0)
        while m < n:
            p = p0 + dp * float(m)
            k = _empty_steps(bricks, p, zoff, dmax_step)
            if k > 0:
                m += k
            else:
                acc += wp.texture_sample(atlas, p + shift, dtype=float)
                m += 1
        acc = acc * dt * value_scale
    out[item, row, col] = acc


@wp.func
def _trilinear(vol: wp.array3d(dtype=wp.float32), p: wp.vec3f, zoff: int) -> float:
    """Trilinear sample at index (i, j, k) = p of the padded block starting at atlas z = zoff."""
    x = p[0] + 1.0
    y = p[1] + 1.0
    z = p[2] + 1.0 + float(zoff)
    nx = vol.shape[2]
    ny = vol.shape[1]
    nz = vol.shape[0]
    x0f = wp.floor(x)
    y0f = wp.floor(y)
    z0f = wp.floor(z)
    fx = x - x0f
    fy = y - y0f
    fz = z - z0f
    x0 = wp.clamp(int(x0f), 0, nx - 1)
    y0 = wp.clamp(int(y0f), 0, ny - 1)
    z0 = wp.clamp(int(z0f), 0, nz - 1)
    x1 = wp.min(x0 + 1, nx - 1)
    y1 = wp.min(y0 + 1, ny - 1)
    z1 = wp.min(z0 + 1, nz - 1)
    c00 = vol[z0, y0, x0] * (1.0 - fx) + vol[z0, y0, x1] * fx
    c01 = vol[z0, y1, x0] * (1.0 - fx) + vol[z0, y1, x1] * fx
    c10 = vol[z1, y0, x0] * (1.0 - fx) + vol[z1, y0, x1] * fx
    c11 = vol[z1, y1, x0] * (1.0 - fx) + vol[z1, y1, x1] * fx
    c0 = c00 * (1.0 - fy) + c01 * fy
    c1 = c10 * (1.0 - fy) + c11 * fy
    return c0 * (1.0 - fz) + c1 * fz


@wp.kernel
def drr_trilinear_kernel(
    atlas: wp.array3d(dtype=wp.float32),
    bricks: wp.array3d(dtype=wp.uint8),
    scale: float,
    step_mm: float,
    value_scale: float,
    items: wp.array2d(dtype=wp.float32),
    cam_M: wp.array(dtype=wp.mat33f),
    vol_dims: wp.array(dtype=wp.vec3i),
    vol_zoff: wp.array(dtype=wp.int32),
    out: wp.array3d(dtype=wp.float32),
):
    item, row, col = wp.tid()
    if _outside(items, item, row, col, scale):
        out[item, row, col] = 0.0
        return
    org, d_idx, t0, t1 = _setup(items, item, row, col, scale, cam_M, vol_dims)
    acc = float(0.0)
    if t1 > t0:
        n = int(wp.ceil((t1 - t0) / step_mm))
        dt = (t1 - t0) / float(n)
        zoff = vol_zoff[int(items[item, 1])]
        dp = d_idx * dt
        dmax_step = wp.max(wp.max(wp.abs(dp[0]), wp.abs(dp[1])), wp.abs(dp[2]))
        p0 = org + d_idx * (t0 + 0.5 * dt)
        m = int(0)
        while m < n:
            p = p0 + dp * float(m)
            k = _empty_steps(bricks, p, zoff, dmax_step)
            if k > 0:
                m += k
            else:
                acc += _trilinear(atlas, p, zoff)
                m += 1
        acc = acc * dt * value_scale
    out[item, row, col] = acc
