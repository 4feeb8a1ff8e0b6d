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

The line integral is a Riemann sum with samples at distances ``(k + 0.5) * step`` (mm) from the
source that fall inside the clipped chord. The grid is fixed to the ray, so as a bone moves its
DRR changes continuously (the field is zero at the clipping box, so samples enter and leave it
with zero weight): an optimizer sees no jumps from a changing number of steps.
"""

from __future__ import annotations

from typing import Any

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


@wp.func
def _zero_run(dist: wp.array3d(dtype=wp.uint8), p: wp.vec3f, zoff: int, dmax_step: float) -> int:
    """How many samples, from the one at ``p`` on, are provably 0 (exact empty-space skipping).

    ``dist`` holds, per padded atlas voxel, the chessboard distance D (voxels, capped at 255) to
    the nearest non-zero voxel. With v the voxel nearest to ``p`` (|p - v| <= 0.5 per axis), a
    sample j steps further depends only on voxels q with |q - v| < 1.5 + j * dmax_step (per
    axis), which are all zero while 1.5 + j * dmax_step <= D. Hence samples 0..j are zero for
    j <= (D - 1.5) / dmax_step, and none is guaranteed when D < 2.
    """
    x = wp.clamp(int(wp.floor(p[0] + 1.5)), 0, dist.shape[2] - 1)
    y = wp.clamp(int(wp.floor(p[1] + 1.5)), 0, dist.shape[1] - 1)
    z = wp.clamp(int(wp.floor(p[2] + 1.5)) + zoff, 0, dist.shape[0] - 1)
    d = float(dist[z, y, x])
    if d < 2.0:
        return 0
    return int((d - 1.5) / dmax_step) + 1


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


CHUNK = 2  # ray samples issued per loop iteration; on an H100, 2 beat 1, 4 and 8 overall (the
# dense 1024² CT case gains ~20 %, the sparse bone case is unchanged; larger chunks waste
# samples at the bone surface before a skip)

TILE_W = 8  # pixels per thread tile: a warp renders an 8 x 4 patch and a 128-thread block two
TILE_H = 8  # 8 x 8 tiles, so neighbouring threads sample neighbouring voxels (texture cache);
# measured on an H100: 8x8 beat 16x16, 8x4, 16x4, 32x4 and 32x8 tiles and row-major order


def tiled_threads(n_items: int, H: int, W: int) -> int:
    """Number of threads of a tiled launch over ``n_items`` images of ``H x W`` pixels."""
    return n_items * (-(-H // TILE_H)) * (-(-W // TILE_W)) * TILE_W * TILE_H


@wp.func
def _tile_pixel(tid: int, H: int, W: int):
    """Thread -> (item, row, col): TILE_W x TILE_H tiles in row-major order, item after item."""
    tiles_x = (W + TILE_W - 1) // TILE_W
    tiles_y = (H + TILE_H - 1) // TILE_H
    per_tile = TILE_W * TILE_H
    per_item = tiles_x * tiles_y * per_tile
    item = tid // per_item
    r = tid - item * per_item
    tile = r // per_tile
    lane = r - tile * per_tile
    ty = tile // tiles_x
    tx = tile - ty * tiles_x
    return item, ty * TILE_H + lane // TILE_W, tx * TILE_W + lane - (lane // TILE_W) * TILE_W


@wp.func
def _outside(items: wp.array2d(dtype=wp.float32), item: int, row: int, col: int, scale: float) -> bool:
    return float(col) * scale >= items[item, 16] or float(row) * scale >= items[item, 17]


@wp.func
def _trilinear(vol: wp.array3d(dtype=wp.float32), p: wp.vec3f, zoff: int) -> float:
    """Trilinear sample at index (i, j, k) = p of the padded block starting at atlas z = zoff.

    Samples lie in the clipping box [-1, n] up to rounding; coordinates are clamped to its lower
    face (the zero padding), and upper neighbours beyond the atlas are clamped onto the padding
    with zero weight, so a sample a rounding error outside the box reads 0, not a voxel.
    """
    x = wp.max(p[0] + 1.0, 0.0)
    y = wp.max(p[1] + 1.0, 0.0)
    z = wp.max(p[2] + 1.0, 0.0) + float(zoff)
    nx = vol.shape[2]
    ny = vol.shape[1]
    nz = vol.shape[0]
    x0f = wp.floor(x)
    y0f = wp.floor(y)
    z0f = wp.floor(z)
    fx = x - x0f
    fy = y - y0f
    fz = z - z0f
    x0 = wp.min(int(x0f), nx - 1)
    y0 = wp.min(int(y0f), ny - 1)
    z0 = wp.min(int(z0f), nz - 1)
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


@wp.func
def _sample(atlas: wp.Texture3D, p: wp.vec3f, zoff: int) -> float:
    """Hardware-filtered sample at index (i, j, k) = p of the padded block at atlas z = zoff;
    texel (i, j, k) of the padded block is centred at (i + 1.5, j + 1.5, zoff + k + 1.5)."""
    return wp.texture_sample(atlas, p + wp.vec3f(1.5, 1.5, float(zoff) + 1.5), dtype=float)


@wp.func
def _sample(atlas: wp.array3d(dtype=wp.float32), p: wp.vec3f, zoff: int) -> float:
    """Exact float32 trilinear sample (see ``_trilinear``)."""
    return _trilinear(atlas, p, zoff)


@wp.kernel
def drr_kernel(
    atlas: Any,
    dist: wp.array3d(dtype=wp.uint8),
    scale: float,
    step_mm: float,
    value_scale: float,
    items: wp.array2d(dtype=wp.float32),
    cam_M: wp.array(dtype=wp.mat33f),
    vol_dims: wp.array(dtype=wp.vec3i),
    vol_zoff: wp.array(dtype=wp.int32),
    out: wp.array3d(dtype=wp.float32),
):
    item, row, col = _tile_pixel(wp.tid(), out.shape[1], out.shape[2])
    if row >= out.shape[1] or col >= out.shape[2]:
        return
    if _outside(items, item, row, col, scale):
        out[item, row, col] = 0.0
        return
    org, d_idx, t0, t1 = _setup(items, item, row, col, scale, cam_M, vol_dims)
    acc = float(0.0)
    # samples at (k + 0.5) * step_mm from the source (a grid fixed to the ray, not to the volume,
    # so the DRR varies continuously with the pose), for the k whose samples fall in [t0, t1]
    k0 = int(wp.ceil(t0 / step_mm - 0.5))
    n = int(wp.floor(t1 / step_mm - 0.5)) - k0 + 1
    if t1 > t0 and n > 0:
        zoff = vol_zoff[int(items[item, 1])]
        dp = d_idx * step_mm
        dmax_step = wp.max(wp.max(wp.abs(dp[0]), wp.abs(dp[1])), wp.abs(dp[2]))
        p0 = org + d_idx * ((float(k0) + 0.5) * step_mm)
        # In empty space the distance map alone moves the ray on (no texture fetch); once it
        # guarantees nothing, CHUNK independent samples per iteration keep several fetches in
        # flight, until a chunk is all zero and the ray is probed again.
        m = int(0)
        probe = int(1)
        while m < n:
            k = int(0)
            if probe == 1:
                k = _zero_run(dist, p0 + dp * float(m), zoff, dmax_step)
            if k > 0:
                m += k
            else:
                chunk = float(0.0)
                for i in range(CHUNK):
                    if m + i < n:
                        chunk += _sample(atlas, p0 + dp * float(m + i), zoff)
                acc += chunk
                m += CHUNK
                probe = int(chunk == 0.0)
        acc = acc * step_mm * value_scale
    out[item, row, col] = acc


drr_texture_kernel = wp.overload(drr_kernel, {"atlas": wp.Texture3D})
drr_trilinear_kernel = wp.overload(drr_kernel, {"atlas": wp.array3d(dtype=wp.float32)})
