"""Synthetic calibration sequences for tests and studies (ground truth from :mod:`core.synthetic`).

* :func:`capture_poses`: poses of an object moved through the capture volume of a rig, the way
  thesis §5.4.1 recommends (the long axis near the plane of the two principal rays, spun about
  itself), keeping every bead inside both images.
* :func:`observe`: exact pinhole projections plus Gaussian localisation noise (px), optionally
  with beads dropped, as :class:`~core.calibration.bundle.ObjectFrame` objects.
* :func:`render`: the same poses rendered through the image chain with
  :func:`core.synthetic.object_frames` (distortion off: calibration runs on corrected images).

Pixels are ``(u, v) = (column, row)``, origin at the centre of the top-left pixel; mm.
"""

from __future__ import annotations

import numpy as np

from .._validate import positive
from ..calibration import _so3
from ..calibration.bundle import ObjectFrame
from ..calibration.objects import CalibrationTarget
from ..geometry.camera import Rig
from .calibration import CalibrationFrame, object_frames
from .imaging import ImagingModel

__all__ = ["capture_centre", "capture_poses", "observe", "render"]


def _gen(rng) -> np.random.Generator:
    return rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)


def capture_centre(rig: Rig) -> np.ndarray:
    """Lab point (mm) closest to all principal rays (where the cones intersect)."""
    A, b = np.zeros((3, 3)), np.zeros(3)
    for c in rig:
        d = c.principal_ray
        Pm = np.eye(3) - np.outer(d, d)
        A += Pm
        b += Pm @ c.source
    return np.linalg.solve(A, b)


def _axis_frame(rig: Rig) -> np.ndarray:
    """Rotation whose z is the in-plane direction most perpendicular to the first two rays."""
    d1, d2 = rig[0].principal_ray, rig[len(rig) - 1].principal_ray
    n = np.cross(d1, d2)
    n = n / np.linalg.norm(n) if np.linalg.norm(n) > 1e-9 else np.array([0.0, 0.0, 1.0])
    bis = d1 + d2
    z = np.cross(n, bis / np.linalg.norm(bis))
    return np.column_stack([n, np.cross(z, n), z])


def capture_poses(rig: Rig, target: CalibrationTarget, n: int, *, rng=0, spread_mm: float = 60.0,
                  axis_tilt_deg: float = 20.0, margin_px: float = 12.0, centre=None,
                  max_tries: int = 10000) -> np.ndarray:
    """``(n, 4, 4)`` poses ``T_lab_from_object`` filling the capture volume.

    Positions are uniform in a cube of half-side ``spread_mm`` about ``centre`` (default
    :func:`capture_centre`); the object's z axis (a spiral's long axis) points within
    ``axis_tilt_deg`` of the direction in the plane of the principal rays that is most
    perpendicular to both, with a uniform spin about it and a random sign. Poses whose beads
    come closer than ``margin_px`` to an image border in any view are redrawn.
    """
    if int(n) != n or n < 1:
        raise ValueError(f"n: expected a positive integer, got {n!r}")
    g = _gen(rng)
    spread = positive(spread_mm, "spread_mm")
    c0 = capture_centre(rig) if centre is None else np.asarray(centre, dtype=float)
    F = _axis_frame(rig)
    tilt = np.radians(float(axis_tilt_deg))
    out = []
    for _ in range(int(max_tries)):
        if len(out) == n:
            break
        cos_t = g.uniform(np.cos(tilt), 1.0)
        phi = g.uniform(0, 2 * np.pi)
        s = np.sqrt(1 - cos_t**2)
        z = F @ np.array([s * np.cos(phi), s * np.sin(phi), cos_t]) * g.choice([-1.0, 1.0])
        a = np.cross(z, [0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.cross(z, [1.0, 0.0, 0.0])
        x = a / np.linalg.norm(a)
        spin = g.uniform(0, 2 * np.pi)
        x = np.cos(spin) * x + np.sin(spin) * np.cross(z, x)
        R = np.column_stack([x, np.cross(z, x), z])
        T = _so3.rigid(R, c0 + g.uniform(-spread, spread, 3))
        X = target.centers_lab(T)
        ok = True
        for cam in rig:
            uv, depth = cam.project(X, return_depth=True)
            if np.any(depth <= 0) or np.any(uv < margin_px - 0.5) or np.any(
                    uv > np.array([cam.width, cam.height]) - 0.5 - margin_px):
                ok = False
                break
        if ok:
            out.append(T)
    if len(out) < n:
        raise ValueError(f"spread_mm: only {len(out)} of {n} poses keep the object inside both "
                         "images; reduce spread_mm or margin_px")
    return np.stack(out)


def observe(rig: Rig, target: CalibrationTarget, poses, *, noise_px: float = 0.05, rng=0,
            drop: int = 0) -> list[ObjectFrame]:
    """Exact projections of the beads at ``poses (F, 4, 4)`` plus isotropic Gaussian noise of
    ``noise_px`` per axis; ``drop`` beads per view and frame are removed at random (NaN)."""
    g = _gen(rng)
    if noise_px < 0:
        raise ValueError(f"noise_px: expected a standard deviation >= 0 px, got {noise_px!r}")
    out = []
    for T in np.asarray(poses, dtype=float).reshape(-1, 4, 4):
        uv = rig.project(target.centers_lab(T))
        uv = uv + g.normal(0.0, float(noise_px), uv.shape)
        for v in range(len(rig)):
            if drop:
                uv[v, g.choice(len(target), int(drop), replace=False)] = np.nan
        out.append(ObjectFrame(target.centers, uv))
    return out


def render(rig: Rig, target: CalibrationTarget, T_lab_from_object, *, rng=0, imaging=None,
           with_body: bool = True) -> CalibrationFrame:
    """One biplane frame of ``target`` at ``T_lab_from_object`` through the image chain.

    ``imaging`` defaults to :meth:`ImagingModel.fluoroscope` of each camera without distortion
    (quantum noise, blur, glare, roll-off, 12-bit camera).
    """
    g = _gen(rng)
    ims = imaging or [ImagingModel.fluoroscope(c, rng=g, distortion=None) for c in rig]
    return object_frames(rig, target.to_synthetic(with_body=with_body), T_lab_from_object, ims, rng=g)
