"""CT volumes in physical space and the explicit HU -> attenuation transfer.

Index convention (as in ITK/SimpleITK): ``data`` is indexed ``[k, j, i]`` (slice, row, column),
and the physical position (mm) of the centre of voxel ``(i, j, k)`` is::

    x = origin + direction @ (spacing * (i, j, k))

``direction`` holds the unit directions of the i, j and k axes in its *columns*. The volume's
box extends half a voxel beyond the outer voxel centres, i.e. over index coordinates
``[-0.5, n - 0.5]`` on each axis.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .._validate import as_float_array

__all__ = ["CTVolume", "HUTransfer"]


@dataclass(frozen=True, eq=False)
class CTVolume:
    """A scalar volume (HU unless ``units`` says otherwise) with its physical geometry.

    Parameters
    ----------
    data : (nz, ny, nx) array
        Voxel values indexed ``[k, j, i]``.
    spacing : (3,) array
        Voxel size along i, j, k in mm (all > 0).
    origin : (3,) array
        Physical position (mm) of the centre of voxel ``(0, 0, 0)``.
    direction : (3, 3) array
        Orthonormal matrix whose columns are the i, j, k axis directions.
    units : str
        ``"HU"`` for CT numbers, ``"1/mm"`` for linear attenuation.
    name : str
        Free label (e.g. ``"talus"``).
    """

    data: np.ndarray
    spacing: np.ndarray = field(default_factory=lambda: np.ones(3))
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    direction: np.ndarray = field(default_factory=lambda: np.eye(3))
    units: str = "HU"
    name: str = ""

    def __post_init__(self) -> None:
        data = np.asarray(self.data)
        if data.ndim != 3 or min(data.shape) < 1:
            raise ValueError(f"data: expected a non-empty 3-D array [k, j, i], got shape {data.shape}")
        if not (np.issubdtype(data.dtype, np.integer) or np.issubdtype(data.dtype, np.floating)):
            raise ValueError(f"data: expected an integer or floating dtype, got {data.dtype}")
        if np.issubdtype(data.dtype, np.floating) and not np.all(np.isfinite(data)):
            raise ValueError("data: contains NaN or infinite voxels")
        spacing = as_float_array(self.spacing, "spacing", shape=(3,))
        if np.any(spacing <= 0):
            raise ValueError(f"spacing: expected three positive voxel sizes in mm, got {spacing}")
        origin = as_float_array(self.origin, "origin", shape=(3,))
        direction = self._check_direction(self.direction)
        for nm, arr in (("spacing", spacing), ("origin", origin), ("direction", direction)):
            arr = np.array(arr, dtype=np.float64)
            arr.setflags(write=False)
            object.__setattr__(self, nm, arr)
        object.__setattr__(self, "data", data)

    @staticmethod
    def _check_direction(direction) -> np.ndarray:
        """Orthonormal; a mirrored (det -1) matrix is allowed, as some CT files have one."""
        D = as_float_array(direction, "direction", shape=(3, 3))
        if not np.allclose(D @ D.T, np.eye(3), atol=1e-6):
            raise ValueError("direction: expected an orthonormal 3x3 matrix (columns = i, j, k axes)")
        return D

    # ------------------------------------------------------------------ geometry
    @property
    def shape_ijk(self) -> tuple[int, int, int]:
        """Number of voxels along (i, j, k)."""
        nz, ny, nx = self.data.shape
        return (nx, ny, nz)

    @property
    def T_physical_from_index(self) -> np.ndarray:
        """4x4 affine mapping homogeneous (i, j, k, 1) to physical mm."""
        T = np.eye(4)
        T[:3, :3] = self.direction * self.spacing[None, :]
        T[:3, 3] = self.origin
        return T

    @property
    def T_index_from_physical(self) -> np.ndarray:
        T = np.eye(4)
        Dinv = self.direction.T / self.spacing[:, None]
        T[:3, :3] = Dinv
        T[:3, 3] = -Dinv @ self.origin
        return T

    def index_to_physical(self, ijk) -> np.ndarray:
        """Physical mm of (..., 3) continuous voxel indices (i, j, k)."""
        ijk = as_float_array(ijk, "ijk")
        return ijk @ (self.direction * self.spacing[None, :]).T + self.origin

    def physical_to_index(self, xyz) -> np.ndarray:
        """Continuous voxel indices (i, j, k) of (..., 3) physical points (mm)."""
        xyz = as_float_array(xyz, "xyz")
        T = self.T_index_from_physical
        return xyz @ T[:3, :3].T + T[:3, 3]

    def corners(self) -> np.ndarray:
        """(8, 3) physical corners of the volume box (half a voxel outside the outer centres)."""
        n = np.array(self.shape_ijk, dtype=float)
        c = np.array([[a, b, d] for a in (0, 1) for b in (0, 1) for d in (0, 1)], dtype=float)
        return self.index_to_physical(c * n - 0.5)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned physical bounding box ``(min xyz, max xyz)`` in mm."""
        c = self.corners()
        return c.min(axis=0), c.max(axis=0)

    @property
    def extent_mm(self) -> np.ndarray:
        return np.array(self.shape_ijk) * self.spacing

    # ------------------------------------------------------------------ content
    def bone_mask(self, threshold: float = 200.0) -> np.ndarray:
        """Boolean ``[k, j, i]`` mask of voxels at or above ``threshold`` (HU by default)."""
        return self.data >= threshold

    def centroid(self, threshold: float | None = 200.0) -> np.ndarray:
        """Physical centroid (mm) of the voxels at or above ``threshold`` (all voxels if None)."""
        if threshold is None:
            k, j, i = np.indices(self.data.shape).reshape(3, -1)
        else:
            k, j, i = np.nonzero(self.bone_mask(threshold))
            if k.size == 0:
                raise ValueError(
                    f"threshold: no voxel of {self.name or 'the volume'} is >= {threshold} "
                    f"(range {self.data.min()}..{self.data.max()})"
                )
        return self.index_to_physical(np.column_stack([i, j, k]).mean(axis=0))

    def crop(self, i: slice = slice(None), j: slice = slice(None), k: slice = slice(None)) -> CTVolume:
        """Sub-volume ``data[k, j, i]`` with the origin moved so physical positions are kept."""
        nx, ny, nz = self.shape_ijk
        starts = []
        for s, n, nm in ((i, nx, "i"), (j, ny, "j"), (k, nz, "k")):
            if s.step not in (None, 1):
                raise ValueError(f"{nm}: expected a contiguous slice (step 1), got {s}")
            a, b, _ = s.indices(n)
            if b <= a:
                raise ValueError(f"{nm}: slice {s} selects no voxel of an axis of length {n}")
            starts.append(a)
        sub = self.data[k, j, i]
        origin = self.index_to_physical(np.array(starts, dtype=float))
        return replace(self, data=np.ascontiguousarray(sub), origin=origin)

    def crop_to_mask(self, mask: np.ndarray | None = None, *, margin: int = 2,
                     threshold: float = 200.0) -> CTVolume:
        """Crop to the bounding box of ``mask`` (default: bone mask) plus ``margin`` voxels."""
        m = self.bone_mask(threshold) if mask is None else np.asarray(mask, dtype=bool)
        if m.shape != self.data.shape:
            raise ValueError(f"mask: expected shape {self.data.shape}, got {m.shape}")
        if not m.any():
            raise ValueError("mask: is empty, nothing to crop to")
        idx = np.nonzero(m)
        lo = [max(int(a.min()) - margin, 0) for a in idx]
        hi = [min(int(a.max()) + margin + 1, n) for a, n in zip(idx, m.shape, strict=True)]
        return self.crop(slice(lo[2], hi[2]), slice(lo[1], hi[1]), slice(lo[0], hi[0]))

    def to_attenuation(self, transfer: HUTransfer | None = None) -> CTVolume:
        """Linear attenuation volume (1/mm, float32) through ``transfer`` (default HUTransfer())."""
        if self.units != "HU":
            raise ValueError(f"units: expected a volume in HU to convert, this one is in {self.units}")
        tr = HUTransfer() if transfer is None else transfer
        return replace(self, data=tr(self.data), units="1/mm")


@dataclass(frozen=True)
class HUTransfer:
    """Explicit map from CT numbers (HU) to linear attenuation μ (1/mm) at the fluoroscope kV.

    The model, applied voxel by voxel:

    1. ``window``: clamp HU to ``[lo, hi]`` (metal streaks, air);
    2. ``threshold``: voxels below it get μ = 0 (keeps only bone in a bone DRR); ``None`` keeps all;
    3. linear μ: ``μ = mu_water * (1 + HU / 1000)`` for HU <= 0 and
       ``μ = mu_water * (1 + bone_slope * HU / 1000)`` for HU > 0 (the bilinear model: CT is
       acquired at ~120 kV, fluoroscopy at ~60 kV, where bone attenuates relatively more, thesis
       §6.1 / Fig. 6.3; ``bone_slope = 1`` is the plain linear model);
    4. ``curve``: optional ``(hu_points, mu_points)`` table replacing step 3 by piecewise-linear
       interpolation (a measured kV-mismatch curve);
    5. μ is clipped at 0 and returned as float32.

    ``mu_water`` defaults to 0.0206 /mm, water at an effective energy of ~60 keV.
    """

    mu_water: float = 0.0206
    threshold: float | None = None
    window: tuple[float, float] | None = (-1000.0, 3000.0)
    bone_slope: float = 1.0
    curve: tuple[tuple[float, ...], tuple[float, ...]] | None = None

    def __post_init__(self) -> None:
        if not (np.isfinite(self.mu_water) and self.mu_water > 0):
            raise ValueError(f"mu_water: expected a positive attenuation in 1/mm, got {self.mu_water}")
        if not (np.isfinite(self.bone_slope) and self.bone_slope > 0):
            raise ValueError(f"bone_slope: expected a positive factor, got {self.bone_slope}")
        if self.window is not None and not (self.window[0] < self.window[1]):
            raise ValueError(f"window: expected (lo, hi) with lo < hi, got {self.window}")
        if self.curve is not None:
            hu, mu = (np.asarray(a, dtype=float) for a in self.curve)
            if hu.ndim != 1 or hu.shape != mu.shape or hu.size < 2 or np.any(np.diff(hu) <= 0):
                raise ValueError("curve: expected two equal-length 1-D sequences, HU strictly increasing")

    def __call__(self, hu) -> np.ndarray:
        h = np.asarray(hu, dtype=np.float32)
        if self.window is not None:
            h = np.clip(h, self.window[0], self.window[1])
        if self.curve is not None:
            mu = np.interp(h, *[np.asarray(a, dtype=float) for a in self.curve]).astype(np.float32)
        else:
            slope = np.where(h > 0, np.float32(self.bone_slope), np.float32(1.0))
            mu = np.float32(self.mu_water) * (1.0 + slope * h / np.float32(1000.0))
        if self.threshold is not None:
            mu = np.where(np.asarray(hu) >= self.threshold, mu, 0.0)
        return np.maximum(mu, 0.0).astype(np.float32)
