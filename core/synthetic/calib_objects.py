"""Calibration hardware of a biplane fluoroscope, as exact geometry (thesis §3.4–3.5, §5.3).

Objects carry bead centres and diameters in their own frame (mm) and a homogeneous body; face
plates (distortion grid, bead lattice, pinhole bar) are placed on an intensifier with
:func:`face_frame`. Rendering lives in :mod:`core.synthetic.calibration`.

Assumed layouts (the thesis gives counts, sizes and materials, not drawings)
----------------------------------------------------------------------------
* **Cube** and **spirals** (§5.3.1–5.3.2): :mod:`core.calibration.hardware` (the library's
  definitions, re-exported here).
* **Distortion grid** (§3.5.2): a 3.2 mm (1/8 in) aluminium plate with 3.0 mm holes at 15 mm
  pitch on the intensifier face — holes inside the round field (≈300 for a 300 mm field, of which
  the lab detects ~250).
* **Bead lattice** (§3.5.2): 2.0 mm steel beads at 20 mm pitch, 6 × 6, in a 6 mm PMMA plate:
  inter-marker distances 20–100 mm and right angles.
* **Pinhole bar** (§3.4.2): 5 mm lead with 0.3 mm holes (smaller than a 0.29–0.33 mm pixel).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_float_array, positive
from ..calibration.hardware import (
    CUBE_DIAMETERS_MM,
    CalibrationObject,
    calibration_cube,
    helical_spiral,
    helix_frame_from_beads,
)
from ..geometry.camera import Camera
from ..render.attenuation import attenuation_per_mm

__all__ = [
    "CUBE_DIAMETERS_MM",
    "CalibrationObject",
    "FacePlate",
    "bead_lattice",
    "calibration_cube",
    "distortion_grid",
    "face_frame",
    "helical_spiral",
    "helix_frame_from_beads",
    "pinhole_bar",
]


def _rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


# ---------------------------------------------------------------------------- face plates
@dataclass(frozen=True, eq=False)
class FacePlate:
    """A plate lying on an intensifier face, in its own frame (z = plate normal, mm).

    ``holes``/``beads`` are (n, 2) positions in the plate plane; ``thickness`` and ``mu`` are
    the plate's (mm, 1/mm); holes have ``hole_diameter``; beads ``bead_diameter``/``bead_mu``.
    """

    name: str
    thickness: float
    mu: float
    holes: np.ndarray | None = None
    hole_diameter: float = 0.0
    beads: np.ndarray | None = None
    bead_diameter: float = 0.0
    bead_mu: float = 0.0

    @property
    def points(self) -> np.ndarray:
        """(n, 3) feature centres (holes or beads) on the plate's mid-plane, plate frame."""
        xy = self.holes if self.holes is not None else self.beads
        return np.column_stack([xy, np.zeros(len(xy))])


def distortion_grid(*, pitch_mm: float = 15.0, field_diameter_mm: float = 300.0,
                    hole_diameter_mm: float = 3.0, thickness_mm: float = 3.2,
                    energy_kev: float = 60.0) -> FacePlate:
    """Aluminium hole grid: holes at ``pitch_mm`` within the round field (1 pitch margin)."""
    pitch = positive(pitch_mm, "pitch_mm")
    R = positive(field_diameter_mm, "field_diameter_mm") / 2 - pitch
    k = np.arange(-int(R // pitch), int(R // pitch) + 1) * pitch
    g = np.stack(np.meshgrid(k, k), -1).reshape(-1, 2)
    holes = g[np.hypot(*g.T) <= R]
    return FacePlate("distortion_grid", positive(thickness_mm, "thickness_mm"),
                     attenuation_per_mm("aluminium", energy_kev), holes=holes,
                     hole_diameter=positive(hole_diameter_mm, "hole_diameter_mm"))


def bead_lattice(*, pitch_mm: float = 20.0, shape=(6, 6), bead_diameter_mm: float = 2.0,
                 thickness_mm: float = 6.0, energy_kev: float = 60.0) -> FacePlate:
    """Steel-bead lattice in PMMA (1.19 g/cm³): ``shape`` = (columns, rows), centred."""
    nx, ny = (int(a) for a in shape)
    pitch = positive(pitch_mm, "pitch_mm")
    x = (np.arange(nx) - (nx - 1) / 2) * pitch
    y = (np.arange(ny) - (ny - 1) / 2) * pitch
    beads = np.stack(np.meshgrid(x, y), -1).reshape(-1, 2)
    return FacePlate("bead_lattice", positive(thickness_mm, "thickness_mm"),
                     attenuation_per_mm("water", energy_kev, density=1.19), beads=beads,
                     bead_diameter=positive(bead_diameter_mm, "bead_diameter_mm"),
                     bead_mu=attenuation_per_mm("steel", energy_kev))


def pinhole_bar(*, positions_mm=None, hole_diameter_mm: float = 0.3, thickness_mm: float = 5.0,
                energy_kev: float = 60.0) -> FacePlate:
    """Lead bar with pinholes; default 7 holes 10 mm apart along x through the centre."""
    pos = (np.column_stack([np.arange(-3, 4) * 10.0, np.zeros(7)]) if positions_mm is None
           else as_float_array(positions_mm, "positions_mm", shape=(None, 2)))
    return FacePlate("pinhole_bar", positive(thickness_mm, "thickness_mm"),
                     attenuation_per_mm("lead", energy_kev), holes=pos,
                     hole_diameter=positive(hole_diameter_mm, "hole_diameter_mm"))


def face_frame(camera: Camera, *, gap_mm: float = 0.0, thickness_mm: float = 0.0,
               offset_mm=(0.0, 0.0), angle_rad: float = 0.0) -> np.ndarray:
    """``T_lab_from_plate`` of a plate lying on ``camera``'s intensifier face.

    The plate's mid-plane is perpendicular to the principal ray, ``gap_mm + thickness_mm / 2``
    in front of the detector plane (towards the source); its x/y axes follow the image's u/v
    directions, rotated by ``angle_rad`` and shifted by ``offset_mm`` in the plane.
    """
    dist = camera.sid - gap_mm - thickness_mm / 2
    R = camera.R.T @ _rot_z(angle_rad)  # columns: plate axes in the lab
    T = np.eye(4)
    T[:3, :3] = R
    off = np.asarray(offset_mm, dtype=float)
    T[:3, 3] = camera.source + dist * camera.principal_ray + camera.R.T @ np.array([off[0], off[1], 0.0])
    return T
