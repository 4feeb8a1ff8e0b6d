"""A seeded biplane fluoroscope rig shaped like a gait-walkway set-up.

Lab frame used by every :mod:`core.synthetic` scene
----------------------------------------------------
Right-handed, millimetres: ``x`` points in the walking direction, ``y`` to the subject's left,
``z`` up. The origin is the centre of the "foot volume" that both X-ray cones cover (roughly the
hindfoot/ankle of a right foot standing on the walkway); the walkway surface lies at
``z = FLOOR_Z_MM`` (85 mm below the origin).

Geometry (thesis §2.3; SEED_NOTES)
----------------------------------
Two disarticulated C-arms straddle a radiolucent walkway: the X-ray sources sit below the floor on
the subject's right (``-y``) and aim obliquely *upwards* through the floor plate; the 30 cm image
intensifiers stand above the walkway on the left (``+y``), one in front of and one behind the foot,
so the two beams cross the transverse plane of the foot at an oblique angle. Source-to-image
distances are 1.3–1.5 m (the stock 1 m of the C-arm is lengthened so a subject can walk between
source and intensifier) and the views are 60–120° apart. A 1024-pixel camera across the 300 mm
intensifier gives ≈0.29 mm pixels (the lab's Phantom v5.2 chain: 0.327 mm).

Each camera is a :class:`core.geometry.Camera` whose z-axis is the principal ray (source →
intensifier centre); image rows run "down", i.e. against the lab's up direction projected onto
the detector, up to a small random roll.
"""

from __future__ import annotations

import numpy as np

from .._validate import positive
from ..geometry.camera import Camera, Rig, make_K

__all__ = ["FLOOR_Z_MM", "foot_rig"]

#: Height (lab z, mm) of the walkway surface under the foot volume.
FLOOR_Z_MM = -85.0


def _range(value, name: str, lo: float = 0.0) -> tuple[float, float]:
    """A ``(low, high)`` pair from a scalar or a 2-sequence, both > ``lo``."""
    a = np.atleast_1d(np.asarray(value, dtype=float))
    if a.shape not in ((1,), (2,)) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: expected a number or a (low, high) pair, got {value!r}")
    lo_v, hi_v = float(a[0]), float(a[-1])
    if not (lo < lo_v <= hi_v):
        raise ValueError(f"{name}: expected {lo} < low <= high, got {value!r}")
    return lo_v, hi_v


def _rodrigues(axis: np.ndarray, angle: float) -> np.ndarray:
    a = axis / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def _camera_rotation(beam: np.ndarray, roll: float) -> np.ndarray:
    """Rows (x_cam, y_cam, z_cam) in lab coordinates: z along ``beam``, image rows against up."""
    z = beam / np.linalg.norm(beam)
    up = np.array([0.0, 0.0, 1.0])
    y = -(up - (up @ z) * z)
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    R = np.stack([x, y, z])
    return (_rodrigues(z, roll) @ R.T).T  # roll the image axes about the principal ray


def foot_rig(
    *,
    seed: int | np.random.Generator = 0,
    sid_mm=(1300.0, 1500.0),
    detector_mm: float = 300.0,
    pixels: int = 1024,
    angle_deg=(60.0, 120.0),
    elevation_deg=(20.0, 35.0),
    odd_mm=(380.0, 480.0),
    aim_mm=(0.0, 0.0, 0.0),
    aim_jitter_mm: float = 5.0,
    principal_offset_mm: float = 3.0,
    roll_deg: float = 3.0,
) -> Rig:
    """Two X-ray cameras looking obliquely up through a walkway at a foot near the lab origin.

    Every random quantity is drawn in millimetres/radians *before* the pixel size is applied, so
    two calls that differ only in ``pixels`` return the same physical geometry (same sources,
    rotations and detector planes) sampled by coarser or finer pixels.

    Parameters
    ----------
    seed : int or numpy.random.Generator
        Seed (or generator) for all the draws below.
    sid_mm : float or (float, float)
        Source-to-image distance, mm, drawn uniformly per camera (thesis §2.4.2: 1.3–1.5 m).
    detector_mm : float
        Side of the square detector field in mm (the 31 cm intensifier mode → 300 mm).
    pixels : int
        Image width = height in pixels; ``pixel_size = detector_mm / pixels``
        (1024 → 0.293 mm; 128 for fast tests, same geometry).
    angle_deg : float or (float, float)
        Angle between the two principal rays, degrees, drawn uniformly from the part of this
        range that the drawn elevations allow (views tilted up by ``e1, e2`` are at most
        ``180 - e1 - e2`` degrees apart); raises when no part is feasible.
    elevation_deg : float or (float, float)
        Upward tilt of each principal ray above the horizontal, degrees.
    odd_mm : float or (float, float)
        Object (aim point) to intensifier distance, mm: the clearance a walking subject needs.
        The magnification at the aim point is ``SID / (SID - ODD)`` (≈1.4).
    aim_mm : (3,) array
        Nominal lab point both principal rays aim at, mm.
    aim_jitter_mm : float
        Each ray aims at a point drawn uniformly within this radius of ``aim_mm`` (real rigs are
        aligned by eye), so the rays pass near, not through, one point.
    principal_offset_mm : float
        Largest offset of the principal point from the detector centre, mm (drawn in a disc).
    roll_deg : float
        Largest roll of each image about its principal ray, degrees (uniform ±).

    Returns
    -------
    Rig
        ``Rig((cam01, cam02))`` with ``pixel_size`` set; square pixels, zero skew.
    """
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    sid_r = _range(sid_mm, "sid_mm")
    ang_r = _range(angle_deg, "angle_deg")
    ele_r = _range(elevation_deg, "elevation_deg", lo=-90.0)
    odd_r = _range(odd_mm, "odd_mm")
    det = positive(detector_mm, "detector_mm")
    if int(pixels) != pixels or pixels < 8:
        raise ValueError(f"pixels: expected an integer >= 8, got {pixels!r}")
    pixels = int(pixels)
    aim = np.asarray(aim_mm, dtype=float)
    if aim.shape != (3,) or not np.all(np.isfinite(aim)):
        raise ValueError(f"aim_mm: expected a finite (3,) lab point, got {aim_mm!r}")
    if ang_r[1] >= 180.0:
        raise ValueError(f"angle_deg: expected angles below 180 degrees, got {angle_deg!r}")

    # ---- draws (all physical; independent of `pixels`)
    elev = np.radians(rng.uniform(*ele_r, size=2))
    max_angle = 180.0 - np.degrees(elev.sum())
    if ang_r[0] > max_angle + 1e-9:
        raise ValueError(
            f"angle_deg/elevation_deg: views tilted up by {np.degrees(elev).round(1).tolist()} deg "
            f"are at most {max_angle:.1f} deg apart (180 - e1 - e2), below angle_deg {angle_deg!r}; "
            "lower the elevations or the angle"
        )
    theta = np.radians(rng.uniform(ang_r[0], min(ang_r[1], max_angle)))
    sid = rng.uniform(*sid_r, size=2)
    odd = rng.uniform(*odd_r, size=2)
    jitter = rng.normal(size=(2, 3))
    jitter *= (aim_jitter_mm * rng.uniform(size=(2, 1)) ** (1 / 3)) / np.linalg.norm(
        jitter, axis=1, keepdims=True)
    off_r = principal_offset_mm * np.sqrt(rng.uniform(size=2))
    off_a = rng.uniform(0, 2 * np.pi, size=2)
    roll = np.radians(rng.uniform(-roll_deg, roll_deg, size=2))

    # azimuth split so that the principal rays are `theta` apart:
    # cos(theta) = cos e1 cos e2 cos(da) + sin e1 sin e2
    c = (np.cos(theta) - np.sin(elev[0]) * np.sin(elev[1])) / (np.cos(elev[0]) * np.cos(elev[1]))
    da = np.arccos(np.clip(c, -1.0, 1.0))
    azimuth = np.pi / 2 + np.array([-da / 2, da / 2])  # beams point towards +y, split front/back

    px = det / pixels
    cams = []
    for n in range(2):
        beam = np.array([
            np.cos(elev[n]) * np.cos(azimuth[n]),
            np.cos(elev[n]) * np.sin(azimuth[n]),
            np.sin(elev[n]),
        ])
        R = _camera_rotation(beam, roll[n])
        source = aim + jitter[n] - (sid[n] - odd[n]) * R[2]
        t = -R @ source
        f = sid[n] / px
        centre = (pixels - 1) / 2.0
        cu = centre + off_r[n] * np.cos(off_a[n]) / px
        cv = centre + off_r[n] * np.sin(off_a[n]) / px
        cams.append(Camera(make_K(f, f, cu, cv), R, t, pixels, pixels, px, f"cam{n + 1:02d}"))
    return Rig(tuple(cams))
