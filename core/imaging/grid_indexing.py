"""Lattice indexing of detected grid points: each point gets its grid cell ``(i, j)`` (thesis §3.5.2).

Algorithm (region growing with local affine prediction)
-------------------------------------------------------
1. The pitch ``p`` is the median nearest-neighbour distance; the lattice direction is the
   median of the neighbour-vector angles folded modulo 90° around the seed (the point nearest
   ``origin_uv``, default the centroid of the points, where an intensifier distorts least).
   ``i`` runs along the lattice direction closest to +u, ``j`` along the one closest to +v.
2. Growing: every empty cell next to the indexed set is predicted by a weighted affine fit
   ``(i, j) → (u, v)`` of the indexed cells within ``fit_radius`` cells (weights fall with cell
   distance). The nearest unassigned detection within ``tolerance × local pitch`` of the
   prediction is assigned (conflicts go to the closest). Because each prediction only uses
   nearby cells, the slowly turning lattice of a pincushion / S-distorted image is followed.
3. Missing points (a hole lost in noise, a cut edge) are bridged: when one ring adds nothing,
   cells two steps away are tried before giving up.
4. Check: each indexed point is predicted from its neighbours with itself left out; the worst
   point further than ``check_tolerance × p`` (default 0.15; real holes under strong
   distortion stay below ~0.07) is dropped as mis-assigned (a speckle near an empty cell, a
   feature cut by the round field edge), and the check repeats.

Detections never assigned are listed in :attr:`GridIndex.unassigned`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .._validate import as_float_array, as_points, positive

__all__ = ["GridIndex", "index_grid"]

_RING1 = [(di, dj) for di in (-1, 0, 1) for dj in (-1, 0, 1) if (di, dj) != (0, 0)]
_RING2 = [(di, dj) for di in range(-2, 3) for dj in range(-2, 3) if max(abs(di), abs(dj)) == 2]


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


def _predict(cell, known_ij: np.ndarray, known_uv: np.ndarray, radius: float) -> np.ndarray | None:
    d = np.max(np.abs(known_ij - cell), axis=1)
    sel = d <= radius
    if sel.sum() < 3:
        return None
    A = np.column_stack([known_ij[sel] - cell, np.ones(sel.sum())])
    w = np.exp(-0.5 * (d[sel] / max(radius / 2, 1.0)) ** 2)
    if np.linalg.matrix_rank(A[:, :2]) < 2:
        return None
    sol = np.linalg.lstsq(A * w[:, None], known_uv[sel] * w[:, None], rcond=None)[0]
    return sol[2]


def _loo_residuals(ij: np.ndarray, uv: np.ndarray, radius: int) -> np.ndarray:
    """Distance of each point from its prediction by its neighbours (itself left out), pixels."""
    out = np.full(len(ij), np.inf)
    for k in range(len(ij)):
        m = np.ones(len(ij), bool)
        m[k] = False
        p = _predict(ij[k], ij[m], uv[m], radius)
        if p is not None:
            out[k] = float(np.hypot(*(p - uv[k])))
    return out


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
    cell_of: dict[tuple[int, int], int] = {(0, 0): seed}
    owner = {seed: (0, 0)}
    # the seed's direct neighbours from the basis, to start the local fits
    for di, dj in _RING1:
        guess = pts[seed] + di * basis[0] + dj * basis[1]
        d, k = tree.query(guess)
        if d < tolerance * pitch and int(k) not in owner:
            cell_of[(di, dj)] = int(k)
            owner[int(k)] = (di, dj)
    ring = _RING1
    while True:
        known = np.array(list(cell_of.keys()))
        known_uv = pts[np.array(list(cell_of.values()))]
        cand = {(int(i + di), int(j + dj)) for i, j in known for di, dj in ring} - set(cell_of)
        claims: dict[int, tuple[float, tuple[int, int]]] = {}
        for cell in cand:
            p = _predict(np.array(cell), known, known_uv, fit_radius + (ring is _RING2))
            if p is None:
                continue
            near = tree.query_ball_point(p, tolerance * pitch)
            best = None
            for k in near:
                if k in owner:
                    continue
                dist = float(np.hypot(*(pts[k] - p)))
                if best is None or dist < best[0]:
                    best = (dist, k)
            if best is not None and (best[1] not in claims or best[0] < claims[best[1]][0]):
                claims[best[1]] = (best[0], cell)
        used = set()
        for k, (_, cell) in sorted(claims.items(), key=lambda kv: kv[1][0]):
            if cell in used:
                continue
            used.add(cell)
            cell_of[cell] = k
            owner[k] = cell
        if claims:
            ring = _RING1
        elif ring is _RING1:
            ring = _RING2
        else:
            break
    idx = np.array(list(cell_of.values()), dtype=int)
    ij = np.array(list(cell_of.keys()), dtype=int)
    if check_tolerance > 0:
        while len(idx) > 3:
            res = _loo_residuals(ij, pts[idx], int(fit_radius))
            res[~np.isfinite(res)] = 0.0  # isolated points cannot be checked locally
            worst = int(np.argmax(res))
            if res[worst] <= check_tolerance * pitch:
                break
            idx, ij = np.delete(idx, worst), np.delete(ij, worst, axis=0)
    if len(idx) < min_points:
        raise ValueError(f"points: only {len(idx)} of {len(pts)} points fit a square lattice "
                         f"(pitch {pitch:.1f} px); need at least {min_points}")
    order = np.lexsort((ij[:, 0], ij[:, 1]))
    idx, ij = idx[order], ij[order]
    unassigned = np.setdiff1d(np.arange(len(pts)), idx)
    return GridIndex(pts[idx].copy(), ij, idx, unassigned, pitch, basis)
