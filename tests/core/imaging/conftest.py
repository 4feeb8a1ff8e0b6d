"""Ground truth for the image-correction tests, as fixtures (the suite imports with importlib).

The "thesis-like" intensifier: the foot rig's first camera (1024², 0.29 mm pixels) with the
realistic :meth:`ImagingModel.fluoroscope` chain (Poisson noise at ~430 quanta per pixel, MTF50
0.5 cycles/mm, 5 % veiling glare, roll-off to 0.65 at the edge, 3 DN read noise, 12 bits) and a
distortion with a 5th-order radial term and a strong S-twist growing as r⁴ (k1 = 0.04,
k2 = 0.06, 5° at the rim): 5.7 mm RMS uncorrected grid error (the lab's: 6.56 mm) and a
3rd-order polynomial left with ~0.4 mm residuals, as in thesis Table 3.1.
"""

from __future__ import annotations

import numpy as np
import pytest

from core.imaging.grid_detection import detect_grid_points
from core.imaging.grid_indexing import index_grid
from core.synthetic import (
    Distortion,
    ImagingModel,
    bead_lattice_frame,
    distortion_grid_frame,
    foot_rig,
)

#: lattice placements (offset mm, angle rad) on the intensifier face, inside the grid's field
LATTICE_PLACEMENTS = (((40.0, 40.0), 0.3), ((-40.0, 40.0), -0.2), ((0.0, -40.0), 0.5))


@pytest.fixture(scope="session")
def camera1024():
    return foot_rig(seed=0, pixels=1024)[0]


@pytest.fixture(scope="session")
def thesis_distortion(camera1024):
    return Distortion.for_camera(camera1024, k1=0.04, k2=0.06, twist_deg=5.0, twist_power=4.0,
                                 center_offset_px=(8.0, -6.0))


@pytest.fixture(scope="session")
def thesis_model(camera1024, thesis_distortion):
    return ImagingModel.fluoroscope(camera1024, rng=0, distortion=thesis_distortion)


@pytest.fixture(scope="session")
def grid_frame(camera1024, thesis_model):
    """One noisy 12-bit hole-grid frame (~250 holes, 15 mm pitch) and its ground truth."""
    return distortion_grid_frame(camera1024, thesis_model, rng=1)


@pytest.fixture(scope="session")
def lattice_points(camera1024, thesis_model):
    """Detected + indexed bead-lattice points ``[(uv, ij), ...]`` at several placements.

    ``gap_mm=0.6`` puts the lattice's mid-plane where the grid's is (3.6 mm from the detector),
    so both see the same magnification.
    """
    out = []
    for k, (off, ang) in enumerate(LATTICE_PLACEMENTS):
        fr = bead_lattice_frame(camera1024, thesis_model, rng=10 + k, offset_mm=off, angle_rad=ang,
                                gap_mm=0.6)
        pts = detect_grid_points(fr.image, feature_diameter_px=2.0 / camera1024.pixel_size,
                                 polarity="dark")
        gi = index_grid(pts.uv)
        out.append((gi.uv, gi.ij))
    return out


@pytest.fixture()
def similarity_residual():
    """``f(ij, uv) -> (m,)`` residuals of the best similarity ``(i, j) → (u, v)``, pixels."""

    def f(ij, uv):
        w = np.asarray(ij)[:, 0] + 1j * np.asarray(ij)[:, 1]
        z = np.asarray(uv)[:, 0] + 1j * np.asarray(uv)[:, 1]
        A = np.column_stack([w, np.ones_like(w)])
        c = np.linalg.lstsq(A, z, rcond=None)[0]
        return np.abs(A @ c - z)

    return f
