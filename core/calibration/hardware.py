"""Calibration hardware as exact geometry: the built-in objects and the helix frame (thesis §5.3).

A :class:`CalibrationObject` holds bead centres and diameters in the object's own frame (mm),
the beads' attenuation and the homogeneous body around them — what a forward model needs to
render the object. :mod:`core.calibration.objects` builds its :class:`CalibrationTarget`
built-ins from these; the synthetic generator (:mod:`core.synthetic`) renders them.

Assumed layouts (the thesis gives counts, sizes and materials, not drawings)
----------------------------------------------------------------------------
* **Cube** (§5.3.1): a 100 mm block of R1/BB Butter-Board tooling resin (modelled as
  water-equivalent at 0.8 g/cm³) with three planar groups of five steel beads — 1.78, 3.17 and
  4.76 mm — in planes ``z = -30, 0, +30`` mm of the cube frame (origin at the block centre).
  Each group is a "die five" (square of side 2·s plus an off-centre fifth bead) with
  ``s = 35, 30, 25`` mm and rotated 0°, 30°, 60° about z, so no two beads line up with the cube
  edges and the pattern has no symmetry.
* **Spirals** (§5.3.2, after Rougée et al.): 23 or 33 stainless beads alternating 3.0/5.0 mm
  on a helix in cast polyurethane foam (0.3 g/cm³) inside a polycarbonate tube (1.2 g/cm³, 3 mm
  wall). Small: radius 30 mm, 3 turns, 40 mm pitch (120 mm long); large: radius 45 mm, 4 turns,
  40 mm pitch (160 mm). Local frame (thesis): z along the helix axis from the first to the last
  bead, x from the axis towards the first bead, origin on the axis half-way between the end
  beads (:func:`helix_frame_from_beads`). With an odd count, strict alternation starts and ends
  on the same size, so the object is symmetric under a half-turn: pass ``diameters`` to break it.

Attenuation: :func:`core.render.attenuation.attenuation_per_mm` (60 keV by default).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from .._validate import as_float_array, as_points, positive
from ..render.attenuation import attenuation_per_mm

__all__ = [
    "CUBE_DIAMETERS_MM",
    "CalibrationObject",
    "calibration_cube",
    "helical_spiral",
    "helix_frame_from_beads",
]

CUBE_DIAMETERS_MM = (1.78, 3.17, 4.76)


@dataclass(frozen=True, eq=False)
class CalibrationObject:
    """Beads (object frame, mm) in a homogeneous body.

    ``body`` is ``("box", (hx, hy, hz), mu)`` or ``("tube", radius, half_length, mu_core,
    wall_mm, mu_wall)`` (cylinder along z), μ in 1/mm; ``bead_mu`` in 1/mm.
    """

    name: str
    centers: np.ndarray
    diameters: np.ndarray
    bead_mu: float
    body: tuple | None = None

    def __post_init__(self) -> None:
        c, _ = as_points(self.centers, "centers", 3)
        d = np.broadcast_to(as_float_array(self.diameters, "diameters"), (len(c),)).astype(float)
        if np.any(d <= 0):
            raise ValueError("diameters: expected positive bead diameters in mm")
        object.__setattr__(self, "centers", c)
        object.__setattr__(self, "diameters", d)

    def __len__(self) -> int:
        return len(self.centers)

    def centers_lab(self, T_lab_from_object) -> np.ndarray:
        """Bead centres in the lab (mm) for the object pose ``T_lab_from_object`` (4x4)."""
        T = as_float_array(T_lab_from_object, "T_lab_from_object", shape=(4, 4))
        return self.centers @ T[:3, :3].T + T[:3, 3]


def _rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def calibration_cube(*, energy_kev: float = 60.0, size_mm: float = 100.0,
                     resin_density: float = 0.8) -> CalibrationObject:
    """The lab's old 15-bead cube (layout assumed as in the module docs)."""
    pts, dia = [], []
    for z, d, s, ang in zip((-30.0, 0.0, 30.0), CUBE_DIAMETERS_MM, (35.0, 30.0, 25.0),
                            np.radians([0.0, 30.0, 60.0]), strict=True):
        die = np.array([[-s, -s, 0], [s, -s, 0], [s, s, 0], [-s, s, 0], [0.3 * s, 0.15 * s, 0]])
        pts.append(die @ _rot_z(ang).T + [0, 0, z])
        dia += [d] * 5
    mu_resin = attenuation_per_mm("water", energy_kev, density=resin_density)
    h = positive(size_mm, "size_mm") / 2
    return CalibrationObject("cube15", np.concatenate(pts), np.array(dia),
                             attenuation_per_mm("steel", energy_kev), ("box", (h, h, h), mu_resin))


def helical_spiral(
    n_beads: int = 23,
    *,
    radius_mm: float | None = None,
    pitch_mm: float = 40.0,
    turns: float | None = None,
    diameters=None,
    energy_kev: float = 60.0,
) -> CalibrationObject:
    """A helical spiral calibration object (thesis §5.3.2).

    Parameters
    ----------
    n_beads : int
        23 (small object) or 33 (large); other counts need ``radius_mm`` and ``turns``.
    radius_mm, pitch_mm, turns : float
        Helix radius, axial advance per turn and number of turns from first to last bead.
    diameters : sequence, optional
        Bead diameters (mm) in order along the helix; default alternating 3.0, 5.0, 3.0, …
    energy_kev : float
        Effective energy for the steel, foam and polycarbonate attenuation.
    """
    presets = {23: (30.0, 3.0), 33: (45.0, 4.0)}
    if int(n_beads) != n_beads or n_beads < 4:
        raise ValueError(f"n_beads: expected an integer >= 4, got {n_beads!r}")
    n = int(n_beads)
    if radius_mm is None or turns is None:
        if n not in presets:
            raise ValueError(f"radius_mm, turns: needed for {n} beads (presets exist for 23 and 33)")
        radius_mm = presets[n][0] if radius_mm is None else radius_mm
        turns = presets[n][1] if turns is None else turns
    r, p, tn = positive(radius_mm, "radius_mm"), positive(pitch_mm, "pitch_mm"), positive(turns, "turns")
    th = 2 * np.pi * tn * np.arange(n) / (n - 1)
    z = p * th / (2 * np.pi)
    z -= z.mean()
    centers = np.column_stack([r * np.cos(th), r * np.sin(th), z])
    dia = np.resize([3.0, 5.0], n) if diameters is None else np.asarray(diameters, dtype=float)
    if dia.shape != (n,):
        raise ValueError(f"diameters: expected {n} values, got shape {dia.shape}")
    half_len = (z.max() - z.min()) / 2 + 15.0
    core_r = r + 8.0
    body = ("tube", core_r + 3.0, half_len,
            attenuation_per_mm("water", energy_kev, density=0.3), 3.0,
            attenuation_per_mm("water", energy_kev, density=1.2))
    return CalibrationObject(f"spiral{n}", centers, dia, attenuation_per_mm("steel", energy_kev), body)


def helix_frame_from_beads(centers) -> np.ndarray:
    """``T_lab_from_object`` recovered from lab bead centres of a helix (thesis §5.3.2).

    The helix axis is the line whose distance to every bead is the same (a cylinder fit by
    least squares, started from the principal axis of the bead cloud). z runs along the axis
    from the first towards the last bead, x from the axis towards the first bead, and the origin
    is the axis point half-way between the end beads' projections onto it. Exact (to solver
    precision) for an ideal helix.
    """
    P, _ = as_points(centers, "centers", 3)
    m = P.mean(axis=0)
    _, _, vt = np.linalg.svd(P - m)
    z0 = vt[0] * np.sign(vt[0] @ (P[-1] - P[0]))
    e1, e2 = vt[1], np.cross(z0, vt[1])

    def axis(q):
        z = z0 + q[0] * e1 + q[1] * e2
        return m + q[2] * e1 + q[3] * e2, z / np.linalg.norm(z)

    def resid(q):
        c, z = axis(q)
        w = P - c
        return np.linalg.norm(w - np.outer(w @ z, z), axis=1) - q[4]

    r0 = np.linalg.norm((P - m) - np.outer((P - m) @ z0, z0), axis=1).mean()
    sol = least_squares(resid, [0.0, 0.0, 0.0, 0.0, r0], xtol=1e-15, ftol=1e-15, gtol=1e-15)
    c, z = axis(sol.x)
    s = (P - c) @ z
    origin = c + z * (s[0] + s[-1]) / 2
    x = (P[0] - origin) - ((P[0] - origin) @ z) * z
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = origin
    return T
