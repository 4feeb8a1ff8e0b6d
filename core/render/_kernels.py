"""Warp kernels for DRR ray casting (see :mod:`core.render.drr` for the model).

One thread renders one pixel of one *item*; an item is one (pose, view, bone) triple. Per item
the host uploads:

* ``item_view``  camera index;
* ``item_vol``   volume index into the atlas tables;
* ``item_org``   the X-ray source in the bone's *voxel index* space (i, j, k);
* ``item_A``     3x3 map from lab directions to index-space directions;
* ``item_roi``   (u0, v0, w, h): the item's region of the full-resolution image, pixels.

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


@wp.func
def _ray_setup(
    item: int,
    row: int,
    col: int,
    scale: float,
    item_view: wp.array(dtype=wp.int32),
    item_vol: wp.array(dtype=wp.int32),
    item_org: wp.array(dtype=wp.vec3f),
    item_A: wp.array(dtype=wp.mat33f),
    item_roi: wp.array(dtype=wp.vec4i),
    cam_M: wp.array(dtype=wp.mat33f),
    vol_dims: wp.array(dtype=wp.vec3i),
):
    """Return (valid, org_idx, dir_idx per mm, t0, t1) for one pixel of one item."""
    roi = item_roi[item]
    u = float(roi[0]) + (float(col) + 0.5) * scale - 0.5
    v = float(roi[1]) + (float(row) + 0.5) * scale - 0.5
    d_lab = cam_M[item_view[item]] * wp.vec3f(u, v, 1.0)
    d_lab = wp.normalize(d_lab)
    d_idx = item_A[item] * d_lab  # index units per mm along the ray
    dims = vol_dims[item_vol[item]]
    lo = wp.vec3f(-1.0, -1.0, -1.0)
    hi = wp.vec3f(float(dims[0]), float(dims[1]), float(dims[2]))
    org = item_org[item]
    t0, t1 = _clip_ray(org, d_idx, lo, hi)
    return org, d_idx, t0, t1


@wp.func
def _inside(row: int, col: int, roi: wp.vec4i, scale: float) -> bool:
    return float(col) * scale < float(roi[2]) and float(row) * scale < float(roi[3])


@wp.kernel
def drr_texture_kernel(
    atlas: wp.Texture3D,
    scale: float,
    step_mm: float,
    item_view: wp.array(dtype=wp.int32),
    item_vol: wp.array(dtype=wp.int32),
    item_org: wp.array(dtype=wp.vec3f),
    item_A: wp.array(dtype=wp.mat33f),
    item_roi: wp.array(dtype=wp.vec4i),
    cam_M: wp.array(dtype=wp.mat33f),
    vol_dims: wp.array(dtype=wp.vec3i),
    vol_zoff: wp.array(dtype=wp.int32),
    out: wp.array3d(dtype=wp.float32),
):
    item, row, col = wp.tid()
    roi = item_roi[item]
    if not _inside(row, col, roi, scale):
        out[item, row, col] = 0.0
        return
    org, d_idx, t0, t1 = _ray_setup(
        item, row, col, scale, item_view, item_vol, item_org, item_A, item_roi, cam_M, vol_dims
    )
    acc = float(0.0)
    if t1 > t0:
        n = int(wp.ceil((t1 - t0) / step_mm))
        dt = (t1 - t0) / float(n)
        # texel (i, j, k) of the padded block is centred at (i + 1.5, j + 1.5, zoff + k + 1.5)
        shift = wp.vec3f(1.5, 1.5, float(vol_zoff[item_vol[item]]) + 1.5)
        p = org + d_idx * (t0 + 0.5 * dt) + shift
        dp = d_idx * dt
        for _s in range(n):
            acc += wp.texture_sample(atlas, p, dtype=float)
            p = p + dp
        acc = acc * dt
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
    scale: float,
    step_mm: float,
    item_view: wp.array(dtype=wp.int32),
    item_vol: wp.array(dtype=wp.int32),
    item_org: wp.array(dtype=wp.vec3f),
    item_A: wp.array(dtype=wp.mat33f),
    item_roi: wp.array(dtype=wp.vec4i),
    cam_M: wp.array(dtype=wp.mat33f),
    vol_dims: wp.array(dtype=wp.vec3i),
    vol_zoff: wp.array(dtype=wp.int32),
    out: wp.array3d(dtype=wp.float32),
):
    item, row, col = wp.tid()
    roi = item_roi[item]
    if not _inside(row, col, roi, scale):
        out[item, row, col] = 0.0
        return
    org, d_idx, t0, t1 = _ray_setup(
        item, row, col, scale, item_view, item_vol, item_org, item_A, item_roi, cam_M, vol_dims
    )
    acc = float(0.0)
    if t1 > t0:
        n = int(wp.ceil((t1 - t0) / step_mm))
        dt = (t1 - t0) / float(n)
        zoff = vol_zoff[item_vol[item]]
        p = org + d_idx * (t0 + 0.5 * dt)
        dp = d_idx * dt
        for _s in range(n):
            acc += _trilinear(atlas, p, zoff)
            p = p + dp
        acc = acc * dt
    out[item, row, col] = acc
