"""Near symmetries of a calibration object: rigid motions and reflections that map most beads
onto beads of the same size.

Private to :mod:`core.calibration.labelling` (which re-exports :func:`near_symmetries`). One
view cannot tell a labelling from its image under such a motion by the beads the motion maps
onto beads (the cube's three squares turned by 90°): RANSAC fits every image of its hypotheses
and lets the other beads decide.
"""

from __future__ import annotations

import numpy as np

from .objects import CalibrationTarget


def near_symmetries(target: CalibrationTarget, *, min_fraction: float = 0.6, tol_mm: float | None = None,
                    max_class: int = 24) -> tuple[np.ndarray, ...]:
    """Label maps ``π`` (model index -> model index, -1 where the bead maps onto no bead) of the
    rigid motions and reflections, other than the identity and the exact
    :attr:`~core.calibration.objects.CalibrationTarget.symmetries`, that map at least
    ``min_fraction`` of the beads onto beads of the same diameter (within ``tol_mm``, default a
    tenth of the smallest diameter).

    One view cannot tell such an image of a labelling from the right one by the beads the motion
    maps onto beads (the cube's three squares turned by 90°, 180° or 270° about its axis): only the
    other beads (each plane's fifth bead) can. The motions are found from congruent triangles of
    beads of one size class (classes of at most ``max_class`` beads).
    """
    key = (target.centers.tobytes(), target.diameters.tobytes(), min_fraction, tol_mm, max_class)
    if key not in _NEAR_SYM:
        _NEAR_SYM[key] = _near_symmetries(target, min_fraction, tol_mm, max_class)
    return _NEAR_SYM[key]


_NEAR_SYM: dict = {}


def _frame3(p: np.ndarray, sign: float) -> np.ndarray:
    e1 = (p[1] - p[0]) / np.linalg.norm(p[1] - p[0])
    e3 = np.cross(e1, p[2] - p[0])
    e3 /= np.linalg.norm(e3)
    return np.column_stack([e1, np.cross(e3, e1), sign * e3])


def _near_symmetries(target, min_fraction, tol_mm, max_class) -> tuple[np.ndarray, ...]:
    from itertools import combinations, permutations

    X, dia = target.centers, target.diameters
    n = len(X)
    tol = 0.1 * float(dia.min()) if tol_mm is None else float(tol_mm)
    _, cls = target.size_classes
    same = dia[:, None] == dia[None]
    exact = {p.tobytes() for p in target.symmetries}
    D = np.linalg.norm(X[:, None] - X[None], axis=2)
    out = {}
    for c in np.unique(cls):
        idx = np.flatnonzero(cls == c)
        if not 3 <= len(idx) <= max_class:
            continue
        tri = np.array(list(permutations(idx, 3)))
        sig = np.stack([D[tri[:, 0], tri[:, 1]], D[tri[:, 0], tri[:, 2]], D[tri[:, 1], tri[:, 2]]], axis=1)
        for ref in combinations(idx, 3):
            a = X[list(ref)]
            if np.linalg.norm(np.cross(a[1] - a[0], a[2] - a[0])) < tol * max(D[ref[0], ref[1]], 1.0):
                continue
            s0 = np.array([D[ref[0], ref[1]], D[ref[0], ref[2]], D[ref[1], ref[2]]])
            for img in tri[np.all(np.abs(sig - s0) < tol, axis=1)]:
                b = X[img]
                for sign in (1.0, -1.0):
                    R = _frame3(b, sign) @ _frame3(a, 1.0).T
                    d = np.linalg.norm(((X - a[0]) @ R.T + b[0])[:, None] - X[None], axis=2)
                    d = np.where(same, d, np.inf)
                    j = d.argmin(axis=1)
                    hit = d[np.arange(n), j] < tol
                    if hit.sum() >= min_fraction * n and len(set(j[hit])) == hit.sum():
                        p = np.where(hit, j, -1)
                        if p.tobytes() not in exact and not np.array_equal(p, np.arange(n)):
                            out[p.tobytes()] = p
    return tuple(out.values())
