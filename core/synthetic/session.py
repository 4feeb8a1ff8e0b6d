"""Write a calibration session as a lab records it on a collection day (synthetic, with truth).

Layout of the session folder (read it with :func:`core.io.read_session`)::

    session.json                 manifest: format, version, cameras, bit_depth, frame_size [H, W],
                                 groups (folder of each group, one flat folder per kV), kv,
                                 the grid and lattice plates, the objects' names, n_frames, notes
    <cam>/dark/0000.tif ...      X-rays off: the camera's dark level and read noise
    <cam>/flat_<kV>kV/*.tif      empty field (nothing in the beam), one folder per kV
    <cam>/grid/*.tif             hole grid lying on the intensifier face, one static placement
    <cam>/lattice/*.tif          bead lattice on the intensifier face, one placement per frame
                                 (an independent check of the distortion correction)
    <cam>/cube/0000.tif          the 15-bead cube, static; it defines the lab frame
    <cam>/spiral/0000.tif ...    the 33-bead spiral moved through the capture volume; frame i of
                                 every camera is one exposure
    truth/                       the generator's ground truth (cameras, image chains, poses,
                                 feature positions, noise-free flatfields); no user path reads it

Frames are raw camera counts (``bit_depth`` bits) in single-page ``uint16`` TIFFs, one file per
frame, rendered through the same image chain as the demo trial
(:class:`~core.synthetic.imaging.ImagingModel` of each view: quantum noise, PSF + glare,
roll-off, intensifier distortion, round field, dark level, read noise, quantisation). The
walkway plate is in the beam for the grid, lattice and object frames and out of it for the empty
field (so the flatfield is the trial's: :meth:`ImagingModel.flatfield`).

The session is written into a temporary folder beside ``out`` and renamed into place when
complete, so a crash or a cancel never leaves a partial session (an earlier one stays intact
until the new one is complete).
"""

from __future__ import annotations

import io
import json
import os
import shutil
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import tifffile

from ..geometry.camera import Camera, Rig
from ..io.atomic import fsync_dir
from .analytic import attenuation_per_mm, slab_line_integrals
from .calib_objects import (
    CalibrationObject,
    bead_lattice,
    calibration_cube,
    distortion_grid,
    face_frame,
    helical_spiral,
)
from .calibration import object_line_integrals, plate_line_integrals
from .imaging import ImagingModel
from .rig import FLOOR_Z_MM, foot_rig

__all__ = ["SESSION_FORMAT", "SESSION_VERSION", "spiral_poses", "write_calibration_session"]

SESSION_FORMAT = "talus-calibration-session"
SESSION_VERSION = 1
_GROUP_TAG = {"dark": 1, "flat": 2, "grid": 3, "lattice": 4, "cube": 5, "spiral": 6}
_LATTICE_OFFSETS_MM = ((0.0, 0.0), (60.0, 0.0), (0.0, 60.0), (-60.0, 0.0), (0.0, -60.0))


class _Cancelled(Exception):
    pass


# ---------------------------------------------------------------------------- files
def _tiff_bytes(image: np.ndarray) -> bytes:
    buf = io.BytesIO()
    tifffile.imwrite(buf, np.ascontiguousarray(image, dtype=np.uint16), photometric="minisblack")
    return buf.getvalue()


def _write(path: Path, data: bytes) -> None:
    """Write a file of the (temporary) session folder and flush it to disk."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())


def _json(obj) -> bytes:
    return (json.dumps(obj, indent=2) + "\n").encode()


def _npz(arrays: dict) -> bytes:
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    return buf.getvalue()


# ---------------------------------------------------------------------------- scene parts
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


def _ray_map(cam: Camera) -> np.ndarray:
    """``M`` with ``M @ (u, v, 1)`` along the lab ray through pixel ``(u, v)`` (unnormalised)."""
    return cam.R.T @ np.linalg.inv(cam.K)


def _unit_rays(M: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``(n, 3)`` unit lab directions through pixels ``(u, v)`` (elementwise: BLAS threads for
    (n, 3) @ (3, 3) products cost more than they save on a busy machine)."""
    d = u[:, None] * M[:, 0] + v[:, None] * M[:, 1] + M[:, 2]
    return d / np.sqrt(np.einsum("ij,ij->i", d, d))[:, None]


class _ObjectRenderer:
    """Line integrals of a tube-bodied object (the spiral) in one view, many poses.

    The body (foam core and polycarbonate wall: low contrast, smooth) is sampled with exact
    chords through its two cylinders at every pixel centre, or on images of 512 pixels and more
    at the centres of 2 × 2 pixel blocks interpolated (bilinear) to full resolution; the steel
    beads are rendered exactly as :func:`~core.synthetic.analytic.bead_line_integrals` with
    fluence averaging over 4 × 4 rays per pixel does (as
    :func:`~core.synthetic.calibration.object_line_integrals` calls it), without its (n, 3) @
    (3, 3) products, which OpenBLAS threads slow 30-fold on a busy 2-core machine.
    """

    def __init__(self, cam: Camera, obj: CalibrationObject, *, supersample: int = 4) -> None:
        if obj.body is None or obj.body[0] != "tube":
            raise ValueError(f"obj: expected an object with a tube body, got {obj.name}")
        self.cam, self.obj, self.ss = cam, obj, int(supersample)
        self.M, self.src = _ray_map(cam), cam.source
        b = self.block = 2 if min(cam.image_shape) >= 512 else 1
        hb, wb = -(-cam.height // b), -(-cam.width // b)
        v, u = np.mgrid[0:hb, 0:wb].astype(np.float64) * b + (b - 1) / 2
        self.coarse = (hb, wb)
        self.dirs = _unit_rays(self.M, u.ravel(), v.ravel())

    def _chords(self, T: np.ndarray, radius: float, half: float) -> np.ndarray:
        R, t = T[:3, :3], T[:3, 3]
        o = (self.src - t) @ R
        d = np.einsum("ni,ij->nj", self.dirs, R)
        a = d[:, 0] ** 2 + d[:, 1] ** 2
        b = o[0] * d[:, 0] + o[1] * d[:, 1]
        c = o[0] ** 2 + o[1] ** 2 - radius * radius
        disc = b * b - a * c
        with np.errstate(divide="ignore", invalid="ignore"):
            sq = np.sqrt(np.maximum(disc, 0.0))
            r0 = np.where(disc > 0, (-b - sq) / a, np.inf)
            r1 = np.where(disc > 0, (-b + sq) / a, -np.inf)
            za, zb = (-half - o[2]) / d[:, 2], (half - o[2]) / d[:, 2]
        flat = np.abs(d[:, 2]) < 1e-12
        z0 = np.where(flat, np.where(abs(o[2]) <= half, -np.inf, np.inf), np.minimum(za, zb))
        z1 = np.where(flat, np.where(abs(o[2]) <= half, np.inf, -np.inf), np.maximum(za, zb))
        lo = np.maximum(np.maximum(r0, z0), 0.0)
        return np.maximum(np.minimum(r1, z1) - lo, 0.0)

    def body(self, T: np.ndarray) -> np.ndarray:
        """``(H, W)`` line integrals of the body at pose ``T``."""
        _, radius, half, mu_core, wall, mu_wall = self.obj.body
        L = (mu_wall * self._chords(T, radius, half)
             + (mu_core - mu_wall) * self._chords(T, radius - wall, half)).reshape(self.coarse)
        if self.block == 1:
            return L
        # coarse sample k sits at pixel b k + (b - 1) / 2: cv2.resize's half-pixel alignment
        h, w = self.cam.image_shape
        b = self.block
        full = cv2.resize(L, (b * self.coarse[1], b * self.coarse[0]), interpolation=cv2.INTER_LINEAR)
        return full[:h, :w]

    def beads(self, T: np.ndarray) -> np.ndarray:
        """``(H, W)`` effective line integrals of the beads (μ above the foam core) at ``T``."""
        cam, ss = self.cam, self.ss
        C = self.obj.centers_lab(T)
        r = self.obj.diameters / 2
        mu = np.full(len(C), self.obj.bead_mu - self.obj.body[3])
        cube = np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)], dtype=float)
        uv, z = cam.project(C[:, None, :] + r[:, None, None] * cube[None], return_depth=True)
        lo = np.maximum(np.floor(uv.min(axis=1)).astype(np.int64) - 1, 0)
        hi = np.minimum(np.ceil(uv.max(axis=1)).astype(np.int64) + 2, [cam.width, cam.height])
        keep = np.nonzero(np.all(z > 0, axis=1) & np.all(hi > lo, axis=1))[0]
        out = np.zeros(cam.image_shape)
        if len(keep) == 0:
            return out
        bw, bh = hi[keep, 0] - lo[keep, 0], hi[keep, 1] - lo[keep, 1]
        npx = bw * bh
        obj = np.repeat(np.arange(len(keep)), npx)
        local = np.arange(len(obj)) - np.repeat(np.cumsum(npx) - npx, npx)
        pu = lo[keep, 0][obj] + local % bw[obj]
        pv = lo[keep, 1][obj] + local // bw[obj]
        off = (np.arange(ss) + 0.5) / ss - 0.5
        ou, ov = (a.ravel() for a in np.meshgrid(off, off))
        su = (pu[:, None] + ou[None]).ravel()
        sv = (pv[:, None] + ov[None]).ravel()
        d = _unit_rays(self.M, su, sv)
        k = np.repeat(keep[obj], ss * ss)
        w = C[k] - self.src
        t = np.einsum("ij,ij->i", w, d)
        d2 = np.einsum("ij,ij->i", w, w) - t * t
        chord = np.where(t > 0, 2.0 * np.sqrt(np.maximum(r[k] ** 2 - d2, 0.0)), 0.0)
        val = -np.log(np.mean(np.exp(-(chord * mu[k]).reshape(-1, ss * ss)), axis=1))
        np.add.at(out, (pv, pu), val)
        return out

    def __call__(self, T: np.ndarray) -> np.ndarray:
        return np.maximum(self.body(T) + self.beads(T), 0.0).astype(np.float32)


def _at_kv(model: ImagingModel, kv: float, kv_ref: float) -> ImagingModel:
    """The chain at another tube voltage: fluence and gain scale as (kV / kV_ref)²."""
    if kv == kv_ref:
        return model
    s = (kv / kv_ref) ** 2
    if model.dark_dn + model.gain_dn * s > 2**model.bits - 1:
        raise ValueError(f"kvs: {kv:g} kV saturates the {model.bits}-bit camera (gain scales as kV²)")
    photons = None if model.photons_per_pixel is None else model.photons_per_pixel * s
    return replace(model, gain_dn=model.gain_dn * s, photons_per_pixel=photons)


def _dark(model: ImagingModel, shape, g: np.random.Generator) -> np.ndarray:
    dn = np.full(shape, float(model.dark_dn))
    if model.read_noise_dn > 0:
        dn = dn + g.normal(0.0, model.read_noise_dn, size=shape)
    return np.clip(np.rint(dn), 0, 2**model.bits - 1).astype(np.uint16)


def _plate(cam: Camera, model: ImagingModel, plate, *, gap_mm: float, offset_mm, angle_rad: float):
    """Line integrals of a face plate on ``cam``'s intensifier, its pose and its features'
    ideal / distorted pixels and lab points (features inside the image only)."""
    T = face_frame(cam, gap_mm=gap_mm, thickness_mm=plate.thickness, offset_mm=offset_mm,
                   angle_rad=angle_rad)
    L = plate_line_integrals(cam, plate, T)
    pts = plate.points @ T[:3, :3].T + T[:3, 3]
    ideal = cam.project(pts)
    inside = np.all((ideal > -0.5) & (ideal < [cam.width - 0.5, cam.height - 0.5]), axis=1)
    ideal, pts = ideal[inside], pts[inside]
    dist = ideal.copy() if model.distortion is None else model.distortion.forward(ideal)
    return L, T, ideal, dist, pts


def _uv(cam: Camera, model: ImagingModel, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    ideal = cam.project(X)
    return ideal, ideal.copy() if model.distortion is None else model.distortion.forward(ideal)


def _camera_truth(cam: Camera, name: str) -> dict:
    return {"session_name": name, "rig_name": cam.name, "width": cam.width, "height": cam.height,
            "K": cam.K.tolist(), "R": cam.R.tolist(), "t": cam.t.tolist(),
            "pixel_size_mm": cam.pixel_size, "sid_mm": cam.sid, "source_mm": cam.source.tolist()}


# ---------------------------------------------------------------------------- writer
def write_calibration_session(
    out,
    *,
    scene=None,
    pixels: int | None = None,
    seed: int = 0,
    n_spiral: int = 40,
    n_grid: int = 5,
    n_lattice: int = 5,
    n_dark: int = 5,
    n_flat: int = 10,
    kvs: Sequence[float] = (70.0,),
    cameras: Sequence[str] = ("cam1", "cam2"),
    energy_kev: float = 60.0,
    progress: Callable[[int, int], None] | None = None,
    cancel: Callable[[], bool] | None = None,
) -> dict | None:
    """Render a calibration session of the demo rig and write it to the folder ``out``.

    Parameters
    ----------
    out : str or Path
        Session folder (replaced as a whole when the new session is complete).
    scene : BiplaneScene, optional
        Take the rig, image chains and walkway from this scene (the demo trial's); otherwise
        they are those of ``make_foot_scene(pixels=pixels, seed=seed)``, built without bones.
    pixels : int, optional
        Image size (square) when no ``scene`` is given (default 512).
    seed : int
        Seed of the object poses, the grid placement and every frame's noise (and of the rig
        and image chains when no ``scene`` is given).
    n_spiral, n_grid, n_lattice, n_dark, n_flat : int
        Frames per camera of the moving 33-bead spiral (≥ 1), of the static hole grid, of the
        bead lattice (one placement each, at most 5; 0 = none), dark frames and empty-field
        frames per kV. The cube has one static frame.
    kvs : sequence of float
        Tube voltages with empty-field frames; the first is the voltage of every other frame
        (the trial's). Fluence and gain scale as kV² from it.
    cameras : sequence of str
        Folder names of the views, in the rig's order.
    energy_kev : float
        Effective energy for the walkway's attenuation when no ``scene`` is given.
    progress : callable(done, total), optional
        Called after each biplane frame (or pair of calibration frames) is written.
    cancel : callable() -> bool, optional
        Checked between frames; when it returns True the partial session is removed, ``out`` is
        left as it was, and None is returned.

    Returns
    -------
    dict or None
        The manifest written to ``session.json`` (None when cancelled).
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"out: {out} exists and is not a folder")
    if scene is not None:
        if pixels is not None and pixels != scene.rig[0].width:
            raise ValueError(f"pixels: {pixels} differs from the scene's {scene.rig[0].width}; "
                             "leave it out when a scene is given")
        rig, models, floor = scene.rig, tuple(scene.imaging), scene.floor
    else:
        rig, models, floor = _default_setup(512 if pixels is None else int(pixels), seed, energy_kev)
    cams = tuple(rig)
    names = [str(c) for c in cameras]
    if len(names) != len(cams) or len(set(names)) != len(names) or not all(names):
        raise ValueError(f"cameras: expected {len(cams)} distinct non-empty names, got {list(cameras)!r}")
    for nm, v in (("n_spiral", n_spiral), ("n_grid", n_grid), ("n_dark", n_dark), ("n_flat", n_flat)):
        if int(v) != v or v < 1:
            raise ValueError(f"{nm}: expected a positive integer, got {v!r}")
    if int(n_lattice) != n_lattice or not 0 <= n_lattice <= len(_LATTICE_OFFSETS_MM):
        raise ValueError(f"n_lattice: expected an integer in 0..{len(_LATTICE_OFFSETS_MM)}, "
                         f"got {n_lattice!r}")
    kv_list = [float(k) for k in kvs]
    if not kv_list or len(set(kv_list)) != len(kv_list) or min(kv_list) <= 0:
        raise ValueError(f"kvs: expected distinct positive tube voltages, got {list(kvs)!r}")
    for m in models:
        for k in kv_list:
            _at_kv(m, k, kv_list[0])
    shape = cams[0].image_shape
    if any(c.image_shape != shape for c in cams):
        raise ValueError("scene: every camera must have the same image size")
    bits = models[0].bits

    def kv_name(kv: float) -> str:
        return f"{kv:g}"

    flat_dirs = {kv_name(k): f"flat_{kv_name(k)}kV" for k in kv_list}
    groups = {"dark": "dark", "flat": flat_dirs, "grid": "grid", "cube": "cube", "spiral": "spiral"}
    if n_lattice:
        groups["lattice"] = "lattice"
    cube, spiral = calibration_cube(energy_kev=energy_kev), helical_spiral(33, energy_kev=energy_kev)
    grid_plate = distortion_grid(field_diameter_mm=shape[1] * cams[0].pixel_size, energy_kev=energy_kev)
    lattice = bead_lattice(energy_kev=energy_kev)
    background = [np.zeros(shape, np.float32) if floor is None else
                  slab_line_integrals(c, (0.0, 0.0, floor[0] - floor[1] / 2), (0.0, 0.0, 1.0),
                                      floor[1], floor[2]).astype(np.float32) for c in cams]

    def rng(group: str, i: int, v: int) -> np.random.Generator:
        return np.random.default_rng([int(seed), 0xCA1B, _GROUP_TAG[group], int(i), int(v)])

    g_pose = np.random.default_rng([int(seed), 0xCA1B, 0])
    poses = spiral_poses(rig, models, int(n_spiral), obj=spiral, rng=g_pose,
                         floor_z_mm=None if floor is None else floor[0])
    grid_place = [(g_pose.uniform(-7.5, 7.5, size=2), np.radians(g_pose.uniform(-2.0, 2.0)))
                  for _ in cams]
    T_cube = np.eye(4)
    for c, m in zip(cams, models, strict=True):
        if not _inside_field(c, m, cube.centers_lab(T_cube), 4.0):
            raise ValueError(f"scene: the cube at the lab origin does not fit inside {c.name}'s field")

    total = (int(n_dark) + int(n_flat) * len(kv_list) + int(n_grid) + int(n_lattice) + 1
             + int(n_spiral))
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=out.parent, prefix=f".{out.name}.", suffix=".tmp"))
    done = 0
    truth: dict = {}

    def step() -> None:
        nonlocal done
        done += 1
        if progress is not None:
            progress(done, total)
        if cancel is not None and cancel():
            raise _Cancelled

    def save(v: int, group_dir: str, i: int, image: np.ndarray) -> None:
        _write(tmp / names[v] / group_dir / f"{i:04d}.tif", _tiff_bytes(image))

    try:
        for i in range(int(n_dark)):
            for v, m in enumerate(models):
                save(v, "dark", i, _dark(m, shape, rng("dark", i, v)))
            step()
        for k, kv in enumerate(kv_list):
            for i in range(int(n_flat)):
                for v, m in enumerate(models):
                    mk = _at_kv(m, kv, kv_list[0])
                    save(v, flat_dirs[kv_name(kv)], i,
                         mk.apply(np.zeros(shape), rng=rng("flat", 1000 * k + i, v)))
                step()
            for v, m in enumerate(models):
                truth[f"flatfield_{names[v]}_{kv_name(kv)}kV"] = (
                    _at_kv(m, kv, kv_list[0]).flatfield(shape).astype(np.float32))
        # static hole grid: one placement per camera, n_grid exposures
        grid_L = []
        for v, (c, m) in enumerate(zip(cams, models, strict=True)):
            off, ang = grid_place[v]
            L, T, ideal, dist, pts = _plate(c, m, grid_plate, gap_mm=2.0, offset_mm=off, angle_rad=ang)
            grid_L.append(L + background[v])
            truth[f"grid_{names[v]}_ideal_uv"], truth[f"grid_{names[v]}_distorted_uv"] = ideal, dist
            truth[f"grid_{names[v]}_points_lab"], truth[f"grid_{names[v]}_T_lab_from_plate"] = pts, T
        for i in range(int(n_grid)):
            for v, m in enumerate(models):
                save(v, "grid", i, m.apply(grid_L[v], rng=rng("grid", i, v)))
            step()
        del grid_L
        for i in range(int(n_lattice)):
            for v, (c, m) in enumerate(zip(cams, models, strict=True)):
                L, T, ideal, dist, pts = _plate(c, m, lattice, gap_mm=0.0,
                                                offset_mm=_LATTICE_OFFSETS_MM[i], angle_rad=0.0)
                save(v, "lattice", i, m.apply(L + background[v], rng=rng("lattice", i, v)))
                key = f"lattice_{names[v]}_{i:04d}"
                truth[f"{key}_ideal_uv"], truth[f"{key}_distorted_uv"] = ideal, dist
                truth[f"{key}_points_lab"], truth[f"{key}_T_lab_from_plate"] = pts, T
            step()
        uvs = []
        for v, (c, m) in enumerate(zip(cams, models, strict=True)):
            L = object_line_integrals(c, cube, T_cube) + background[v]
            save(v, "cube", 0, m.apply(L, rng=rng("cube", 0, v)))
            uvs.append(_uv(c, m, cube.centers_lab(T_cube)))
        truth["cube_T_lab_from_object"] = T_cube
        truth["cube_ideal_uv"] = np.stack([u[0] for u in uvs])
        truth["cube_distorted_uv"] = np.stack([u[1] for u in uvs])
        truth["cube_points_lab"] = cube.centers_lab(T_cube)
        step()
        ideal, dist = [], []
        tube = [_ObjectRenderer(c, spiral) for c in cams]
        for i, T in enumerate(poses):
            uvs = []
            for v, (c, m) in enumerate(zip(cams, models, strict=True)):
                L = tube[v](T) + background[v]
                save(v, "spiral", i, m.apply(L, rng=rng("spiral", i, v)))
                uvs.append(_uv(c, m, spiral.centers_lab(T)))
            ideal.append(np.stack([u[0] for u in uvs]))
            dist.append(np.stack([u[1] for u in uvs]))
            step()
        truth["spiral_T_lab_from_object"] = poses
        truth["spiral_ideal_uv"], truth["spiral_distorted_uv"] = np.stack(ideal), np.stack(dist)

        n_frames = {"dark": int(n_dark), **{d: int(n_flat) for d in flat_dirs.values()},
                    "grid": int(n_grid), "cube": 1, "spiral": int(n_spiral)}
        if n_lattice:
            n_frames["lattice"] = int(n_lattice)
        manifest = {
            "format": SESSION_FORMAT, "version": SESSION_VERSION, "cameras": names,
            "bit_depth": int(bits), "frame_size": [int(shape[0]), int(shape[1])],
            "groups": groups, "kv": kv_list[0], "n_frames": n_frames,
            "grid": {"kind": "hole", "pitch_mm": 15.0, "hole_diameter_mm": grid_plate.hole_diameter,
                     "thickness_mm": grid_plate.thickness, "material": "aluminium",
                     "field_diameter_mm": float(shape[1] * cams[0].pixel_size),
                     "placement": "on the intensifier face, about 2 mm off it, shifted and turned "
                                  "by hand; one placement per camera: average its frames"},
            "objects": {"cube": cube.name, "spiral": spiral.name},
            "detector": {"field_mm": float(shape[1] * cams[0].pixel_size),
                         "pixel_size_mm": float(cams[0].pixel_size),
                         "note": "nominal intensifier field across the image width"},
            "notes": ("Synthetic collection day (core.synthetic, seed "
                      f"{int(seed)}): raw {bits}-bit counts, one TIFF per frame. Dark frames with "
                      "the X-rays off; empty-field frames with nothing in the beam; grid and "
                      "lattice frames with the plate on the intensifier face; the cube "
                      "(static, at the lab origin: it defines the lab frame) and the spiral "
                      "(moved through the capture volume) stand above the walkway plate, which "
                      "stays in the beam. Frame i of every camera in a group is one exposure."),
        }
        if n_lattice:
            manifest["lattice"] = {
                "kind": "bead", "pitch_mm": 20.0, "shape": [6, 6],
                "bead_diameter_mm": lattice.bead_diameter, "material": "steel beads in PMMA",
                "placement": "on the intensifier face; each frame is a separate placement: "
                             "check inter-bead distances (20-100 mm) and right angles within a frame"}
        truth_json = {
            "what": "ground truth of the synthetic session; for tests and studies only",
            "cameras": [_camera_truth(c, nm) for c, nm in zip(cams, names, strict=True)],
            "imaging": {nm: m.to_dict() for nm, m in zip(names, models, strict=True)},
            "kv_gain_scale": {kv_name(k): (k / kv_list[0]) ** 2 for k in kv_list},
            "walkway": None if floor is None else {"z_top_mm": floor[0], "thickness_mm": floor[1],
                                                   "mu_per_mm": floor[2]},
            "lattice_offsets_mm": [list(o) for o in _LATTICE_OFFSETS_MM[: int(n_lattice)]],
            "grid_placement": {nm: {"offset_mm": list(map(float, p[0])), "angle_rad": float(p[1])}
                               for nm, p in zip(names, grid_place, strict=True)},
            "arrays": "truth/truth.npz: flatfield_<cam>_<kV>kV (DN, float32), grid_/lattice_<cam>_* "
                      "and cube_/spiral_* ideal_uv, distorted_uv ((frame,) view, bead, 2; pixels "
                      "(u, v) = (column, row)), points_lab (mm) and T_lab_from_* poses",
        }
        _write(tmp / "truth" / "truth.json", _json(truth_json))
        _write(tmp / "truth" / "truth.npz", _npz(truth))
        _write(tmp / "session.json", _json(manifest))
        for folder in sorted({p.parent for p in tmp.rglob("*")}):
            fsync_dir(folder)
    except _Cancelled:
        shutil.rmtree(tmp, ignore_errors=True)
        return None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    _replace_folder(tmp, out)
    return manifest


def _replace_folder(new: Path, dest: Path) -> None:
    """Put the complete folder ``new`` at ``dest``; an existing ``dest`` is removed only after."""
    old = None
    if dest.exists():
        old = Path(tempfile.mkdtemp(dir=dest.parent, prefix=f".{dest.name}.", suffix=".old"))
        os.replace(dest, old / dest.name)
    os.replace(new, dest)
    fsync_dir(dest.parent)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
