"""Lattice indexing of detected grid points: each point gets its grid cell ``(i, j)`` (thesis §3.5.2).

Algorithm (region growing with local affine prediction)
-------------------------------------------------------
1. The pitch ``p`` is the median nearest-neighbour distance; the lattice direction is the
   median of the neighbour-vector angles folded modulo 90° around the seed (the point nearest
   ``origin_uv``, default the centroid of the points, where an intensifier distorts least).
   ``i`` runs along the lattice direction closest to +u, ``j`` along the one closest to +v.
2. Growing, breadth-first: every empty cell next to the indexed set is predicted by a weighted
   affine fit ``(i, j) → (u, v)`` of the indexed cells within ``fit_radius`` cells (weights fall
   with cell distance). The nearest unassigned detection within ``tolerance × p`` of the
   prediction is assigned (conflicts go to the closest). Because each prediction only uses
   nearby cells, the slowly turning lattice of a pincushion / S-distorted image is followed.
3. Missing points (a hole lost in noise, a cut edge) are bridged: when one ring adds nothing,
   cells two steps away are tried before giving up.
4. Check: each indexed point is predicted from its neighbours with itself left out; the worst
   point further than ``check_tolerance × p`` (default 0.15; real holes under strong
   distortion stay below ~0.07) is dropped as mis-assigned (a speckle near an empty cell, a
   feature cut by the round field edge), and the check repeats.

Cost
----
Indexed cells live in a dense ``(i, j)`` table, so a cell's neighbours are table look-ups, and
each ring of candidate cells is predicted in one batch of 3×3 weighted normal equations and
matched with one k-d tree query. A grid of ``n`` points takes O(√n) rings of O(√n) cells, O(n)
work in all; the check recomputes only the ``(2 fit_radius + 1)²`` predictions around a dropped
point (``core.studies.imaging.grid_benchmark`` times it on 250 to 20,000 points).

Result
------
Indices are exact up to the choice of cell (0, 0) (a translation of every ``(i, j)``): the
seed is the well-surrounded point nearest ``origin_uv``, and the axes are fixed by the image
(``i`` ≈ +u, ``j`` ≈ +v), so there is no flip or swap unless the grid is turned by ~45°.
Detections never assigned are listed in :attr:`GridIndex.unassigned`.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree

from .._validate import as_float_array, as_points, positive

__all__ = ["GridIndex", "index_grid"]

_RING1 = [(di, dj) for di in (-1, 0, 1) for dj in (-1, 0, 1) if (di, dj) != (0, 0)]


@dataclass(frozen=True, eq=False)
class GridIndex:
    """Indexed grid points.

    Attributes
    ----------
    uv : (m, 2) float64
        Positions of the indexed points, pixels.
    ij : (m, 2) int
        Lattice cell of each point; ``(0, 0)`` is the seed point nearest the origin.
    point_index : (m,) int
        Row of each indexed point in the detected array passed to :func:`index_grid`.
    unassigned : (k,) int
        Rows of detected points that fit no lattice cell.
    pitch_px : float
        Median nearest-neighbour distance of the detections, pixels.
    basis : (2, 2) float64
        Lattice steps at the seed: rows are the ``i`` and ``j`` step vectors, pixels.
    """

    uv: np.ndarray
    ij: np.ndarray
    point_index: np.ndarray
    unassigned: np.ndarray
    pitch_px: float
    basis: np.ndarray

    def __len__(self) -> int:
        return len(self.uv)


def _lattice_basis(pts: np.ndarray, seed: int, tree: cKDTree, pitch: float) -> np.ndarray:
    """i and j step vectors near the seed (median neighbour angle modulo 90°)."""
    d, nb = tree.query(pts[seed], min(len(pts), 60))
    local = nb[d < 4 * pitch]
    angles = []
    for k in local:
        dk, nk = tree.query(pts[k], min(5, len(pts)))
        for dd, q in zip(dk[1:], nk[1:], strict=True):
            if 0.7 * pitch < dd < 1.3 * pitch:
                v = pts[q] - pts[k]
                angles.append(np.arctan2(v[1], v[0]))
    if len(angles) < 4:
        raise ValueError(f"points: fewer than 4 neighbour pairs at the grid pitch ({pitch:.1f} px) near "
                         f"the seed; the points do not form a square lattice")
    a = np.asarray(angles)
    # fold modulo 90° with a circular mean of 4·angle
    theta = np.angle(np.mean(np.exp(4j * a))) / 4
    e1 = np.array([np.cos(theta), np.sin(theta)])
    e2 = np.array([-np.sin(theta), np.cos(theta)])
    cands = [e1, e2, -e1, -e2]
    ei = max(cands, key=lambda e: e[0])  # closest to +u
    ej = np.array([-ei[1], ei[0]])       # +90° in (u, v) with v down: closest to +v
    # local pitch along each direction
    return np.stack([ei, ej]) * pitch


def _seed(pts: np.ndarray, tree: cKDTree, origin: np.ndarray, pitch: float) -> int:
    """Of the 9 points nearest ``origin``, the one with the most neighbours at about one pitch."""
    _, near = tree.query(origin, min(9, len(pts)))
    best, score = int(near[0]), -1
    for k in np.atleast_1d(near):
        d = tree.query(pts[k], min(9, len(pts)))[0][1:]
        good = int(np.sum((d > 0.8 * pitch) & (d < 1.2 * pitch)))
        if good > score:
            best, score = int(k), good
    return best


class _Cells:
    """Dense cell table: ``table[i + off, j + off]`` is the row of the point in cell ``(i, j)``,
    -1 if none. Grows (re-centred) when indexed cells come near its edge."""

    def __init__(self, half: int) -> None:
        self.off = int(half)
        self.table = np.full((2 * self.off + 1, 2 * self.off + 1), -1, dtype=np.int64)

    def ensure(self, ij: np.ndarray, margin: int) -> None:
        if ij.size == 0:
            return
        need = int(np.abs(ij).max()) + margin
        if need > self.off:
            half = max(need, 2 * self.off)
            t = np.full((2 * half + 1, 2 * half + 1), -1, dtype=np.int64)
            s = half - self.off
            t[s : s + self.table.shape[0], s : s + self.table.shape[1]] = self.table
            self.table, self.off = t, half

    def get(self, ij: np.ndarray) -> np.ndarray:
        return self.table[ij[..., 0] + self.off, ij[..., 1] + self.off]

    def set(self, ij: np.ndarray, rows) -> None:
        self.table[ij[..., 0] + self.off, ij[..., 1] + self.off] = rows

    def filled(self) -> tuple[np.ndarray, np.ndarray]:
        """``(ij (m, 2), rows (m,))`` of the occupied cells."""
        a = np.argwhere(self.table >= 0)
        return a - self.off, self.table[a[:, 0], a[:, 1]]


def _predict(cells: np.ndarray, table: _Cells, pts: np.ndarray, radius: int):
    """Weighted affine predictions ``(i, j) → (u, v)`` at ``cells (m, 2)`` from the indexed cells
    within Chebyshev ``radius`` of each (the cell itself left out), all cells at once.

    Returns ``(uv (m, 2), ok (m,))``; ``ok`` is False where fewer than 3 neighbours are indexed
    or they lie on one line (no affine fit). Row weights fall with the cell distance ``d`` as
    ``exp(-d² / 2 (radius / 2)²)`` (``radius / 2`` at least 1).
    """
    r = int(radius)
    g = np.arange(-r, r + 1)
    di, dj = (a.ravel() for a in np.meshgrid(g, g, indexing="ij"))
    keep = (di != 0) | (dj != 0)
    di, dj = di[keep], dj[keep]
    d = np.maximum(np.abs(di), np.abs(dj))
    w2 = np.exp(-0.5 * (d / max(r / 2, 1.0)) ** 2) ** 2
    A = np.column_stack([di, dj, np.ones_like(di)]).astype(float)  # (K, 3)
    m = len(cells)
    out, ok = np.full((m, 2), np.nan), np.zeros(m, bool)
    if m == 0:
        return out, ok
    table.ensure(cells, r + 1)
    rows = table.get(cells[:, None, :] + np.stack([di, dj], axis=1)[None])  # (m, K)
    valid = rows >= 0
    # affine rank 3 of the unweighted design (integer Gram determinant) and at least 3 points
    G = np.einsum("mk,ka,kb->mab", valid.astype(float), A, A)
    good = (valid.sum(axis=1) >= 3) & (np.linalg.det(G) > 0.5)
    if not good.any():
        return out, ok
    W = valid[good] * w2
    uv = pts[np.where(valid[good], rows[good], 0)]
    M = np.einsum("mk,ka,kb->mab", W, A, A)
    R = np.einsum("mk,ka,mkc->mac", W, A, uv)
    sol = np.linalg.solve(M, R)
    out[good], ok[good] = sol[:, 2, :], True
    return out, ok


def _loo_residuals(ij: np.ndarray, table: _Cells, pts: np.ndarray, radius: int) -> np.ndarray:
    """Distance of each indexed point from its prediction by its neighbours (itself left out),
    pixels; ``inf`` where it cannot be predicted."""
    p, ok = _predict(ij, table, pts, radius)
    res = np.full(len(ij), np.inf)
    res[ok] = np.hypot(*(p[ok] - pts[table.get(ij[ok])]).T)
    return res


def _grow(table: _Cells, pts: np.ndarray, tree: cKDTree, owned: np.ndarray, pitch: float,
          tolerance: float, fit_radius: int) -> None:
    """Breadth-first growth of the indexed set (module docs, steps 2–3), one ring per pass."""
    ring = 1
    k_near = min(8, len(pts))
    while True:
        table.ensure(table.filled()[0], 2 * ring + fit_radius + 2)
        known = (table.table >= 0).astype(np.uint8)
        ring_mask = cv2.dilate(known, np.ones((2 * ring + 1, 2 * ring + 1), np.uint8)) > known
        cand = np.argwhere(ring_mask) - table.off
        pred, ok = _predict(cand, table, pts, fit_radius + (ring == 2))
        cand, pred = cand[ok], pred[ok]
        claims = 0
        if len(cand):
            d, k = tree.query(pred, k_near, distance_upper_bound=tolerance * pitch)
            d, k = d.reshape(len(cand), -1), k.reshape(len(cand), -1)
            free = np.isfinite(d)
            free[free] = ~owned[k[free]]
            has = free.any(axis=1)
            first = np.argmax(free, axis=1)
            sel = np.flatnonzero(has)
            dist, point = d[sel, first[sel]], k[sel, first[sel]]
            # a point claimed by several cells goes to the closest prediction
            order = np.argsort(dist, kind="stable")
            point, cells = point[order], cand[sel[order]]
            _, uniq = np.unique(point, return_index=True)
            point, cells = point[uniq], cells[uniq]
            table.set(cells, point)
            owned[point] = True
            claims = len(point)
        if claims:
            ring = 1
        elif ring == 1:
            ring = 2
        else:
            break


def _check(table: _Cells, pts: np.ndarray, ij: np.ndarray, radius: int, limit: float) -> None:
    """Module docs step 4: drop the worst point while it is further than ``limit`` pixels from
    its neighbours' prediction. Dropping a point changes only the predictions within ``radius``
    cells of it, so only those are recomputed (each drop costs O(radius²), not O(n))."""
    res = _loo_residuals(ij, table, pts, radius)
    res[~np.isfinite(res)] = 0.0  # isolated points cannot be checked locally
    pos = {(int(a), int(b)): k for k, (a, b) in enumerate(ij)}
    g = np.arange(-radius, radius + 1)
    ring = np.stack([a.ravel() for a in np.meshgrid(g, g, indexing="ij")], axis=1)
    alive = len(ij)
    while alive > 3:
        worst = int(np.argmax(res))
        if res[worst] <= limit:
            break
        table.set(ij[worst], -1)
        res[worst] = -np.inf
        alive -= 1
        near = ij[worst] + ring
        near = near[table.get(near) >= 0]
        if len(near):
            r = _loo_residuals(near, table, pts, radius)
            r[~np.isfinite(r)] = 0.0
            res[[pos[(int(a), int(b))] for a, b in near]] = r


def index_grid(points, *, origin_uv=None, tolerance: float = 0.3, fit_radius: int = 2,
               check_tolerance: float = 0.15, min_points: int = 9) -> GridIndex:
    """Assign lattice indices ``(i, j)`` to detected grid points.

    Parameters
    ----------
    points : (n, 2) array_like
        Detected centres ``(u, v)``, pixels (e.g. :attr:`GridPoints.uv`).
    origin_uv : (2,) array_like, optional
        Where to start (the point nearest it becomes cell (0, 0)); default the centroid.
    tolerance : float
        Largest distance from a predicted cell position to accept a point, in pitches (< 0.5).
    fit_radius : int
        Cell radius (Chebyshev) of the local affine predictions.
    check_tolerance : float
        Final check: a point further than this (in pitches) from the prediction of its
        neighbours, itself left out, is dropped (worst first); 0 = no check.
    min_points : int
        Fewer indexed points than this is an error.

    Raises
    ------
    ValueError
        Too few points, or no square lattice found (the message says how many were indexed).
    """
    pts, _ = as_points(points, "points", 2)
    if len(pts) < max(int(min_points), 5):
        raise ValueError(f"points: found {len(pts)} grid points, indexing needs at least "
                         f"{max(min_points, 5)}")
    if not 0 < tolerance < 0.5:
        raise ValueError(f"tolerance: expected a fraction of the pitch in (0, 0.5), got {tolerance}")
    if int(fit_radius) != fit_radius or fit_radius < 1:
        raise ValueError(f"fit_radius: expected an integer >= 1, got {fit_radius!r}")
    tree = cKDTree(pts)
    nn = tree.query(pts, 2)[0][:, 1]
    pitch = positive(float(np.median(nn)), "pitch (median nearest-neighbour distance)")
    origin = pts.mean(axis=0) if origin_uv is None else as_float_array(origin_uv, "origin_uv", shape=(2,))
    seed = _seed(pts, tree, origin, pitch)
    basis = _lattice_basis(pts, seed, tree, pitch)
    half = int(np.ceil(np.ptp(pts, axis=0).max() / pitch)) + 2 * int(fit_radius) + 4
    table = _Cells(half)
    owned = np.zeros(len(pts), bool)
    table.set(np.array([0, 0]), seed)
    owned[seed] = True
    # the seed's direct neighbours from the basis, to start the local fits
    for di, dj in _RING1:
        guess = pts[seed] + di * basis[0] + dj * basis[1]
        d, k = tree.query(guess)
        if d < tolerance * pitch and not owned[int(k)]:
            table.set(np.array([di, dj]), int(k))
            owned[int(k)] = True
    _grow(table, pts, tree, owned, pitch, float(tolerance), int(fit_radius))
    ij, idx = table.filled()
    if check_tolerance > 0 and len(idx) > 3:
        _check(table, pts, ij, int(fit_radius), check_tolerance * pitch)
        ij, idx = table.filled()
    if len(idx) < min_points:
        raise ValueError(f"points: only {len(idx)} of {len(pts)} points fit a square lattice "
                         f"(pitch {pitch:.1f} px); need at least {min_points}")
    order = np.lexsort((ij[:, 0], ij[:, 1]))
    idx, ij = idx[order], ij[order]
    unassigned = np.setdiff1d(np.arange(len(pts)), idx)
    return GridIndex(pts[idx].copy(), ij, idx, unassigned, pitch, basis)
