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
    <cam>/glare/*.tif            a 60 mm, 2 mm lead disc in the middle of the intensifier face,
                                 nothing else in the beam: the veiling glare measurement
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

The spiral's poses and the session's scene are built in :mod:`core.synthetic.session_poses`, the
frames' line integrals in :mod:`core.synthetic.session_render`.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import tifffile

from ..geometry.camera import Camera
from ..io.atomic import fsync_dir
from ..render.attenuation import attenuation_per_mm
from .analytic import cylinder_line_integrals, slab_line_integrals
from .calib_objects import bead_lattice, calibration_cube, distortion_grid, face_frame, helical_spiral
from .calibration import object_line_integrals
from .session_poses import _default_setup, _inside_field, spiral_poses
from .session_render import _at_kv, _dark, _ObjectRenderer, _plate, _uv

__all__ = ["SESSION_FORMAT", "SESSION_VERSION", "spiral_poses", "write_calibration_session"]

SESSION_FORMAT = "talus-calibration-session"
SESSION_VERSION = 1
_GROUP_TAG = {"dark": 1, "flat": 2, "grid": 3, "lattice": 4, "cube": 5, "spiral": 6, "glare": 7}
#: the glare disc: lead, diameter and thickness (mm)
GLARE_DISC_MM = (60.0, 2.0)
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
    n_glare: int = 2,
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
    n_glare : int
        Frames per camera of the lead disc that measures veiling glare (0 = none).
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
    if int(n_glare) != n_glare or n_glare < 0:
        raise ValueError(f"n_glare: expected an integer >= 0, got {n_glare!r}")
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
    if n_glare:
        groups["glare"] = "glare"
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
        if not _inside_field(c, m, cube.centers_lab(T_cube)[None], 4.0)[0]:
            raise ValueError(f"scene: the cube at the lab origin does not fit inside {c.name}'s field")

    total = (int(n_dark) + int(n_flat) * len(kv_list) + int(n_grid) + int(n_lattice) + 1
             + int(n_spiral) + int(n_glare))
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
        disc_mm, lead_mm = GLARE_DISC_MM
        disc_L = [cylinder_line_integrals(c, face_frame(c, thickness_mm=lead_mm), disc_mm / 2, lead_mm / 2,
                                          attenuation_per_mm("lead", energy_kev), supersample=3,
                                          average="fluence") for c in cams] if n_glare else []
        for i in range(int(n_glare)):
            for v, m in enumerate(models):
                save(v, "glare", i, m.apply(disc_L[v], rng=rng("glare", i, v)))
            step()
        del disc_L
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
        if n_glare:
            n_frames["glare"] = int(n_glare)
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
        if n_glare:
            manifest["glare"] = {
                "kind": "disc", "diameter_mm": GLARE_DISC_MM[0], "thickness_mm": GLARE_DISC_MM[1],
                "material": "lead", "placement": "in the middle of the intensifier face, nothing else in "
                                                 "the beam (the walkway out, as for the empty field)"}
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
