"""The pose series of the plots dock (:mod:`app.plots`): a bone's centroid translation and
rotation relative to its first recorded frame, and their low-passed version at Winter's residual
cut-off. numpy and scipy only (the low-pass runs in the dock's worker thread)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def _rel_series(P: np.ndarray, centroid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centroid translation (mm) and rotation vector (deg) relative to the first finite pose."""
    n = len(P)
    t = np.full((n, 3), np.nan)
    r = np.full((n, 3), np.nan)
    ok = np.all(np.isfinite(P), axis=(1, 2))
    if not ok.any():
        return t, r
    k0 = int(np.flatnonzero(ok)[0])
    c = P[ok, :3, :3] @ centroid + P[ok, :3, 3]
    t[ok] = c - c[0]
    R0 = P[k0, :3, :3]
    r[ok] = np.rad2deg(Rotation.from_matrix(P[ok, :3, :3] @ R0.T).as_rotvec())
    return t, r


def _lowpass(P: np.ndarray, centroid: np.ndarray) -> tuple[float, tuple[np.ndarray, np.ndarray]]:
    """Winter's residual cut-off (cycles per frame) of the centroid's path and the pose series
    low-passed at it (:func:`_rel_series` of :func:`core.tracking.kinematics.filter_poses`). Runs in
    a worker thread: numpy and scipy only."""
    from core.tracking.kinematics import filter_poses, residual_cutoff

    ok = np.all(np.isfinite(P), axis=(1, 2))
    path = np.full((len(P), 3), np.nan)
    path[ok] = P[ok, :3, :3] @ centroid + P[ok, :3, 3]
    cutoff, _ = residual_cutoff(path, 1.0, candidates=np.linspace(0.02, 0.2, 19))
    return cutoff, _rel_series(filter_poses(P, 1.0, cutoff, center=centroid), centroid)
