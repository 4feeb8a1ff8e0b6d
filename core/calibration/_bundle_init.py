"""Initial guess of the bundle adjustment: per-frame DLT, median intrinsics, PnP, rig averaging.

Private to :mod:`core.calibration.bundle`. Frames are in the rig frame of camera 1 (index 0).
"""

from __future__ import annotations

import cv2
import numpy as np

from ..geometry.camera import Rig
from . import _so3
from .dlt import calibrate_dlt


def pnp(K: np.ndarray, X: np.ndarray, uv: np.ndarray) -> np.ndarray | None:
    """``T_cam_from_object`` from >= 4 observed points and known intrinsics, or None."""
    ok = np.all(np.isfinite(uv), axis=1)
    if ok.sum() < 4:
        return None
    Xo = np.ascontiguousarray(X[ok], np.float64)
    xo = np.ascontiguousarray(uv[ok], np.float64)
    try:
        good, rvec, tvec = cv2.solvePnP(Xo, xo, K, None, flags=cv2.SOLVEPNP_SQPNP)
        if not good:
            return None
        rvec, tvec = cv2.solvePnPRefineLM(Xo, xo, K, None, rvec, tvec)
    except cv2.error:
        return None
    R = cv2.Rodrigues(rvec)[0]
    t = tvec.ravel()
    if np.any(Xo @ R[2] + t[2] <= 0):
        return None
    return _so3.rigid(R, t)


def from_dlt(frames, sizes, fixed_pp, sid_f) -> tuple[np.ndarray, list[str]]:
    """Per-camera intrinsics ``(V, 4)`` (fx, fy, cu, cv) as medians of per-frame DLTs, and
    notes on cameras without any usable frame."""
    V = len(sizes)
    intr = np.full((V, 4), np.nan)
    notes = []
    for c, (w, h) in enumerate(sizes):
        ks = []
        for fr in frames:
            d = calibrate_dlt(fr.points, fr.uv[c], width=w, height=h, max_skew_px=1e9)
            if d.ok:
                ks.append([d.camera.fx, d.camera.fy, d.camera.cu, d.camera.cv])
        if ks:
            intr[c] = np.median(np.asarray(ks), axis=0)
        else:
            notes.append(f"camera {c + 1}: no frame has >= 6 non-coplanar observed beads for the "
                         "DLT initial guess")
        if fixed_pp[c] is not None:
            intr[c, 2:] = fixed_pp[c]
        if sid_f[c] is not None and not np.isfinite(intr[c, 0]):
            intr[c, :2] = sid_f[c]
            if fixed_pp[c] is None:
                intr[c, 2:] = ((w - 1) / 2, (h - 1) / 2)
    return intr, notes


def from_rig(rig: Rig) -> tuple[np.ndarray, np.ndarray]:
    """Intrinsics ``(V, 4)`` and relative poses ``T_cam_c_from_cam_1 (V, 4, 4)`` of a rig."""
    intr = np.array([[c.fx, c.fy, c.cu, c.cv] for c in rig])
    T1 = rig[0].T_cam_from_lab
    rel = np.stack([c.T_cam_from_lab @ _so3.inv(T1) for c in rig])
    return intr, rel


def poses_with_intrinsics(frames, intr) -> np.ndarray:
    """``(F, V, 4, 4)`` PnP pose of every frame in every view (NaN where < 4 points)."""
    F, V = len(frames), len(intr)
    out = np.full((F, V, 4, 4), np.nan)
    for c in range(V):
        fx, fy, cu, cv = intr[c]
        K = np.array([[fx, 0, cu], [0, fy, cv], [0, 0, 1.0]])
        for f, fr in enumerate(frames):
            T = pnp(K, fr.points, fr.uv[c])
            if T is not None:
                out[f, c] = T
    return out


def relative_poses(view_poses: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """``T_cam_c_from_cam_1`` averaged over the frames seen well by both views.

    Robust: the medoid of the per-frame estimates (smallest median distance to the others)
    selects the inliers (rotation within 3 median deviations or 0.2°, translation within 3 median
    deviations or 2 mm), whose chordal-mean rotation and median translation are returned.
    """
    V = view_poses.shape[1]
    rel = np.tile(np.eye(4), (V, 1, 1))
    notes = []
    for c in range(1, V):
        both = np.isfinite(view_poses[:, 0, 0, 0]) & np.isfinite(view_poses[:, c, 0, 0])
        if not both.any():
            notes.append(f"camera {c + 1}: no frame is seen well enough by camera 1 and camera {c + 1} "
                         "together to relate them")
            rel[c] = np.nan
            continue
        Ts = view_poses[both, c] @ _so3.inv(view_poses[both, 0])
        ang = np.linalg.norm(_so3.log(np.einsum("aij,bkj->abik", Ts[:, :3, :3], Ts[:, :3, :3])), axis=2)
        dt = np.linalg.norm(Ts[:, None, :3, 3] - Ts[None, :, :3, 3], axis=2)
        med = np.argmin(np.median(ang / max(np.median(ang), 1e-9) + dt / max(np.median(dt), 1e-9), axis=1))
        a, d = ang[med], dt[med]
        inl = (a <= max(3 * np.median(a), np.radians(0.2))) & (d <= max(3 * np.median(d), 2.0))
        R = _so3.mean_rotation(Ts[inl, :3, :3])
        t = np.median(Ts[inl, :3, 3], axis=0)
        rel[c] = _so3.rigid(R, t)
    return rel, notes


def frame_poses(view_poses: np.ndarray, rel: np.ndarray) -> np.ndarray:
    """``T_cam1_from_object (F, 4, 4)`` from the best view of each frame (NaN if none)."""
    F, V = view_poses.shape[:2]
    out = np.full((F, 4, 4), np.nan)
    for f in range(F):
        for c in range(V):
            if np.isfinite(view_poses[f, c, 0, 0]) and np.all(np.isfinite(rel[c])):
                out[f] = _so3.inv(rel[c]) @ view_poses[f, c]
                break
    return out
