"""Voxelise a closed triangle surface mesh into a bone volume in HU.

Method
------
1. **Inside/outside by ray parity.** For every row of voxel centres parallel to the x-axis, the
   crossings of that row's line with the mesh are found by rasterising each triangle's (y, z)
   footprint onto the grid (edge functions, vectorised over all triangle × row pairs) and
   interpolating the crossing's x; a voxel is inside when an odd number of crossings lie to its
   left. The rows are shifted by ~1e-6 voxel in y and z (never seen by the caller) so that no row
   passes exactly through a mesh edge or vertex, where a crossing would be counted twice.
2. **Distance to the surface.** A Euclidean distance transform of the inside mask gives every
   voxel's distance to ±1 voxel; in the band that matters (``cortex_mm`` + 2 voxels either side
   of the surface) it is replaced by the exact point–triangle distance (Ericson, *Real-Time
   Collision Detection* §5.1.5) to candidate triangles from a k-d tree of triangle centroids.
3. **HU** from the signed distance with :func:`core.synthetic.phantoms.hu_from_sdf` (cortical
   shell of ``cortex_mm``, trabecular interior with optional seeded texture, soft tissue outside,
   partial-volume edges), as for the analytic phantoms.

The mesh must be closed (every edge shared by exactly two faces); orientation does not matter.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import distance_transform_edt
from scipy.spatial import cKDTree

from .._validate import as_float_array, positive
from ..geometry.triangles import closest_point_on_triangles
from ..render.volume import CTVolume
from .phantoms import SOFT_HU, _texture, hu_from_sdf, voxel_grid

__all__ = [
    "box_mesh",
    "icosphere",
    "mesh_inside_grid",
    "mesh_volume",
    "point_triangle_distance",
    "voxelize_mesh",
]


def _check_mesh(vertices, faces) -> tuple[np.ndarray, np.ndarray]:
    V = as_float_array(vertices, "vertices", shape=(None, 3))
    F = np.asarray(faces)
    if F.ndim != 2 or F.shape[1] != 3 or not np.issubdtype(F.dtype, np.integer):
        raise ValueError(f"faces: expected an integer array of shape (M, 3), got {F.dtype} {F.shape}")
    if F.size == 0 or F.min() < 0 or F.max() >= len(V):
        raise ValueError(f"faces: vertex indices must lie in [0, {len(V)}), got range "
                         f"{F.min() if F.size else None}..{F.max() if F.size else None}")
    e = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    if np.any(counts != 2):
        raise ValueError(
            f"faces: the mesh is not closed ({int(np.sum(counts != 2))} edges are not shared by "
            "exactly two faces); inside/outside is undefined"
        )
    return V, F.astype(np.int64)


def mesh_volume(vertices, faces) -> float:
    """Enclosed volume (mm³) of a closed mesh by the divergence theorem (orientation-free)."""
    V, F = _check_mesh(vertices, faces)
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return float(abs(np.einsum("ij,ij->i", a, np.cross(b, c)).sum()) / 6.0)


def mesh_inside_grid(vertices, faces, origin, spacing: float, shape_ijk, *,
                     max_pairs: int = 4_000_000) -> np.ndarray:
    """Boolean ``[k, j, i]`` mask of grid voxel centres inside the closed mesh (ray parity).

    The grid has voxel ``(i, j, k)`` centred at ``origin + spacing * (i, j, k)`` (mm).
    """
    V, F = _check_mesh(vertices, faces)
    s = positive(spacing, "spacing")
    o = as_float_array(origin, "origin", shape=(3,))
    nx, ny, nz = (int(n) for n in shape_ijk)
    # grid units; rows shifted off any exact edge/vertex hit
    G = (V - o) / s
    G[:, 1] -= 1.1e-6 * np.sqrt(2.0)
    G[:, 2] -= 1.3e-6 * np.sqrt(3.0)
    hist = np.zeros((nz, ny, nx + 1), dtype=np.int32)
    T = G[F]  # (M, 3 vertices, xyz)
    lo = np.ceil(T[:, :, 1:].min(axis=1)).astype(np.int64)
    hi = np.floor(T[:, :, 1:].max(axis=1)).astype(np.int64)
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, [ny - 1, nz - 1])
    cnt = np.where(np.all(hi >= lo, axis=1), np.prod(hi - lo + 1, axis=1), 0)
    order = np.cumsum(cnt)
    start = 0
    while start < len(F):
        # triangles [start, stop) with at most ~max_pairs (triangle, row) pairs
        base = order[start - 1] if start else 0
        stop = max(int(np.searchsorted(order, base + max_pairs, side="right")), start + 1)
        t = np.repeat(np.arange(start, stop), cnt[start:stop])
        if t.size:
            first = np.repeat(order[start:stop] - cnt[start:stop], cnt[start:stop])
            local = np.arange(t.size) + base - first
            wj = hi[t, 0] - lo[t, 0] + 1
            j = lo[t, 0] + local % wj
            k = lo[t, 1] + local // wj
            a, b, c = T[t, 0], T[t, 1], T[t, 2]

            def edge(p, q, yy, zz):
                return (q[:, 1] - p[:, 1]) * (zz - p[:, 2]) - (q[:, 2] - p[:, 2]) * (yy - p[:, 1])

            w0, w1, w2 = edge(b, c, j, k), edge(c, a, j, k), edge(a, b, j, k)
            area = w0 + w1 + w2
            hit = (((w0 >= 0) & (w1 >= 0) & (w2 >= 0)) | ((w0 <= 0) & (w1 <= 0) & (w2 <= 0)))
            hit &= area != 0
            with np.errstate(divide="ignore", invalid="ignore"):
                x = (w0 * a[:, 0] + w1 * b[:, 0] + w2 * c[:, 0]) / area
            i0 = np.clip(np.ceil(x[hit]), 0, nx).astype(np.int64)
            np.add.at(hist, (k[hit], j[hit], i0), 1)
        start = stop
    return (np.cumsum(hist, axis=2)[:, :, :nx] % 2).astype(bool)


def point_triangle_distance(p, a, b, c) -> np.ndarray:
    """Euclidean distance (mm) from points ``p`` to triangles ``(a, b, c)``; all (N, 3) row-wise."""
    return np.linalg.norm(p - closest_point_on_triangles(p, a, b, c), axis=1)


def _exact_distance(points: np.ndarray, V: np.ndarray, F: np.ndarray, chunk: int = 20000):
    tri = V[F]
    cen = tri.mean(axis=1)
    rad = np.linalg.norm(tri - cen[:, None], axis=2).max(axis=1)
    tree_c = cKDTree(cen)
    samples = np.concatenate([V, cen])
    d_up, _ = cKDTree(samples).query(points)
    out = np.empty(len(points))
    for s in range(0, len(points), chunk):
        q, du = points[s : s + chunk], d_up[s : s + chunk]
        lists = tree_c.query_ball_point(q, du + rad.max() + 1e-9)
        n = np.fromiter((len(x) for x in lists), dtype=np.int64, count=len(lists))
        cand = np.concatenate([np.asarray(x, dtype=np.int64) for x in lists])
        qi = np.repeat(np.arange(len(q)), n)
        d = point_triangle_distance(q[qi], tri[cand, 0], tri[cand, 1], tri[cand, 2])
        best = np.full(len(q), np.inf)
        np.minimum.at(best, qi, d)
        out[s : s + chunk] = best
    return out


def voxelize_mesh(
    vertices,
    faces,
    *,
    spacing: float = 0.5,
    margin_mm: float = 3.0,
    cortex_mm: float = 1.0,
    cortical_hu: float = 1500.0,
    trabecular_hu: float = 300.0,
    texture_hu: float = 0.0,
    background_hu: float = SOFT_HU,
    seed: int = 0,
    name: str = "",
    dtype=np.int16,
) -> CTVolume:
    """Voxelise a closed triangle mesh (vertices mm, faces indices) into a bone :class:`CTVolume`.

    Parameters
    ----------
    vertices : (N, 3) array
        Vertex positions in the bone's physical frame, mm.
    faces : (M, 3) int array
        Triangles; the mesh must be closed.
    spacing : float
        Isotropic voxel size, mm.
    margin_mm : float
        Soft tissue kept around the mesh's bounding box, mm.
    cortex_mm : float
        Cortical shell thickness measured inwards from the surface, mm.
    cortical_hu, trabecular_hu, background_hu : float
        Tissue values, HU (see :mod:`core.synthetic.phantoms`).
    texture_hu : float
        Amplitude (1 σ) of seeded trabecular texture, HU (0 = uniform interior).
    seed : int
        Seed of the texture.
    name : str
    dtype : numpy dtype
        ``np.int16`` (rounded) or ``np.float32``.

    Returns
    -------
    CTVolume
        HU; voxel (0, 0, 0) is centred at the returned ``origin``.
    """
    V, F = _check_mesh(vertices, faces)
    s = positive(spacing, "spacing")
    cortex = positive(cortex_mm, "cortex_mm")
    lo, hi = V.min(axis=0) - margin_mm, V.max(axis=0) + margin_mm
    origin, pts, n_ijk = voxel_grid(lo, hi, s)
    inside = mesh_inside_grid(V, F, origin, s, n_ijk)
    approx = np.where(inside, -(distance_transform_edt(inside) - 0.5) * s,
                      (distance_transform_edt(~inside) - 0.5) * s)
    band = np.abs(approx) <= cortex + 2.0 * s
    d = approx.copy()
    exact = _exact_distance(pts[band], V, F)
    d[band] = np.where(inside[band], -exact, exact)
    trab = trabecular_hu
    if texture_hu:
        trab = trabecular_hu + texture_hu * _texture(inside.shape, s, np.random.default_rng(seed))
    hu = hu_from_sdf(d, voxel_mm=s, cortex_mm=cortex, cortical_hu=cortical_hu,
                     trabecular_hu=trab, background_hu=background_hu)
    data = np.rint(hu).astype(dtype) if np.issubdtype(np.dtype(dtype), np.integer) else hu.astype(dtype)
    return CTVolume(data, spacing=np.full(3, s), origin=origin, units="HU", name=name)


def icosphere(radius: float = 1.0, subdivisions: int = 2, center=(0.0, 0.0, 0.0)):
    """Closed triangulated sphere: ``(vertices (N, 3), faces (M, 3))``, 20·4^subdivisions faces."""
    t = (1 + 5**0.5) / 2
    V = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t),
         (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    F = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
         (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9),
         (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    verts = [np.array(v, dtype=float) / np.linalg.norm(v) for v in V]
    faces = F

    def midpoint(i, j, cache):
        key = (min(i, j), max(i, j))
        if key not in cache:
            m = verts[i] + verts[j]
            verts.append(m / np.linalg.norm(m))
            cache[key] = len(verts) - 1
        return cache[key]

    for _ in range(int(subdivisions)):
        mid: dict[tuple[int, int], int] = {}
        new = []
        for a, b, c in faces:
            ab, bc, ca = midpoint(a, b, mid), midpoint(b, c, mid), midpoint(c, a, mid)
            new += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new
    return np.array(verts) * radius + np.asarray(center, dtype=float), np.array(faces, dtype=np.int64)


def box_mesh(half_extents, center=(0.0, 0.0, 0.0)):
    """Closed 12-triangle box with ``half_extents`` (3,) mm: ``(vertices (8, 3), faces (12, 3))``."""
    h = as_float_array(half_extents, "half_extents", shape=(3,))
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    F = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1),
         (2, 3, 7), (2, 7, 6), (0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3)]
    return corners * h + np.asarray(center, dtype=float), np.array(F, dtype=np.int64)
