"""Distortion calibration from a grid image: detect → index → ideal grid → fit (thesis §3.5).

The ideal grid
--------------
A flat grid on the intensifier face projects, without distortion, to a similarity transform of
its lattice: ``ideal = c + s R(θ) (i, j)``. Near the intensifier axis the distortion is close to
the identity, so :func:`ideal_grid` fits that similarity to the indexed points within
``central_cells`` cells of the point nearest ``center_uv`` (default the image centre). The
corrected image then overlays the raw one at the centre and has the grid's central pixel
size, ``mm_per_px = pitch_mm / s``, everywhere. Which central region is used only sets that
reference; distances in millimetres (``ideal × mm_per_px``) do not depend on it.

Sub-modules: :mod:`~core.imaging.grid_detection`, :mod:`~core.imaging.grid_indexing`,
:mod:`~core.imaging.distortion_models` (models and :class:`~.ModelSpec`),
:mod:`~core.imaging.distortion_maps` (dense remap, :func:`~.undistort_image`) and
:mod:`~core.imaging.distortion_eval` (residual tables, bead-lattice errors, cross-validation,
the condition-number sweep of Fig. 3.11).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_float_array, positive
from .distortion_eval import ResidualStats, residual_stats
from .distortion_maps import remap_tables, undistort_image
from .distortion_models import DistortionModel, ModelSpec, fit_distortion
from .grid_detection import GridPoints, detect_grid_points
from .grid_indexing import GridIndex, index_grid

__all__ = [
    "DistortionCalibration",
    "DistortionModel",
    "IdealGrid",
    "ModelSpec",
    "calibrate_distortion",
    "detect_grid_points",
    "fit_distortion",
    "ideal_grid",
    "index_grid",
    "remap_tables",
    "undistort_image",
]


@dataclass(frozen=True, eq=False)
class IdealGrid:
    """Ideal (undistorted) pixel positions of indexed grid points.

    Attributes
    ----------
    ideal_uv : (m, 2) float64   ideal positions, pixels
    distorted_uv : (m, 2) float64   detected positions of the same points, pixels
    ij : (m, 2) int
    mm_per_px : float   ideal pixel size in the grid plane, mm
    step_px : float     lattice step ``s`` in ideal pixels
    angle_rad : float   lattice rotation ``θ`` of the i axis from +u
    origin_uv : (2,)    ideal position of cell (0, 0)
    """

    ideal_uv: np.ndarray
    distorted_uv: np.ndarray
    ij: np.ndarray
    mm_per_px: float
    step_px: float
    angle_rad: float
    origin_uv: np.ndarray


def ideal_grid(index: GridIndex, *, pitch_mm: float, center_uv=None, central_cells: int = 2,
               image_shape=None) -> IdealGrid:
    """Ideal grid positions from the central region of an indexed grid (see module docs).

    Parameters
    ----------
    index : GridIndex
    pitch_mm : float
        Grid pitch on the plate (thesis: 15 mm).
    center_uv : (2,), optional
        Reference centre (default: the centre of ``image_shape``, else the points' centroid).
    central_cells : int
        Chebyshev cell radius of the central block the similarity is fitted to (>= 1).
    image_shape : (H, W), optional
    """
    pitch = positive(pitch_mm, "pitch_mm")
    if int(central_cells) != central_cells or central_cells < 1:
        raise ValueError(f"central_cells: expected an integer >= 1, got {central_cells!r}")
    if center_uv is not None:
        c = as_float_array(center_uv, "center_uv", shape=(2,))
    elif image_shape is not None:
        c = np.array([(image_shape[1] - 1) / 2, (image_shape[0] - 1) / 2])
    else:
        c = index.uv.mean(axis=0)
    k0 = int(np.argmin(np.linalg.norm(index.uv - c, axis=1)))
    near = np.max(np.abs(index.ij - index.ij[k0]), axis=1) <= central_cells
    if near.sum() < 4:
        raise ValueError(f"index: only {int(near.sum())} points within {central_cells} cells of the "
                         f"centre; the similarity needs at least 4 (increase central_cells)")
    w = index.ij[near, 0] + 1j * index.ij[near, 1]
    z = index.uv[near, 0] + 1j * index.uv[near, 1]
    A = np.column_stack([w, np.ones_like(w)])
    a, b = np.linalg.lstsq(A, z, rcond=None)[0]
    zi = a * (index.ij[:, 0] + 1j * index.ij[:, 1]) + b
    ideal = np.column_stack([zi.real, zi.imag])
    s = float(abs(a))
    return IdealGrid(ideal, index.uv.copy(), index.ij.copy(), pitch / s, s, float(np.angle(a)),
                     np.array([b.real, b.imag]))


@dataclass(frozen=True, eq=False)
class DistortionCalibration:
    """Everything a grid calibration produced: points, indices, ideal grid, model, residuals."""

    points: GridPoints
    index: GridIndex
    grid: IdealGrid
    model: DistortionModel
    residuals: ResidualStats

    def summary(self) -> dict:
        """JSON-ready summary (counts, polarity, model, residuals in px and mm)."""
        return {"detected": len(self.points), "indexed": len(self.index),
                "unassigned": len(self.index.unassigned), "polarity": self.points.polarity,
                "pitch_px": self.index.pitch_px, "mm_per_px": self.grid.mm_per_px,
                "model": self.model.label, "rank": self.model.rank, "condition": self.model.condition,
                "residuals": self.residuals.to_dict()}


def calibrate_distortion(image, *, pitch_mm: float = 15.0, feature_diameter_px: float,
                         model: str | ModelSpec = "poly(8,8)", polarity: str = "auto",
                         center_uv=None, detect_options: dict | None = None,
                         index_options: dict | None = None) -> DistortionCalibration:
    """Calibrate the distortion of one view from a grid image (or a stack of grid frames).

    Parameters
    ----------
    image : (H, W) or (n, H, W) array_like
        Grid frame(s); a stack is averaged.
    pitch_mm : float
        Grid pitch (mm).
    feature_diameter_px : float
        Hole/bead diameter in the image (pixels).
    model : str or ModelSpec
        Model to fit (e.g. ``"poly(8,8)"``, the thesis recommendation of order >= 8).
    polarity : {"auto", "bright", "dark"}
        Bright holes or dark beads (see :func:`detect_grid_points`).
    center_uv : (2,), optional
        Reference centre of the ideal grid (default: the image centre).
    detect_options, index_options : dict, optional
        Extra keyword options of :func:`detect_grid_points` and :func:`index_grid`.
    """
    pts = detect_grid_points(image, feature_diameter_px=feature_diameter_px, polarity=polarity,
                             **(detect_options or {}))
    shape = np.asarray(image).shape[-2:]
    c = np.array([(shape[1] - 1) / 2, (shape[0] - 1) / 2]) if center_uv is None else center_uv
    idx = index_grid(pts.uv, origin_uv=c, **(index_options or {}))
    grid = ideal_grid(idx, pitch_mm=pitch_mm, center_uv=c)
    m = fit_distortion(grid.ideal_uv, grid.distorted_uv, model, mm_per_px=grid.mm_per_px)
    return DistortionCalibration(pts, idx, grid, m, residual_stats(m, grid.distorted_uv, grid.ideal_uv))
