"""The thesis §4.3 test object: 21 steel beads on a 20 mm grid, flat on an intensifier.

Layout (the thesis gives counts, sizes and pitch — "21 (5 × 2 mm and 16 × 3 mm) stainless steel
beads … 20 mm grid … outer beads are 3 mm and inner beads are 2 mm"): a 5 × 5 grid of 20 mm
pitch whose outer ring holds the sixteen 3 mm beads and whose inner 3 × 3 holds five 2 mm beads
in an X (centre and the four inner corners). The beads sit in a 6 mm acrylic (PMMA, 1.19 g/cm³)
plate lying on the intensifier face.

Imaging follows the thesis set-up: 0.327 mm pixels, a source-to-image distance of 1400 mm
(1.3–1.5 m), and :meth:`core.synthetic.ImagingModel.fluoroscope` — quantum noise at the lab's
raw-frame dose, the measured MTF50 of 0.5 cycles/mm, veiling glare, roll-off, read noise and
12-bit quantisation — without spatial distortion (the thesis corrected it first, Chapter 3).
Frames are flatfield-corrected with the true flatfield (floats in [0, 1], beads dark). The
2 and 3 mm beads project to 6.1 and 9.2 px (radii 3.1 and 4.6 px); with the blur their
signatures are 9–12 px wide, as in the thesis.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.camera import Camera, make_K
from .analytic import attenuation_per_mm, bead_line_integrals, slab_line_integrals
from .calib_objects import face_frame
from .imaging import ImagingModel

__all__ = ["LatticeScene", "lattice_beads", "make_lattice_scene", "neighbour_pairs"]

PIXEL_MM = 0.327
SID_MM = 1400.0
PLATE_MM = 6.0


def lattice_beads(pitch_mm: float = 20.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bead layout in the plate frame: ``xy (21, 2)`` mm, ``diameters (21,)`` mm, grid ``(21, 2)``."""
    grid, dia = [], []
    for j in range(5):
        for i in range(5):
            outer = i in (0, 4) or j in (0, 4)
            inner_x = (i - 2) ** 2 + (j - 2) ** 2 in (0, 2)
            if outer or inner_x:
                grid.append((i, j))
                dia.append(3.0 if outer else 2.0)
    g = np.array(grid)
    return (g - 2) * float(pitch_mm), np.array(dia), g


def neighbour_pairs(grid: np.ndarray) -> np.ndarray:
    """``(n_pairs, 2)`` index pairs of beads that are grid neighbours (one pitch apart)."""
    d = np.abs(grid[:, None, :] - grid[None, :, :]).sum(axis=2)
    i, j = np.nonzero(np.triu(d == 1))
    return np.stack([i, j], axis=1)


@dataclass(frozen=True, eq=False)
class LatticeScene:
    """A rendered lattice set-up and its ground truth.

    Attributes
    ----------
    camera : Camera
    imaging : ImagingModel
    line_integral : (H, W) float32
        Effective line integrals of plate and beads.
    uv : (21, 2)
        True bead centres (pinhole projections), pixels.
    diameter_px : (21,)
        Projected bead diameters, pixels.
    diameters_mm : (21,)
    pairs : (n_pairs, 2)
        Neighbour pairs (nominal distance ``pitch_mm``).
    pitch_mm : float
    mm_per_px : float
        Scale in the beads' plane (pixel size × source-to-bead / source-to-image distance).
    """

    camera: Camera
    imaging: ImagingModel
    line_integral: np.ndarray
    uv: np.ndarray
    diameter_px: np.ndarray
    diameters_mm: np.ndarray
    pairs: np.ndarray
    pitch_mm: float
    mm_per_px: float

    def frames(self, n: int, rng) -> np.ndarray:
        """``(n, H, W)`` float32 flatfield-corrected noisy frames (independent noise)."""
        g = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        flat = self.imaging.flatfield(self.line_integral.shape)
        return np.stack([self.imaging.to_float(self.imaging.apply(self.line_integral, rng=g),
                                               flatfield=flat) for _ in range(int(n))])

    def expected(self) -> np.ndarray:
        """Noise-free flatfield-corrected frame (float64)."""
        m = self.imaging
        return (m.expected_dn(self.line_integral) - m.dark_dn) / (m.flatfield(self.line_integral.shape)
                                                                  - m.dark_dn)


def make_lattice_scene(*, fluence_per_mm2: float = 5000.0, offset_mm=(3.1, -2.3),
                       angle_deg: float = 4.0, size_px: int = 320, pitch_mm: float = 20.0,
                       seed: int = 0, blur: bool = True) -> LatticeScene:
    """Render the lattice (module docs) flat on the intensifier of a thesis-like camera.

    ``fluence_per_mm2`` is the detected quanta per mm² at full fluence (the dose;
    :meth:`ImagingModel.fluoroscope`); ``offset_mm``/``angle_deg`` place the plate so that the
    beads fall on varied sub-pixel positions; ``blur=False`` switches PSF and glare off.
    """
    if int(size_px) != size_px or size_px < 64:
        raise ValueError(f"size_px: expected an integer >= 64, got {size_px!r}")
    f = SID_MM / PIXEL_MM
    c = (size_px - 1) / 2.0
    cam = Camera(make_K(f, f, c, c), np.eye(3), np.array([0.0, 0.0, 0.0]), size_px, size_px,
                 pixel_size=PIXEL_MM, name="lattice")
    T = face_frame(cam, gap_mm=0.0, thickness_mm=PLATE_MM, offset_mm=offset_mm,
                   angle_rad=np.radians(angle_deg))
    xy, dia, grid = lattice_beads(pitch_mm)
    pts = np.column_stack([xy, np.zeros(len(xy))]) @ T[:3, :3].T + T[:3, 3]
    mu_pmma = attenuation_per_mm("water", density=1.19)
    L = slab_line_integrals(cam, T[:3, 3], T[:3, 2], PLATE_MM, mu_pmma).astype(np.float64)
    L += bead_line_integrals(cam, pts, dia, attenuation_per_mm("steel") - mu_pmma, average="fluence")
    model = ImagingModel.fluoroscope(cam, rng=seed, fluence_per_mm2=fluence_per_mm2, distortion=None)
    if not blur:
        model = ImagingModel(photons_per_pixel=model.photons_per_pixel, rolloff_edge=model.rolloff_edge,
                             read_noise_dn=model.read_noise_dn)
    depth = float(T[2, 3])  # source at the origin looking along +z
    mm_per_px = PIXEL_MM * depth / cam.sid
    return LatticeScene(cam, model, L.astype(np.float32), cam.project(pts), dia / mm_per_px, dia,
                        neighbour_pairs(grid), float(pitch_mm), mm_per_px)
