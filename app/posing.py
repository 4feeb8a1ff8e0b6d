"""Interactive posing math (Qt-free): what a mouse drag or a key nudge does to a bone's pose.

All functions take and return 4x4 ``T_lab_from_bone`` (mm) and keep the bone's centroid as the
pivot of rotations, as the optimizers do. Pixel coordinates are ``(u, v) = (column, row)``.

* :func:`translate_in_view` — drag in a fluoroscope pane: the bone moves parallel to that
  camera's detector plane so its centroid's projection follows the mouse exactly; its depth
  along that camera's principal ray is unchanged.
* :func:`rotate_in_view` — rotation drag in a pane: the bone turns about the ray from that
  camera's source through its centroid, by the angle the mouse swept around the projected
  centroid (clockwise on screen is positive, as ``v`` points down).
* :func:`nudge` — keyboard steps: translations along and rotations about the lab axes through
  the centroid.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from core.geometry.camera import Camera

__all__ = ["drag_angle", "nudge", "rotate_in_view", "translate_in_view"]


def _about(T: np.ndarray, centre_lab: np.ndarray, R: np.ndarray, shift=(0.0, 0.0, 0.0)) -> np.ndarray:
    """``Tr(c + shift) · R · Tr(-c) · T``: rotate about a lab point, then translate."""
    out = np.asarray(T, dtype=float).copy()
    out[:3, :3] = R @ out[:3, :3]
    out[:3, 3] = R @ (out[:3, 3] - centre_lab) + centre_lab + np.asarray(shift, dtype=float)
    return out


def centroid_lab(T: np.ndarray, centroid_bone: np.ndarray) -> np.ndarray:
    return np.asarray(T)[:3, :3] @ centroid_bone + np.asarray(T)[:3, 3]


def translate_in_view(camera: Camera, T, centroid_bone, du: float, dv: float) -> np.ndarray:
    """Move the bone so its centroid's projection in ``camera`` moves by ``(du, dv)`` pixels."""
    c = centroid_lab(T, centroid_bone)
    xc = camera.R @ c + camera.t
    if xc[2] <= 0:
        raise ValueError("camera: the bone's centroid is behind this camera's source")
    d_cam = np.array([du * xc[2] / camera.fx, dv * xc[2] / camera.fy, 0.0])
    return _about(T, c, np.eye(3), camera.R.T @ d_cam)


def drag_angle(centre_uv, start_uv, end_uv) -> float:
    """Angle (rad) swept by the mouse around ``centre_uv``; clockwise on screen is positive."""
    c = np.asarray(centre_uv, dtype=float)
    a = np.asarray(start_uv, dtype=float) - c
    b = np.asarray(end_uv, dtype=float) - c
    return float(np.arctan2(a[0] * b[1] - a[1] * b[0], a @ b))


def rotate_in_view(camera: Camera, T, centroid_bone, angle: float) -> np.ndarray:
    """Rotate the bone by ``angle`` (rad) about the ray from ``camera``'s source through its
    centroid; the projected centroid stays put and the image turns clockwise for angle > 0."""
    c = centroid_lab(T, centroid_bone)
    axis = c - camera.source
    axis /= np.linalg.norm(axis)
    R = Rotation.from_rotvec(axis * float(angle)).as_matrix()
    return _about(T, c, R)


def nudge(T, centroid_bone, *, translate=(0.0, 0.0, 0.0), rotate=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Translate by ``translate`` (lab mm) and rotate by the rotation vector ``rotate`` (lab,
    rad) about the bone's centroid."""
    c = centroid_lab(T, centroid_bone)
    R = Rotation.from_rotvec(np.asarray(rotate, dtype=float)).as_matrix()
    return _about(T, c, R, translate)
