"""JointTrack pose files (``.jts``): read and write, and their camera frame.

Format (``JT_EULER_312``; JointTrack Auto reads it and its own ``JTA_EULER_KINEMATICS`` the
same way): line 1 the format name, line 2 the column titles ``x_tran, y_tran, z_tran, z_rot,
x_rot, y_rot``, then one comma-separated line of six numbers per frame (mm, degrees);
``NOT_OPTIMIZED`` in the first column marks a frame without a pose.

Euler convention: ``R = Rz(z_rot) @ Rx(x_rot) @ Ry(y_rot)`` with column vectors
(``V_global = R V_local``), the body-fixed 3-1-2 sequence the format is named after — as in the
published JointTrack tools' ``jts.read`` (``rot.z(jts[k,3]) @ rot.x(jts[k,4]) @ rot.y(jts[k,5])``,
Scott Banks / Shang Mu, 2010-2021) and JointTrack Auto's loader, which maps columns 3, 4, 5 to
z, x, y. :func:`euler312_to_matrix` is checked against that product in the tests.

Camera frame: a ``.jts`` pose is ``T_camera_from_bone`` in JointTrack's camera frame — origin at
the X-ray source (the perspective centre), x along the image's columns, y *up* the image, z
pointing back from the image plane towards the source, so bones in front of the source have
negative ``z_tran`` (the published example poses are at ``z ≈ -1000`` mm, a source-to-bone
distance). That is OpenCV's camera frame turned 180° about x: ``T_jt = diag(1, -1, -1) @ T_cv``.
The y direction is the OpenGL convention JointTrack renders with; it was not checked against a
JointTrack-rendered image here (no JointTrack calibration with images is in ``shared/data``).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from .atomic import atomic_write
from .errors import reads

__all__ = [
    "JT_FROM_OPENCV",
    "euler312_to_matrix",
    "jts_to_lab",
    "lab_to_jts",
    "matrix_to_euler312",
    "read_jts",
    "write_jts",
]

JT_FROM_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])
JT_FROM_OPENCV.setflags(write=False)
HEADER = (
    "          x_tran,          y_tran,          z_tran,"
    "                   z_rot,           x_rot,           y_rot"
)


def euler312_to_matrix(pose6) -> np.ndarray:
    """``(..., 4, 4)`` from ``(..., 6)`` ``x, y, z, z_rot, x_rot, y_rot`` (mm, degrees)."""
    a = np.asarray(pose6, dtype=float)
    if a.shape[-1:] != (6,):
        raise ValueError(f"pose6: expected shape (..., 6), got {a.shape}")
    z, x, y = (np.radians(a[..., k]) for k in (3, 4, 5))
    cz, sz, cx, sx, cy, sy = np.cos(z), np.sin(z), np.cos(x), np.sin(x), np.cos(y), np.sin(y)
    T = np.zeros((*a.shape[:-1], 4, 4))
    # Rz @ Rx @ Ry
    T[..., 0, 0] = cz * cy - sz * sx * sy
    T[..., 0, 1] = -sz * cx
    T[..., 0, 2] = cz * sy + sz * sx * cy
    T[..., 1, 0] = sz * cy + cz * sx * sy
    T[..., 1, 1] = cz * cx
    T[..., 1, 2] = sz * sy - cz * sx * cy
    T[..., 2, 0] = -cx * sy
    T[..., 2, 1] = sx
    T[..., 2, 2] = cx * cy
    T[..., :3, 3] = a[..., :3]
    T[..., 3, 3] = 1.0
    return T


def matrix_to_euler312(T) -> np.ndarray:
    """Inverse of :func:`euler312_to_matrix`; ``x_rot`` in [-90, 90]."""
    T = np.asarray(T, dtype=float)
    if T.shape[-2:] != (4, 4):
        raise ValueError(f"T: expected shape (..., 4, 4), got {T.shape}")
    R = T[..., :3, :3]
    x = np.arcsin(np.clip(R[..., 2, 1], -1, 1))
    z = np.arctan2(-R[..., 0, 1], R[..., 1, 1])
    y = np.arctan2(-R[..., 2, 0], R[..., 2, 2])
    return np.concatenate([T[..., :3, 3], np.degrees(np.stack([z, x, y], axis=-1))], axis=-1)


def lab_to_jts(T_lab_from_bone, camera) -> np.ndarray:
    """JointTrack ``T_camera_from_bone`` for a Talus camera (``R``, ``t``: lab -> OpenCV camera)."""
    C = np.eye(4)
    C[:3, :3], C[:3, 3] = camera.R, np.ravel(camera.t)
    return JT_FROM_OPENCV @ C @ np.asarray(T_lab_from_bone, dtype=float)


def jts_to_lab(T_jt, camera) -> np.ndarray:
    """Inverse of :func:`lab_to_jts`."""
    C = np.eye(4)
    C[:3, :3], C[:3, 3] = camera.R, np.ravel(camera.t)
    return np.linalg.inv(JT_FROM_OPENCV @ C) @ np.asarray(T_jt, dtype=float)


def write_jts(path: str | os.PathLike, poses) -> None:
    """Write ``(n, 4, 4)`` camera-frame poses (NaN = not optimised) as ``JT_EULER_312``, atomically."""
    P = np.asarray(poses, dtype=float)
    if P.ndim != 3 or P.shape[1:] != (4, 4) or not len(P):
        raise ValueError(f"poses: expected shape (n_frames, 4, 4), got {P.shape}")
    lines = ["JT_EULER_312", HEADER]
    for T in P:
        if np.isnan(T).any():
            lines.append(",".join(["NOT_OPTIMIZED"] + ["0"] * 5))
            continue
        R = T[:3, :3]
        if np.abs(R @ R.T - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
            raise ValueError("poses: expected rigid transforms")
        lines.append(",".join(f"{v:.10g}" for v in matrix_to_euler312(T)))
    atomic_write(path, "\n".join(lines) + "\n")


def read_jts(path: str | os.PathLike) -> np.ndarray:
    """Read a ``JT_EULER_312`` / ``JTA_EULER_KINEMATICS`` file: ``(n, 4, 4)`` camera-frame poses,
    NaN for ``NOT_OPTIMIZED`` frames."""
    return _read(Path(path))


@reads("a JointTrack pose file (JT_EULER_312: title line, column line, 6 numbers a frame)")
def _read(path: Path) -> np.ndarray:
    lines = path.read_text(encoding="utf-8-sig").splitlines()
    if not lines or lines[0].strip() not in ("JT_EULER_312", "JTA_EULER_KINEMATICS"):
        raise ValueError(f"{path}: line 1: expected 'JT_EULER_312' or 'JTA_EULER_KINEMATICS'")
    out = []
    for no, ln in enumerate(lines[2:], start=3):
        if not ln.strip():
            continue
        parts = [p.strip() for p in ln.split(",")]
        if parts and parts[-1] == "":
            parts = parts[:-1]
        if len(parts) < 6:
            raise ValueError(f"{path}: line {no}: {len(parts)} values, expected 6")
        if parts[0].replace(" ", "") == "NOT_OPTIMIZED":
            out.append(np.full((4, 4), np.nan))
            continue
        try:
            v = [float(p) for p in parts[:6]]
        except ValueError:
            raise ValueError(f"{path}: line {no}: expected 6 numbers, got {ln.strip()[:60]!r}") from None
        if not all(math.isfinite(x) for x in v):
            raise ValueError(f"{path}: line {no}: non-finite value")
        out.append(euler312_to_matrix(v))
    if not out:
        raise ValueError(f"{path}: no pose lines after the two header lines")
    return np.stack(out)
