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


def _inside_field(cam: Camera, model: ImagingModel, X: np.ndarray, margin_px: float) -> np.ndarray:
    """Per candidate: all its lab points ``X (m, k, 3)`` project in front of the source, inside
    the image and the round field (after the view's distortion), ``margin_px`` clear of their
    borders; ``(m,)`` bool."""
    m, k = X.shape[:2]
    uv, depth = cam.project(X.reshape(-1, 3), return_depth=True)
    ok = np.all(depth.reshape(m, k) > 0, axis=1)
    if model.distortion is not None:
        with np.errstate(all="ignore"):  # points behind the source: refused above
            uv = model.distortion.forward(uv)
    lo, hi = margin_px - 0.5, np.array([cam.width, cam.height]) - 0.5 - margin_px
    ok &= ~np.any(((uv < lo) | (uv > hi)).reshape(m, -1), axis=1)
    if model.aperture_radius is not None:
        c = (model.distortion.center if model.distortion is not None
             else ((cam.width - 1) / 2, (cam.height - 1) / 2))
        r = model.aperture_radius * min(cam.width, cam.height) / 2 - margin_px
        ok &= ~np.any((np.hypot(uv[:, 0] - c[0], uv[:, 1] - c[1]) > r).reshape(m, k), axis=1)
    return ok


def _capture_centre(rig: Rig) -> np.ndarray:
    """Lab point (mm) closest to every principal ray: the middle of the capture volume."""
    A, b = np.zeros((3, 3)), np.zeros(3)
    for c in rig:
        P = np.eye(3) - np.outer(c.principal_ray, c.principal_ray)
        A += P
        b += P @ c.source
    return np.linalg.solve(A, b)


def _rotations(q: np.ndarray, qq: np.ndarray) -> np.ndarray:
    """``(m, 3, 3)`` rotations of the quaternions ``q (m, 4)`` (``qq``: their ``q·q``), uniform on
    SO(3) for normal ``q``."""
    w, x, y, z = (q / np.sqrt(qq)[:, None]).T
    R = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
                  2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
                  2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], axis=1)
    return R.reshape(-1, 3, 3)


def _tube_bottom(obj: CalibrationObject, T: np.ndarray) -> np.ndarray:
    """Lowest lab z (mm) of a tube body (or of the beads when the object has none) at the poses
    ``T (m, 4, 4)``."""
    if obj.body is None or obj.body[0] != "tube":
        return np.array([(obj.centers_lab(t)[:, 2] - obj.diameters / 2).min() for t in T])
    radius, half = obj.body[1], obj.body[2]
    az, tz = T[:, 2, 2], T[:, 2, 3]
    return np.minimum(tz + -half * az, tz + half * az) - radius * np.sqrt(np.maximum(0.0, 1 - az ** 2))


def _candidates(g: np.random.Generator, m: int, c0: np.ndarray, spread_mm: float) -> np.ndarray:
    """``m`` candidate poses ``(m, 4, 4)``, drawn one after the other from ``g`` (a random
    orientation, then a position in the cube of half-side ``spread_mm`` about ``c0``)."""
    q, qq, t = np.empty((m, 4)), np.empty(m), np.empty((m, 3))
    for i in range(m):
        q[i] = g.normal(size=4)
        qq[i] = q[i].dot(q[i])
        t[i] = g.uniform(-spread_mm, spread_mm, 3)
    T = np.zeros((m, 4, 4))
    T[:, :3, :3] = _rotations(q, qq)
    T[:, :3, 3] = c0 + t
    T[:, 3, 3] = 1.0
    return T


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
    kept: list[np.ndarray] = []
    want = int(pool) * int(n)
    tries = 0
    # candidates are drawn in batches and checked together; the generator is left where drawing
    # them one at a time, until enough were kept, would leave it
    while tries < int(max_tries) and len(kept) < want:
        m = min(512, int(max_tries) - tries)
        state = g.bit_generator.state
        T = _candidates(g, m, c0, spread_mm)
        ok = np.ones(m, bool) if floor_z_mm is None else ~(_tube_bottom(obj, T) < floor_z_mm + 2.0)
        X = obj.centers @ T[:, :3, :3].transpose(0, 2, 1) + T[:, None, :3, 3]
        for c, model in zip(cams, imaging, strict=True):
            ok &= _inside_field(c, model, X, margin_px)
        idx = np.flatnonzero(ok)[: want - len(kept)]
        kept.extend(T[idx])
        tries += m
        if len(kept) >= want and idx[-1] + 1 < m:  # draw again up to the last one kept only
            g.bit_generator.state = state
            _candidates(g, int(idx[-1]) + 1, c0, spread_mm)
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
