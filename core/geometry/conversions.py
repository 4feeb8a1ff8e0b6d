"""Conversions between :class:`~core.geometry.Camera`, 3x4 projection matrices and 11-term DLTs.

Conventions
-----------
* A projection matrix ``P`` (3x4) maps homogeneous lab points (mm) to homogeneous pixels,
  ``x ~ P X``. It is defined up to a non-zero scale, *including a negative one*.
* ``P = K [R | t]`` is decomposed with the signs fixed so that ``fx > 0``, ``fy > 0``,
  ``det R = +1`` and ``K[2, 2] = 1``; the camera z-axis then points from the X-ray source towards
  the detector (points in front of the source have positive depth).
* Talus pixel coordinates are ``(u, v) = (column, row)`` with the origin at the **centre** of the
  top-left pixel; ``P`` and, unless ``convention`` says otherwise, the DLT are expressed in them.
* The standard photogrammetric 11-parameter DLT is::

      u = (L1 X + L2 Y + L3 Z + L4) / (L9 X + L10 Y + L11 Z + 1)
      v = (L5 X + L6 Y + L7 Z + L8) / (L9 X + L10 Y + L11 Z + 1)

  i.e. ``P`` scaled so that ``P[2, 3] = 1`` (``L = P.ravel()[:11]``). It cannot represent a
  camera for which the lab origin lies in the source's principal plane (``P[2, 3] = 0``).
* ``convention="dltdv"`` selects the image coordinates of DLTdv / easyWand / XMALab's DLT export
  (MATLAB heritage): 1-based, with the vertical axis pointing *up* from the bottom edge::

      u_dltdv = u + 1,        v_dltdv = height - v

  (XMALab ``Camera::getDLT`` flips rows with ``(height - 1) - v`` and then adds 1 to both axes.)
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import scipy.linalg

from .._validate import as_float_array, positive
from .camera import Camera

__all__ = [
    "DLTFit",
    "P_from_dlt",
    "camera_from_P",
    "camera_from_dlt",
    "compose_P",
    "decompose_P",
    "dlt_from_P",
    "dlt_from_correspondences",
]

Convention = Literal["talus", "dltdv"]


# ---------------------------------------------------------------------------- P <-> K, R, t
def compose_P(K, R, t) -> np.ndarray:
    """Projection matrix ``P = K [R | t]``.

    Parameters
    ----------
    K : (3, 3) array
        Intrinsics, pixels.
    R : (3, 3) array
        Rotation lab -> camera.
    t : (3,) array
        Translation lab -> camera, mm.

    Returns
    -------
    P : (3, 4) array
        Maps homogeneous lab points (mm) to homogeneous pixels ``(u, v, 1)``.
    """
    K = as_float_array(K, "K", shape=(3, 3))
    R = as_float_array(R, "R", shape=(3, 3))
    t = as_float_array(t, "t", shape=(3,))
    return K @ np.hstack([R, t[:, None]])


def decompose_P(P) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Decompose a projection matrix into ``K, R, t`` by RQ decomposition.

    Parameters
    ----------
    P : (3, 4) array
        Finite projective camera, any non-zero scale (a negative overall scale is undone).

    Returns
    -------
    K : (3, 3) array
        Upper-triangular intrinsics in pixels with ``K[2, 2] = 1`` and ``fx, fy > 0``. The skew
        ``K[0, 1]`` is returned as found (it is generally non-zero for a ``P`` from a DLT).
    R : (3, 3) array
        Proper rotation lab -> camera (``det R = +1``).
    t : (3,) array
        Translation lab -> camera, mm, so that ``P ∝ K [R | t]`` with a positive factor and the
        source at ``C = -R.T @ t``.

    Raises
    ------
    ValueError
        If ``P`` has the wrong shape, non-finite entries, or a singular left 3x3 block (a camera
        at infinity or a degenerate matrix).
    """
    P = as_float_array(P, "P", shape=(3, 4))
    M = P[:, :3]
    sv = np.linalg.svd(M, compute_uv=False)
    if sv[0] == 0 or sv[-1] <= 1e-12 * sv[0]:
        raise ValueError(
            "P: expected a finite projective camera with a non-singular left 3x3 block P[:, :3], "
            f"got singular values {sv}"
        )
    if np.linalg.det(M) < 0:  # P given with a negative overall scale
        P = -P
        M = P[:, :3]
    K, R = scipy.linalg.rq(M)
    D = np.diag(np.sign(np.diag(K)))  # RQ is unique up to these signs; D @ D = I
    K = K @ D
    R = D @ R
    t = np.linalg.solve(K, P[:, 3])
    K = np.triu(K / K[2, 2])
    if np.linalg.det(R) < 0:  # cannot happen for det(M) > 0 and positive diag(K); guard anyway
        raise ValueError("P: decomposition produced a reflection; P is not a valid camera")
    return K, R, t


def _skew_shift_px(K: np.ndarray, height: int) -> float:
    """Largest horizontal shift (px) over the image rows caused by setting ``K[0, 1]`` to zero."""
    fy, cv = K[1, 1], K[1, 2]
    dy = max(abs(-0.5 - cv), abs(height - 0.5 - cv)) / fy
    return float(abs(K[0, 1]) * dy)


def camera_from_P(
    P,
    width: int,
    height: int,
    *,
    pixel_size: float | None = None,
    name: str = "",
    max_skew_px: float = 0.5,
    return_skew_shift: bool = False,
):
    """A zero-skew :class:`Camera` from a 3x4 projection matrix.

    The :class:`Camera` model has no skew. A skew ``s = K[0, 1]`` (typical of a ``P`` estimated by
    an unconstrained DLT) is dropped, which moves the projection of a point at row ``v`` by
    ``s (v - cv) / fy`` pixels horizontally. The largest such shift over the image rows is checked
    against ``max_skew_px``.

    Parameters
    ----------
    P : (3, 4) array
        Projection matrix in Talus pixels (``(u, v) = (column, row)``, origin at the centre of the
        top-left pixel), any non-zero scale.
    width, height : int
        Image size in pixels (columns, rows).
    pixel_size : float, optional
        Detector pixel pitch, mm.
    name : str
        Camera label.
    max_skew_px : float
        Largest tolerated image shift (pixels) caused by dropping the skew. Default 0.5 px.
    return_skew_shift : bool
        Also return that shift.

    Returns
    -------
    camera : Camera
    skew_shift_px : float, only if ``return_skew_shift``
        Largest horizontal displacement (pixels, over the image rows) caused by dropping the skew.

    Raises
    ------
    ValueError
        On a bad ``P`` (see :func:`decompose_P`), a bad image size, or if dropping the skew moves
        image points by more than ``max_skew_px``.
    """
    max_skew_px = float(max_skew_px)
    if not np.isfinite(max_skew_px) or max_skew_px < 0:
        raise ValueError(
            f"max_skew_px: expected a non-negative number of pixels, got {max_skew_px}"
        )
    K, R, t = decompose_P(P)
    if int(height) != height or height < 1:
        raise ValueError(f"height: expected a positive integer number of pixels, got {height!r}")
    shift = _skew_shift_px(K, int(height))
    if shift > max_skew_px:
        raise ValueError(
            f"P: the intrinsics have skew K[0, 1] = {K[0, 1]:.4g} px; dropping it (the Camera "
            f"model has zero skew) moves image points by up to {shift:.3g} px, more than "
            f"max_skew_px={max_skew_px:g}"
        )
    K[0, 1] = 0.0
    cam = Camera(K, R, t, width, height, pixel_size, name)
    return (cam, shift) if return_skew_shift else cam


# ---------------------------------------------------------------------------- DLT <-> P
def _image_transform(convention: str, height) -> np.ndarray:
    """3x3 matrix mapping homogeneous Talus pixels to the ``convention``'s image coordinates."""
    if convention == "talus":
        return np.eye(3)
    if convention == "dltdv":
        if height is None:
            raise ValueError('height: required (image rows, pixels) with convention="dltdv"')
        h = positive(height, "height")
        return np.array([[1.0, 0.0, 1.0], [0.0, -1.0, h], [0.0, 0.0, 1.0]])
    raise ValueError(f'convention: expected "talus" or "dltdv", got {convention!r}')


def dlt_from_P(P, *, convention: Convention = "talus", height: float | None = None) -> np.ndarray:
    """The 11 DLT coefficients ``L1..L11`` of a projection matrix.

    Parameters
    ----------
    P : (3, 4) array
        Projection matrix in Talus pixels (``(u, v) = (column, row)``, origin at the centre of
        the top-left pixel), lab in mm, any non-zero scale.
    convention : {"talus", "dltdv"}
        Image coordinates the DLT is expressed in: ``"talus"`` (same as ``P``) or ``"dltdv"``
        (1-based, vertical axis up: ``u + 1, height - v``; DLTdv / easyWand / XMALab).
    height : float, optional
        Image height in pixels; required for ``"dltdv"``.

    Returns
    -------
    L : (11,) array
        ``P`` scaled to ``P[2, 3] = 1``, row-major, last entry dropped.

    Raises
    ------
    ValueError
        On a bad ``P``, or if ``P[2, 3]`` is ~0 (lab origin in the source's principal plane).
    """
    P = as_float_array(P, "P", shape=(3, 4))
    Pd = _image_transform(convention, height) @ P
    if abs(Pd[2, 3]) <= 1e-12 * np.abs(Pd).max():
        raise ValueError(
            "P: P[2, 3] is ~0 (the lab origin lies in the source's principal plane), which the "
            "11-parameter DLT (normalised by L12 = 1) cannot represent"
        )
    return (Pd / Pd[2, 3]).ravel()[:11].copy()


def P_from_dlt(L, *, convention: Convention = "talus", height: float | None = None) -> np.ndarray:
    """Projection matrix (Talus pixels) from the 11 DLT coefficients ``L1..L11``.

    Parameters
    ----------
    L : (11,) array
        DLT coefficients; see the module docstring for the equations.
    convention : {"talus", "dltdv"}
        Image coordinates of the DLT (see :func:`dlt_from_P`).
    height : float, optional
        Image height in pixels; required for ``"dltdv"``.

    Returns
    -------
    P : (3, 4) array
        Projection matrix mapping lab points (mm) to Talus pixels ``(column, row)``.
    """
    L = as_float_array(L, "L", shape=(11,))
    A = _image_transform(convention, height)
    return np.linalg.solve(A, np.append(L, 1.0).reshape(3, 4))


def camera_from_dlt(
    L,
    width: int,
    height: int,
    *,
    convention: Convention = "talus",
    pixel_size: float | None = None,
    name: str = "",
    max_skew_px: float = 0.5,
) -> Camera:
    """A zero-skew :class:`Camera` from 11 DLT coefficients (see :func:`camera_from_P`).

    Parameters
    ----------
    L : (11,) array
        DLT coefficients in the image coordinates of ``convention``.
    width, height : int
        Image size in pixels (columns, rows); ``height`` also defines the ``"dltdv"`` flip.
    convention : {"talus", "dltdv"}
        See :func:`dlt_from_P`.
    pixel_size : float, optional
        Detector pixel pitch, mm.
    name : str
        Camera label.
    max_skew_px : float
        Largest tolerated image shift (pixels) caused by dropping the DLT's skew.
    """
    P = P_from_dlt(L, convention=convention, height=height)
    return camera_from_P(
        P, width, height, pixel_size=pixel_size, name=name, max_skew_px=max_skew_px
    )


# ---------------------------------------------------------------------------- DLT estimation
@dataclass(frozen=True, eq=False)
class DLTFit:
    """Result of :func:`dlt_from_correspondences`.

    Attributes
    ----------
    coefficients : (11,) array
        DLT coefficients ``L1..L11`` in the requested image convention.
    P : (3, 4) array
        The same camera as a projection matrix in Talus pixels, scaled so that
        ``P = K [R | t]`` with ``K[2, 2] = 1`` (positive depth for the input points).
    residuals : (N,) array
        Reprojection error (2D distance) of each input point, pixels.
    """

    coefficients: np.ndarray
    P: np.ndarray
    residuals: np.ndarray

    @property
    def rms_px(self) -> float:
        """Root-mean-square reprojection distance, pixels (~ sqrt(2) x the per-axis noise)."""
        return float(np.sqrt(np.mean(self.residuals**2)))


def _similarity_normaliser(pts: np.ndarray) -> np.ndarray:
    """Hartley normalisation: centroid to 0, mean distance to sqrt(dim)."""
    d = pts.shape[1]
    c = pts.mean(axis=0)
    mean_dist = np.linalg.norm(pts - c, axis=1).mean()
    s = np.sqrt(d) / mean_dist
    T = np.eye(d + 1)
    T[:d, :d] *= s
    T[:d, d] = -s * c
    return T


def dlt_from_correspondences(
    X, uv, *, convention: Convention = "talus", height: float | None = None
) -> DLTFit:
    """Linear DLT estimate of a camera from >= 6 non-coplanar 3D <-> 2D correspondences.

    Hartley-normalised homogeneous least squares (minimises the algebraic error in the
    normalised frames); refine with a non-linear method when accuracy matters.

    Parameters
    ----------
    X : (N, 3) array
        Lab points, mm; N >= 6, not all in one plane.
    uv : (N, 2) array
        Their image positions in the coordinates of ``convention`` (``"talus"``: ``(column, row)``
        pixels with the origin at the centre of the top-left pixel).
    convention : {"talus", "dltdv"}
        Image convention of ``uv`` and of the returned coefficients (see :func:`dlt_from_P`).
    height : float, optional
        Image height in pixels; required for ``"dltdv"``.

    Returns
    -------
    DLTFit
        Coefficients, projection matrix (Talus pixels) and per-point residuals (pixels).

    Raises
    ------
    ValueError
        On wrong shapes, NaN, fewer than 6 points, coplanar/collinear points or another
        degenerate configuration.
    """
    X = as_float_array(X, "X", shape=(None, 3))
    uv = as_float_array(uv, "uv", shape=(None, 2))
    n = len(X)
    if len(uv) != n:
        raise ValueError(f"uv: expected {n} points to match X, got {len(uv)}")
    if n < 6:
        raise ValueError(
            f"X: expected at least 6 correspondences for the 11-parameter DLT, got {n}"
        )
    sv = np.linalg.svd(X - X.mean(axis=0), compute_uv=False)
    if sv[2] <= 1e-6 * sv[0]:
        raise ValueError(
            "X: the points are coplanar (or collinear); the 11-parameter DLT needs a non-planar "
            "calibration object"
        )
    A_img = _image_transform(convention, height)
    uvh = np.column_stack([uv, np.ones(n)]) @ np.linalg.inv(A_img).T
    uv_t = uvh[:, :2] / uvh[:, 2:]  # Talus pixels
    T2 = _similarity_normaliser(uv_t)
    T3 = _similarity_normaliser(X)
    xn = (np.column_stack([uv_t, np.ones(n)]) @ T2.T)[:, :2]
    Xn = np.column_stack([X, np.ones(n)]) @ T3.T
    A = np.zeros((2 * n, 12))
    A[0::2, 0:4] = Xn
    A[0::2, 8:12] = -xn[:, :1] * Xn
    A[1::2, 4:8] = Xn
    A[1::2, 8:12] = -xn[:, 1:] * Xn
    _, s, Vt = np.linalg.svd(A)
    if s[10] <= 1e-10 * s[0]:
        raise ValueError("X, uv: degenerate configuration, the DLT system has no unique solution")
    Pn = Vt[-1].reshape(3, 4)
    P = np.linalg.solve(T2, Pn) @ T3
    Xh = np.column_stack([X, np.ones(n)])
    w = Xh @ P[2]
    # Scale to P = K [R | t] with K[2, 2] = 1 and positive depth for the observed points.
    P = P * (np.sign(np.median(w)) / np.linalg.norm(P[2, :3]))
    proj = Xh @ P.T
    res = np.linalg.norm(proj[:, :2] / proj[:, 2:] - uv_t, axis=1)
    coeffs = dlt_from_P(P, convention=convention, height=height)
    return DLTFit(coefficients=coeffs, P=P, residuals=res)
