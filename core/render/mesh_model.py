"""Bone and implant models from surface meshes: a voxeliser that accepts real, slightly open meshes.

:func:`inside_mask` decides for every voxel centre of a grid whether it lies inside a triangle
surface by **ray parity voted over three axes**: along each grid axis, rays through the voxel
centres cross the surface; a centre with an odd number of crossings below it is inside for that
axis, and a centre inside for at least two of the three axes is inside. A hole in a real mesh
(segmentation STLs and implant files often have a few unshared edges) only spoils the rays that
pass through it, and those are outvoted by the two other axes; a closed mesh gives the exact
parity answer. Rays are shifted by an irrational fraction of a voxel so that none runs exactly
through a vertex or an edge. Orientation and winding of the triangles do not matter.

:func:`mesh_model` turns a mesh into a :class:`~core.render.volume.CTVolume` for the DRR
renderer: either uniform (``value`` inside: bone HU, or a metal's linear attenuation in 1/mm
with ``units="1/mm"``) or a cortical shell (``shell_mm`` thick, ``shell_value``) around a
cancellous interior (``value``).
"""

from __future__ import annotations

import numpy as np

from .volume import CTVolume

__all__ = ["boundary_edges", "inside_mask", "mesh_model"]

_JITTER = (0.5 ** 0.5 - 0.7) * 1e-3 + 1e-4 * (5 ** 0.5 - 2)  # ≈ 1.3e-5 voxel, irrational


def boundary_edges(faces) -> int:
    """Number of edges not shared by exactly two faces (0 for a closed manifold mesh)."""
    F = np.asarray(faces, dtype=np.int64)
    e = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    return int(np.sum(counts != 2))


def _parity_along(tri: np.ndarray, axis: int, origin, spacing, shape_ijk) -> np.ndarray:
    """Crossing parity ``[k, j, i]`` of the rays along grid ``axis`` through the voxel centres."""
    a, b = [d for d in range(3) if d != axis]  # the two axes spanning a ray's position
    na, nb, nc = shape_ijk[a], shape_ijk[b], shape_ijk[axis]
    # triangle vertices in continuous voxel coordinates; rays at integer (a, b) + jitter
    g = (tri - origin) / spacing
    ja, jb = _JITTER, _JITTER * 1.6180339887
    A, B, C = g[..., a] - ja, g[..., b] - jb, g[..., axis]
    lo_a = np.clip(np.ceil(A.min(1)), 0, na).astype(np.int64)
    hi_a = np.clip(np.floor(A.max(1)), -1, na - 1).astype(np.int64)
    lo_b = np.clip(np.ceil(B.min(1)), 0, nb).astype(np.int64)
    hi_b = np.clip(np.floor(B.max(1)), -1, nb - 1).astype(np.int64)
    wa, wb = hi_a - lo_a + 1, hi_b - lo_b + 1
    keep = (wa > 0) & (wb > 0)
    counts = np.zeros((na, nb, nc + 1), dtype=np.int32)
    idx = np.flatnonzero(keep)
    # process in chunks of (triangle, column) pairs to bound memory
    cells = (wa[idx] * wb[idx]).astype(np.int64)
    start = 0
    while start < len(idx):
        stop = start + max(1, int(np.searchsorted(np.cumsum(cells[start:]), 4_000_000)) + 1)
        t = idx[start:stop]
        n = (wa[t] * wb[t]).astype(np.int64)
        tt = np.repeat(t, n)
        off = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
        pa = lo_a[tt] + off // wb[tt]
        pb = lo_b[tt] + off % wb[tt]
        # barycentric coordinates of (pa, pb) in the projected triangle
        x0, y0 = A[tt, 0], B[tt, 0]
        x1, y1 = A[tt, 1] - x0, B[tt, 1] - y0
        x2, y2 = A[tt, 2] - x0, B[tt, 2] - y0
        px, py = pa - x0, pb - y0
        det = x1 * y2 - x2 * y1
        ok = det != 0
        safe = np.where(ok, det, 1.0)
        u = np.where(ok, (px * y2 - x2 * py) / safe, -1.0)
        v = np.where(ok, (x1 * py - px * y1) / safe, -1.0)
        hit = (u >= 0) & (v >= 0) & (u + v <= 1)
        c = C[tt, 0] + u * (C[tt, 1] - C[tt, 0]) + v * (C[tt, 2] - C[tt, 0])
        # a crossing at c lies below the voxel centres ceil(c), ceil(c)+1, ...
        first = np.clip(np.ceil(c[hit]), 0, nc).astype(np.int64)
        np.add.at(counts, (pa[hit], pb[hit], first), 1)
        start = stop
    par = (np.cumsum(counts, axis=2)[..., :nc] & 1).astype(bool)  # [a, b, axis]
    # back to [k, j, i] = axes (2, 1, 0)
    order = {a: 0, b: 1, axis: 2}
    return np.transpose(par, (order[2], order[1], order[0]))


def inside_mask(vertices, faces, origin, spacing, shape_ijk) -> np.ndarray:
    """Boolean ``[k, j, i]`` mask of the voxel centres ``origin + spacing * (i, j, k)`` inside the
    surface (axis-aligned grid; see the module docs for the voted ray parity)."""
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    if V.ndim != 2 or V.shape[1] != 3 or F.ndim != 2 or F.shape[1] != 3 or not len(F):
        raise ValueError(f"vertices, faces: expected (N, 3) and non-empty (M, 3), got {V.shape}, {F.shape}")
    sp = np.broadcast_to(np.asarray(spacing, dtype=float), (3,))
    if not np.all(sp > 0):
        raise ValueError(f"spacing: expected positive voxel sizes, got {spacing!r}")
    shape = tuple(int(n) for n in shape_ijk)
    tri = V[F]
    o = np.asarray(origin, float)
    votes = sum(_parity_along(tri, ax, o, sp, shape).astype(np.int8) for ax in range(3))
    return votes >= 2


def mesh_model(
    mesh,
    *,
    spacing: float = 0.5,
    margin_mm: float = 2.0,
    value: float = 1200.0,
    units: str = "HU",
    shell_mm: float | None = None,
    shell_value: float | None = None,
    background: float | None = None,
    name: str | None = None,
    max_voxels: int = 200_000_000,
) -> CTVolume:
    """A model volume of ``mesh`` (:class:`core.io.meshes.Mesh`, mm) for DRR rendering.

    Parameters
    ----------
    spacing : float
        Isotropic voxel size, mm.
    margin_mm : float
        Background kept around the mesh's bounding box.
    value : float
        Inside value: HU (bone, e.g. 1200) or, with ``units="1/mm"``, a linear attenuation
        (a metal implant: e.g. about 2 /mm for titanium, 6 /mm for cobalt-chromium at 60 keV).
    shell_mm, shell_value : float, optional
        A cortical shell: voxels inside and within ``shell_mm`` of the outside get
        ``shell_value``, deeper ones ``value``.
    background : float, optional
        Outside value; default -1000 HU (air) or 0 /mm.

    The volume's physical frame is the mesh's (identity direction, ``origin`` = the first voxel
    centre), so a pose of the mesh is a pose of the volume.
    """
    if units not in ("HU", "1/mm"):
        raise ValueError(f"units: expected 'HU' or '1/mm', got {units!r}")
    if not spacing > 0 or not margin_mm >= 0:
        raise ValueError(f"spacing, margin_mm: expected > 0 and >= 0, got {spacing}, {margin_mm}")
    if (shell_mm is None) != (shell_value is None):
        raise ValueError("shell_mm, shell_value: give both or neither")
    if shell_mm is not None and not shell_mm > 0:
        raise ValueError(f"shell_mm: expected > 0, got {shell_mm}")
    V = np.asarray(mesh.vertices, dtype=float)
    lo, hi = V.min(0) - margin_mm, V.max(0) + margin_mm
    shape = tuple(int(n) for n in np.ceil((hi - lo) / spacing).astype(int) + 1)
    if int(np.prod(shape)) > max_voxels:
        raise ValueError(f"spacing: {spacing} mm gives {shape} voxels (> {max_voxels}); use a coarser one")
    inside = inside_mask(V, mesh.faces, lo, spacing, shape)
    bg = (-1000.0 if units == "HU" else 0.0) if background is None else float(background)
    data = np.full(inside.shape, bg, dtype=np.float32)
    data[inside] = value
    if shell_mm is not None:
        from scipy.ndimage import distance_transform_edt

        depth = distance_transform_edt(inside, sampling=spacing)
        data[inside & (depth - 0.5 * spacing <= shell_mm)] = shell_value  # centre-to-surface depth
    return CTVolume(data, (spacing,) * 3, lo, units=units, name=name if name is not None else mesh.name)
