"""The scene of a synthetic calibration session (:mod:`core.synthetic.session`): the demo rig's
image chains and walkway built without bones, and the poses of the hand-held spiral moved
through the capture volume (inside both round X-ray fields, above the walkway, spread by
farthest-point sampling)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..geometry.camera import Camera, Rig
from .analytic import attenuation_per_mm
from .calib_objects import CalibrationObject, helical_spiral
from .imaging import ImagingModel
from .rig import FLOOR_Z_MM, foot_rig

__all__ = ["spiral_poses"]


def _default_setup(pixels: int, seed: int, energy_kev: float):
    """The rig, image chains and walkway of ``make_foot_scene(pixels=pixels, seed=seed)``
    (same sub-seeds) without building its bones."""
    ss = np.random.SeedSequence(int(seed)).spawn(4)
    g_rig, g_img = np.random.default_rng(ss[0]), np.random.default_rng(ss[3])
    rig = foot_rig(seed=g_rig, pixels=pixels)
    models = tuple(ImagingModel.fluoroscope(c, rng=g_img, aperture_radius=1.0) for c in rig)
    floor = (FLOOR_Z_MM, 5.0, attenuation_per_mm("carbon", energy_kev))
    return rig, models, floor


def _inside_field(cam: Camera, model: ImagingModel, X: np.ndarray, margin_px: float) -> bool:
    """All lab points ``X`` project in front of the source, inside the image and the round field
    (after the view's distortion), ``margin_px`` clear of their borders."""
    uv, depth = cam.project(X, return_depth=True)
    if np.any(depth <= 0):
        return False
    if model.distortion is not None:
        uv = model.distortion.forward(uv)
    lo, hi = margin_px - 0.5, np.array([cam.width, cam.height]) - 0.5 - margin_px
    if np.any(uv < lo) or np.any(uv > hi):
        return False
    if model.aperture_radius is not None:
        c = (model.distortion.center if model.distortion is not None
             else ((cam.width - 1) / 2, (cam.height - 1) / 2))
        r = model.aperture_radius * min(cam.width, cam.height) / 2 - margin_px
        if np.any(np.hypot(uv[:, 0] - c[0], uv[:, 1] - c[1]) > r):
            return False
    return True


def _capture_centre(rig: Rig) -> np.ndarray:
    """Lab point (mm) closest to every principal ray: the middle of the capture volume."""
    A, b = np.zeros((3, 3)), np.zeros(3)
    for c in rig:
        P = np.eye(3) - np.outer(c.principal_ray, c.principal_ray)
        A += P
        b += P @ c.source
    return np.linalg.solve(A, b)


def _random_rotation(g: np.random.Generator) -> np.ndarray:
    q = g.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def _tube_bottom(obj: CalibrationObject, T: np.ndarray) -> float:
    """Lowest lab z (mm) of a tube body (or of the beads when the object has none)."""
    if obj.body is None or obj.body[0] != "tube":
        return float((obj.centers_lab(T)[:, 2] - obj.diameters / 2).min())
    radius, half = obj.body[1], obj.body[2]
    a = T[:3, 2]
    ends = T[:3, 3][None] + np.outer([-half, half], a)
    return float(ends[:, 2].min() - radius * np.sqrt(max(0.0, 1 - a[2] ** 2)))


def spiral_poses(rig: Rig, imaging: Sequence[ImagingModel], n: int, *, obj: CalibrationObject | None = None,
                 rng=0, floor_z_mm: float | None = FLOOR_Z_MM, spread_mm: float = 50.0,
                 margin_px: float | None = None, pool: int = 10, max_tries: int = 200_000) -> np.ndarray:
    """``(n, 4, 4)`` poses ``T_lab_from_object`` of a hand-held object moved through the capture
    volume (the part of the lab both round X-ray fields see).

    Candidates: a position uniform in a cube of half-side ``spread_mm`` about the point closest
    to both principal rays and a uniformly random orientation; a candidate is kept when every
    bead lies inside both images and round fields (``margin_px`` clear, default one large bead
    diameter in pixels) and the object's body stays above the walkway (``floor_z_mm``; None = no
    walkway). From ``pool × n`` kept candidates, ``n`` are chosen by farthest-point sampling on
    their bead clouds (centre and orientation together), so the poses spread over the whole
    volume and over orientations.
    """
    if int(n) != n or n < 1:
        raise ValueError(f"n: expected a positive integer, got {n!r}")
    obj = obj or helical_spiral(33)
    g = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    cams = tuple(rig)
    c0 = _capture_centre(rig)
    if margin_px is None:
        margin_px = float(obj.diameters.max()) / min(c.pixel_size for c in cams) + 2.0
    kept = []
    want = int(pool) * int(n)
    for _ in range(int(max_tries)):
        if len(kept) >= want:
            break
        T = np.eye(4)
        T[:3, :3] = _random_rotation(g)
        T[:3, 3] = c0 + g.uniform(-spread_mm, spread_mm, 3)
        if floor_z_mm is not None and _tube_bottom(obj, T) < floor_z_mm + 2.0:
            continue
        X = obj.centers_lab(T)
        if all(_inside_field(c, m, X, margin_px) for c, m in zip(cams, imaging, strict=True)):
            kept.append(T)
    if len(kept) < n:
        raise ValueError(f"n: only {len(kept)} of {n} poses of {obj.name} fit inside both fields "
                         f"after {max_tries} tries; lower n or margin_px")
    clouds = np.stack([obj.centers_lab(T) for T in kept]).reshape(len(kept), -1)
    chosen = [int(np.argmin(np.linalg.norm(np.stack([T[:3, 3] for T in kept]) - c0, axis=1)))]
    d = np.linalg.norm(clouds - clouds[chosen[0]], axis=1)
    for _ in range(int(n) - 1):
        k = int(np.argmax(d))
        chosen.append(k)
        d = np.minimum(d, np.linalg.norm(clouds - clouds[k], axis=1))
    return np.stack([kept[k] for k in chosen])
