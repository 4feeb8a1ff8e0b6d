"""Exact line integrals through simple objects (beads, plates, boxes, cylinders) and attenuation data.

Every function here returns ``∫ μ dl`` (unitless) per pixel for rays from the camera's source
through sub-pixel positions, averaged over ``supersample × supersample`` rays per pixel (box
anti-aliasing of the detector pixel). The chord of a ray through

* a sphere of radius ``r`` whose centre lies at perpendicular distance ``d`` from the ray is
  ``2·sqrt(r² - d²)`` (0 for ``d >= r``);
* a box, a finite cylinder or a slab is the length of the ray's parameter interval inside all of
  its bounding slabs / the cylinder's disc (Kay–Kajiya slab test).

These are the ground truth for markers and calibration hardware: nothing is voxelised.

Attenuation coefficients
------------------------
:func:`attenuation_per_mm` and its tables live in :mod:`core.render.attenuation` (the library
uses them too) and are re-exported here.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .._validate import as_float_array, as_points, check_rigid, positive
from ..geometry.camera import Camera
from ..render.attenuation import DENSITY_G_CM3, MASS_ATTENUATION_CM2_G, attenuation_per_mm

__all__ = [
    "DENSITY_G_CM3",
    "MASS_ATTENUATION_CM2_G",
    "attenuation_per_mm",
    "bead_line_integrals",
    "box_line_integrals",
    "cylinder_line_integrals",
    "slab_chords",
    "slab_line_integrals",
    "sphere_chords",
]

# ---------------------------------------------------------------------------- chords
def sphere_chords(origin: np.ndarray, dirs: np.ndarray, centers: np.ndarray, radii: np.ndarray):
    """Chord lengths (mm) of rays ``origin + t·dirs`` (unit dirs, t > 0) through spheres (row-wise)."""
    w = centers - origin
    cr = np.cross(w, dirs)
    d2 = np.einsum("ij,ij->i", cr, cr)
    ahead = np.einsum("ij,ij->i", w, dirs) > 0
    return np.where(ahead, 2.0 * np.sqrt(np.maximum(radii * radii - d2, 0.0)), 0.0)


def _slab_interval(o, d, lo, hi):
    """Parameter interval of rays (o, d) (N, k) inside ``lo <= x <= hi`` per axis (k axes)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = (lo - o) / d, (hi - o) / d
    par = np.abs(d) < 1e-15
    inside = (o >= lo) & (o <= hi)
    t0 = np.where(par, np.where(inside, -np.inf, np.inf), np.minimum(ta, tb))
    t1 = np.where(par, np.where(inside, np.inf, -np.inf), np.maximum(ta, tb))
    return t0.max(axis=1), t1.min(axis=1)


def _local(origin, dirs, T_lab_from_obj):
    R, t = T_lab_from_obj[:3, :3], T_lab_from_obj[:3, 3]
    d = dirs @ R
    return np.broadcast_to((origin - t) @ R, d.shape), d


def _box_chords(origin, dirs, T, half):
    o, d = _local(origin, dirs, T)
    t0, t1 = _slab_interval(o, d, -half, half)
    return np.maximum(t1 - np.maximum(t0, 0.0), 0.0)


def _cylinder_chords(origin, dirs, T, radius, half_length):
    """Chords through finite cylinders; ``T`` (N, 4, 4), ``radius``/``half_length`` (N,) per ray."""
    R, t = T[:, :3, :3], T[:, :3, 3]
    o = np.einsum("nji,nj->ni", R, origin - t)
    d = np.einsum("nji,nj->ni", R, dirs)
    a = d[:, 0] ** 2 + d[:, 1] ** 2
    b = o[:, 0] * d[:, 0] + o[:, 1] * d[:, 1]
    c = o[:, 0] ** 2 + o[:, 1] ** 2 - radius * radius
    disc = b * b - a * c
    par = a < 1e-15
    with np.errstate(divide="ignore", invalid="ignore"):
        sq = np.sqrt(np.maximum(disc, 0.0))
        r0, r1 = (-b - sq) / a, (-b + sq) / a
    r0 = np.where(par, np.where(c <= 0, -np.inf, np.inf), np.where(disc > 0, r0, np.inf))
    r1 = np.where(par, np.where(c <= 0, np.inf, -np.inf), np.where(disc > 0, r1, -np.inf))
    hl = half_length[:, None]
    z0, z1 = _slab_interval(o[:, 2:], d[:, 2:], -hl, hl)
    lo = np.maximum(np.maximum(r0, z0), 0.0)
    return np.maximum(np.minimum(r1, z1) - lo, 0.0)


# ---------------------------------------------------------------------------- rendering
def _roi(camera: Camera, roi) -> tuple[int, int, int, int]:
    if roi is None:
        return 0, 0, camera.width, camera.height
    r = tuple(int(x) for x in roi)
    if len(r) != 4 or r[2] < 0 or r[3] < 0:
        raise ValueError(f"roi: expected (u0, v0, w, h) with w, h >= 0, got {roi!r}")
    return r


def _splat(camera, corners, chord: Callable, mu, roi, supersample: int, *, average: str = "line",
           base: Callable | None = None, chunk_rays: int = 2_000_000):
    """Render N local objects: ``corners (N, 8, 3)`` bound each; ``chord(idx, o, d)`` -> mm.

    ``average="line"`` box-filters the line integral over each pixel; ``"fluence"`` box-filters
    the transmitted fluence and returns the *effective* line integral ``-log(mean(exp(-L)))``
    minus the pixel mean of ``base(dirs)`` (a smooth background integral such as a plate the
    objects are embedded in), so that adding it back gives the right pixel fluence.
    """
    if average not in ("line", "fluence"):
        raise ValueError(f"average: expected 'line' or 'fluence', got {average!r}")
    u0, v0, w, h = _roi(camera, roi)
    out = np.zeros((h, w))
    s = int(supersample)
    if s < 1:
        raise ValueError(f"supersample: expected an integer >= 1, got {supersample!r}")
    if len(corners) == 0 or w == 0 or h == 0:
        return out.astype(np.float32)
    uv, z = camera.project(corners, return_depth=True)
    front = np.all(z > 0, axis=1)
    lo = np.floor(uv.min(axis=1)).astype(np.int64) - 1
    hi = np.ceil(uv.max(axis=1)).astype(np.int64) + 2
    lo = np.maximum(lo, [u0, v0])
    hi = np.minimum(hi, [u0 + w, v0 + h])
    keep = np.nonzero(front & np.all(hi > lo, axis=1))[0]
    off = (np.arange(s) + 0.5) / s - 0.5
    ou, ov = np.meshgrid(off, off)
    sub = np.stack([ou.ravel(), ov.ravel()], axis=1)  # (s², 2)
    src = camera.source
    # group objects so that each chunk holds at most ~chunk_rays sub-rays
    sizes = np.prod(hi[keep] - lo[keep], axis=1) * s * s
    start = 0
    while start < len(keep):
        stop = start + max(1, int(np.searchsorted(np.cumsum(sizes[start:]), chunk_rays)))
        idx = keep[start:stop]
        bw, bh = (hi[idx, 0] - lo[idx, 0]), (hi[idx, 1] - lo[idx, 1])
        npx = bw * bh
        obj = np.repeat(np.arange(len(idx)), npx)
        first = np.repeat(np.cumsum(npx) - npx, npx)
        local = np.arange(len(obj)) - first
        pu = lo[idx, 0][obj] + local % bw[obj]
        pv = lo[idx, 1][obj] + local // bw[obj]
        uvs = (np.stack([pu, pv], axis=1)[:, None, :] + sub[None]).reshape(-1, 2)
        _, dirs = camera.rays(uvs)
        k = np.repeat(idx[obj], s * s)
        L = (chord(k, src, dirs) * mu[k]).reshape(-1, s * s)
        if average == "line":
            val = L.mean(axis=1)
        else:
            b = np.zeros_like(L) if base is None else base(dirs).reshape(-1, s * s)
            val = -np.log(np.mean(np.exp(-(L + b)), axis=1)) - b.mean(axis=1)
        np.add.at(out, (pv - v0, pu - u0), val)
        start = stop
    return out.astype(np.float32)


def _mu_array(mu, n: int, name: str = "mu", *, signed: bool = False) -> np.ndarray:
    m = np.broadcast_to(as_float_array(mu, name), (n,)).astype(float)
    if not signed and np.any(m < 0):
        raise ValueError(f"{name}: expected attenuation coefficients >= 0 (1/mm)")
    return m


def bead_line_integrals(camera: Camera, centers, diameters, mu, *, roi=None, supersample: int = 4,
                        average: str = "line", _base=None):
    """Anti-aliased image of ``∫ μ dl`` through spherical beads (exact chords, no voxels).

    Parameters
    ----------
    camera : Camera
    centers : (N, 3) array
        Bead centres in the lab, mm.
    diameters : (N,) array or float
        Bead diameters, mm.
    mu : float or (N,) array
        Linear attenuation of the bead material, 1/mm (e.g. ``attenuation_per_mm("steel")``).
    roi : (u0, v0, w, h), optional
        Pixel box to render (full-resolution pixels; default the whole image). Pixel ``[r, c]``
        of the result is centred at ``(u, v) = (u0 + c, v0 + r)``.
    supersample : int
        Rays per pixel along each axis (4 → 16 rays per pixel, box-filtered).
    average : {"line", "fluence"}
        Box-filter the line integral (the DRR-style ground truth) or the transmitted fluence
        (returns ``-log`` of the pixel-mean transmission: what a detector pixel integrates, and
        what to feed :class:`~core.synthetic.imaging.ImagingModel` for opaque beads whose edges
        fall inside pixels).

    Returns
    -------
    (h, w) float32 array
        Line integrals (unitless); overlapping beads add.
    """
    C, _ = as_points(centers, "centers", 3)
    n = len(C)
    D = np.broadcast_to(as_float_array(diameters, "diameters"), (n,)).astype(float)
    if np.any(D <= 0):
        raise ValueError("diameters: expected positive bead diameters in mm")
    r = D / 2
    cube = np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)], dtype=float)
    corners = C[:, None, :] + r[:, None, None] * cube[None]
    return _splat(camera, corners, lambda k, o, d: sphere_chords(o, d, C[k], r[k]),
                  _mu_array(mu, n, signed=average == "fluence"), roi, supersample, average=average,
                  base=_base)


def box_line_integrals(camera: Camera, T_lab_from_box, half_extents, mu, *, roi=None,
                       supersample: int = 2):
    """Line integrals through a homogeneous box (half-extents mm, pose 4x4, μ 1/mm)."""
    T = check_rigid(T_lab_from_box, "T_lab_from_box")
    h = as_float_array(half_extents, "half_extents", shape=(3,))
    cube = np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)], dtype=float)
    corners = ((cube * h) @ T[:3, :3].T + T[:3, 3])[None]
    return _splat(camera, corners, lambda k, o, d: _box_chords(o, d, T, h),
                  _mu_array(mu, 1), roi, supersample)


def cylinder_line_integrals(camera: Camera, T_lab_from_cyl, radius, half_length, mu, *,
                            roi=None, supersample: int = 2, average: str = "line", _base=None):
    """Line integrals through homogeneous finite cylinders along their local z-axis.

    ``T_lab_from_cyl`` is (4, 4) or (N, 4, 4); ``radius``, ``half_length`` (mm) and ``mu``
    (1/mm) broadcast to (N,). A negative ``mu`` *removes* material: drilled holes in a plate or
    the bore of a tube, added to the plate's or tube's own integral. ``average`` as for
    :func:`bead_line_integrals`.
    """
    T = as_float_array(T_lab_from_cyl, "T_lab_from_cyl")
    T = T[None] if T.ndim == 2 else T
    for i in range(len(T)):
        check_rigid(T[i], f"T_lab_from_cyl[{i}]")
    n = len(T)
    r = np.broadcast_to(as_float_array(radius, "radius"), (n,)).astype(float)
    hl = np.broadcast_to(as_float_array(half_length, "half_length"), (n,)).astype(float)
    cube = np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)], dtype=float)
    loc = cube[None] * np.stack([r, r, hl], axis=1)[:, None, :]
    corners = np.einsum("nij,nkj->nki", T[:, :3, :3], loc) + T[:, None, :3, 3]

    return _splat(camera, corners, lambda k, o, d: _cylinder_chords(o, d, T[k], r[k], hl[k]),
                  _mu_array(mu, n, signed=True), roi, supersample, average=average, base=_base)


def slab_chords(origin, dirs, point, normal, thickness: float) -> np.ndarray:
    """Chords (mm) of rays ``origin + t·dirs`` (t > 0) through ``|(x - point)·n| <= thickness/2``."""
    nrm = np.asarray(normal, dtype=float)
    nrm = nrm / np.linalg.norm(nrm)
    cos = dirs @ nrm
    s0 = (np.asarray(point, dtype=float) - origin) @ nrm
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = (s0 - thickness / 2) / cos, (s0 + thickness / 2) / cos
    L = np.maximum(np.maximum(ta, tb) - np.maximum(np.minimum(ta, tb), 0.0), 0.0)
    return np.where(np.abs(cos) < 1e-12, 0.0, L)


def slab_line_integrals(camera: Camera, point, normal, thickness: float, mu: float, *, roi=None):
    """Line integrals through an infinite plate (walkway floor, grid plate) of ``thickness`` mm.

    The plate is ``|(x - point)·n| <= thickness / 2``; a ray crossing it in front of the source
    gets ``μ · thickness / |cos θ|`` (θ between ray and normal).
    """
    p = as_float_array(point, "point", shape=(3,))
    nrm = as_float_array(normal, "normal", shape=(3,))
    t = positive(thickness, "thickness")
    u0, v0, w, h = _roi(camera, roi)
    v, u = np.mgrid[v0 : v0 + h, u0 : u0 + w].astype(float)
    src, d = camera.rays(np.stack([u, v], axis=-1))
    return (float(mu) * slab_chords(src, d, p, nrm, t)).astype(np.float32)
