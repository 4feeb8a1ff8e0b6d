"""Pinhole X-ray camera and two-camera (or n-camera) rig.

An X-ray "camera" is a point source and a flat detector. Talus models it as a pinhole camera
``x ~ K [R | t] X``:

* ``K = [[fx, 0, cu], [0, fy, cv], [0, 0, 1]]`` with focal lengths and principal point in
  pixels (skew is always 0);
* ``R`` (3x3 rotation) and ``t`` (3, mm) map lab coordinates into the camera frame, whose
  z-axis is the principal ray pointing from the source towards the detector;
* the source (camera centre) is ``C = -R^T t``;
* the source-to-image distance is ``SID = fx * pixel_size`` when the detector pixel size (mm) is
  known.

Image points are ``(u, v) = (column, row)`` with the origin at the centre of the top-left pixel;
pixel ``[r, c]`` of an image array is centred at ``(u, v) = (c, r)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._validate import as_float_array, as_points, check_rotation, positive

__all__ = ["Camera", "Rig", "make_K"]


def make_K(fx: float, fy: float, cu: float, cv: float) -> np.ndarray:
    """Intrinsic matrix from focal lengths and principal point (pixels)."""
    return np.array([[fx, 0.0, cu], [0.0, fy, cv], [0.0, 0.0, 1.0]])


def _check_K(K) -> np.ndarray:
    K = as_float_array(K, "K", shape=(3, 3))
    if not np.allclose(K[2], [0, 0, 1]) or K[1, 0] != 0 or K[2, 0] != 0:
        raise ValueError(f"K: expected an upper-triangular matrix with last row (0, 0, 1), got\n{K}")
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(
            f"K: expected positive focal lengths fx, fy (a singular or mirrored K), got "
            f"fx={K[0, 0]}, fy={K[1, 1]}"
        )
    if abs(K[0, 1]) > 1e-9 * K[0, 0]:
        raise ValueError(f"K: expected zero skew, got K[0, 1] = {K[0, 1]}")
    K = K.copy()
    K[0, 1] = 0.0
    return K


@dataclass(frozen=True, eq=False)
class Camera:
    """A calibrated X-ray camera (pinhole model).

    Parameters
    ----------
    K : (3, 3) array
        Intrinsics in pixels, zero skew.
    R : (3, 3) array
        Rotation lab -> camera (orthonormal, det +1).
    t : (3,) array
        Translation lab -> camera, mm.
    width, height : int
        Image size in pixels (columns, rows).
    pixel_size : float, optional
        Detector pixel pitch in mm (square pixels); gives the physical detector plane and SID.
    name : str
        Free label (e.g. ``"cam01"``).
    """

    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    width: int
    height: int
    pixel_size: float | None = None
    name: str = ""
    _Kinv: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        K = _check_K(self.K)
        R = check_rotation(self.R, "R")
        t = as_float_array(self.t, "t", shape=(3,))
        for nm in ("width", "height"):
            v = getattr(self, nm)
            if int(v) != v or v < 1:
                raise ValueError(f"{nm}: expected a positive integer number of pixels, got {v!r}")
        if self.pixel_size is not None:
            object.__setattr__(self, "pixel_size", positive(self.pixel_size, "pixel_size"))
        for nm, arr in (("K", K), ("R", R), ("t", t)):
            arr = arr.copy()
            arr.setflags(write=False)
            object.__setattr__(self, nm, arr)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        Kinv = np.linalg.inv(K)
        Kinv.setflags(write=False)
        object.__setattr__(self, "_Kinv", Kinv)

    # ------------------------------------------------------------------ intrinsics
    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cu(self) -> float:
        return float(self.K[0, 2])

    @property
    def cv(self) -> float:
        return float(self.K[1, 2])

    @property
    def image_shape(self) -> tuple[int, int]:
        """``(height, width)``: the shape of an image array from this camera."""
        return (self.height, self.width)

    @property
    def sid(self) -> float:
        """Source-to-image distance in mm (``fx * pixel_size``)."""
        if self.pixel_size is None:
            raise ValueError("pixel_size: the camera has no detector pixel size, SID is unknown")
        return self.fx * self.pixel_size

    # ------------------------------------------------------------------ extrinsics
    @property
    def source(self) -> np.ndarray:
        """X-ray source position ``C = -R^T t`` in the lab (mm)."""
        return -self.R.T @ self.t

    @property
    def principal_ray(self) -> np.ndarray:
        """Unit vector (lab) from the source through the principal point."""
        return self.R[2].copy()

    @property
    def P(self) -> np.ndarray:
        """The 3x4 projection matrix ``K [R | t]``."""
        return self.K @ np.hstack([self.R, self.t[:, None]])

    @property
    def T_cam_from_lab(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = self.R
        T[:3, 3] = self.t
        return T

    # ------------------------------------------------------------------ projection
    def project(self, X, *, return_depth: bool = False):
        """Project lab points to pixels.

        Parameters
        ----------
        X : (..., 3) array
            Lab points, mm.
        return_depth : bool
            Also return the depth along the principal ray (mm; positive in front of the source).

        Returns
        -------
        uv : (..., 2) array
            ``(u, v) = (column, row)`` pixel coordinates, origin at the centre of the top-left pixel.
        depth : (...,) array, only if ``return_depth``
        """
        pts, lead = as_points(X, "X", 3)
        xc = pts @ self.R.T + self.t
        z = xc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.fx * xc[:, 0] / z + self.cu
            v = self.fy * xc[:, 1] / z + self.cv
        uv = np.stack([u, v], axis=-1).reshape(*lead, 2)
        if return_depth:
            return uv, z.reshape(lead)
        return uv

    def rays(self, uv) -> tuple[np.ndarray, np.ndarray]:
        """Back-project pixels to rays in the lab.

        Parameters
        ----------
        uv : (..., 2) array
            Pixel coordinates ``(column, row)``, origin at the centre of the top-left pixel.

        Returns
        -------
        origin : (3,) array
            The source position (all rays start there), mm.
        directions : (..., 3) array
            Unit direction of each ray (lab), pointing from the source towards the detector.
        """
        pts, lead = as_points(uv, "uv", 2)
        h = np.column_stack([pts, np.ones(len(pts))])
        d = (h @ self._Kinv.T) @ self.R  # R^T applied to each row
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return self.source, d.reshape(*lead, 3)

    def pixel_grid(self) -> np.ndarray:
        """``(height, width, 2)`` array of the ``(u, v)`` coordinates of every pixel centre."""
        v, u = np.mgrid[0 : self.height, 0 : self.width].astype(np.float64)
        return np.stack([u, v], axis=-1)

    # ------------------------------------------------------------------ detector
    def detector_point(self, uv, *, distance: float | None = None) -> np.ndarray:
        """Lab position (mm) of pixel(s) ``uv`` on the detector plane.

        The detector plane is perpendicular to the principal ray at ``distance`` from the
        source (default: the SID, which needs ``pixel_size``).
        """
        dist = self.sid if distance is None else positive(distance, "distance")
        pts, lead = as_points(uv, "uv", 2)
        h = np.column_stack([pts, np.ones(len(pts))]) @ self._Kinv.T  # z = 1 in the camera frame
        xc = h * dist
        X = (xc - self.t) @ self.R  # R^T (xc - t)
        return X.reshape(*lead, 3)

    def detector_corners(self, *, distance: float | None = None) -> np.ndarray:
        """(4, 3) lab positions of the outer corners of the detector (TL, TR, BR, BL), mm."""
        w, h = self.width, self.height
        uv = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])
        return self.detector_point(uv, distance=distance)

    def detector_plane(self, *, distance: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(point, unit normal)`` of the detector plane; the normal is the principal ray."""
        dist = self.sid if distance is None else positive(distance, "distance")
        return self.source + dist * self.principal_ray, self.principal_ray

    # ------------------------------------------------------------------ helpers
    def with_pose(self, R, t) -> Camera:
        return Camera(self.K, R, t, self.width, self.height, self.pixel_size, self.name)

    def __repr__(self) -> str:
        return (
            f"Camera({self.name!r}, {self.width}x{self.height}, fx={self.fx:.1f}, fy={self.fy:.1f}, "
            f"c=({self.cu:.1f}, {self.cv:.1f}), source={np.round(self.source, 1).tolist()})"
        )


@dataclass(frozen=True)
class Rig:
    """A set of calibrated cameras sharing one lab frame (two for a biplane system).

    Read one from MayaCam files with :func:`core.geometry.rig_from_mayacam` (kept in
    :mod:`core.geometry.mayacam`, which builds on this module, not the other way round).
    """

    cameras: tuple[Camera, ...]

    def __post_init__(self) -> None:
        cams = tuple(self.cameras)
        if not cams or not all(isinstance(c, Camera) for c in cams):
            raise ValueError("cameras: expected a non-empty sequence of Camera objects")
        object.__setattr__(self, "cameras", cams)

    def __len__(self) -> int:
        return len(self.cameras)

    def __getitem__(self, i: int) -> Camera:
        return self.cameras[i]

    def __iter__(self):
        return iter(self.cameras)

    def project(self, X) -> np.ndarray:
        """``(n_cameras, ..., 2)`` pixel coordinates of lab points ``X (..., 3)`` in every view."""
        return np.stack([c.project(X) for c in self.cameras])

    def angle_between_views(self, i: int = 0, j: int = 1) -> float:
        """Angle (rad) between the principal rays of cameras ``i`` and ``j``."""
        a, b = self.cameras[i].principal_ray, self.cameras[j].principal_ray
        return float(np.arccos(np.clip(a @ b, -1.0, 1.0)))
