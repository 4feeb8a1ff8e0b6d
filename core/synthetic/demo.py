"""Write a complete synthetic biplane study (frames, CT volumes, rig, ground truth) to a folder.

Layout of ``out_dir``::

    summary.json                    what is where, parameters, status ("complete"/"cancelled")
    rig/cam01.txt, cam02.txt        MayaCam 2.0 (core.geometry.write_mayacam)
    rig/rig.json                    K, R, t, size, pixel size, SID, source of each camera
    imaging/cam01.json, ...         every image-chain parameter (incl. the distortion)
    imaging/flatfield_cam01.tif     noise-free empty-field frame I0 (float32 DN)
    volumes/<bone>.tif + .json      CT sub-volume, int16 HU, one page per slice k (rows j,
                                    columns i); JSON: spacing, origin, direction, units
    volumes/soft_foot.tif, ...      soft-tissue envelope parts (float32 HU), same format
    frames/cam01/frame_0000.tif     12-bit frames (uint16 TIFF), one file per frame
    poses/<bone>.npy / .csv         T_lab_from_bone per frame, (N, 4, 4) / frame + 16 values
    poses/all.npy                   (n_bones, N, 4, 4)
    beads/beads.csv                 bead, bone, x, y, z (bone CT frame, mm), diameter
    beads/uv_cam01.npy              (N, n_beads, 2) distorted bead centres (u, v) per frame
    beads/uv_ideal_cam01.npy        (N, n_beads, 2) pinhole (undistorted) bead centres
    calibration_session/            the collection day's calibration frames of the same rig and
                                    image chains, as a lab records them (session.json, cam1/…,
                                    cam2/…; truth/ apart): :mod:`core.synthetic.session`, read
                                    with :func:`core.io.read_session`
    calibrations/session/v1/        the rig and correction estimated from that session alone
                                    (:func:`core.study.calibrations.calibrate_study`, as
                                    ``talus calibrate``); the trial uses them (256² and larger)

Every file is written atomically (temporary file in the same folder + rename), frames one by one
as they are rendered, the calibration session as a whole folder after the trial, and
``summary.json`` last; a cancelled run leaves complete files and a summary saying how many frames
were written (and no calibration session unless it was complete).
"""

from __future__ import annotations

import io
import json
import os
import shutil
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import tifffile

from ..geometry.mayacam import write_mayacam
from ..render.volume import CTVolume
from .scene import BiplaneScene, make_foot_scene

__all__ = ["make_demo_study", "write_volume"]


def _atomic_bytes(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _tiff_bytes(array: np.ndarray, **kwargs) -> bytes:
    buf = io.BytesIO()
    tifffile.imwrite(buf, array, **kwargs)
    return buf.getvalue()


def _npy_bytes(array: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.save(buf, array)
    return buf.getvalue()


def _json_bytes(obj) -> bytes:
    return (json.dumps(obj, indent=2) + "\n").encode()


def write_volume(volume: CTVolume, path) -> tuple[Path, Path]:
    """Write ``volume`` as a multipage TIFF (``data`` as stored) plus a JSON geometry sidecar.

    Read it back with ``core.io.read_tiff_volume(path, meta["spacing"], origin=meta["origin"],
    direction=meta["direction"], units=meta["units"])`` where ``meta`` is the JSON sidecar.
    Returns ``(tif_path, json_path)``.
    """
    p = Path(path)
    _atomic_bytes(p, _tiff_bytes(np.ascontiguousarray(volume.data), photometric="minisblack"))
    meta = {"name": volume.name, "units": volume.units, "shape_kji": list(volume.data.shape),
            "dtype": str(volume.data.dtype), "spacing": volume.spacing.tolist(),
            "origin": volume.origin.tolist(), "direction": volume.direction.tolist(),
            "index_convention": "data[k, j, i]; x = origin + direction @ (spacing * (i, j, k))"}
    js = p.with_suffix(".json")
    _atomic_bytes(js, _json_bytes(meta))
    return p, js


def _camera_dict(cam) -> dict:
    return {"name": cam.name, "width": cam.width, "height": cam.height, "K": cam.K.tolist(),
            "R": cam.R.tolist(), "t": cam.t.tolist(), "pixel_size_mm": cam.pixel_size,
            "sid_mm": cam.sid, "source_mm": cam.source.tolist()}


def _write_static(scene: BiplaneScene, out: Path, rel) -> dict:
    files: dict = {"rig": [], "imaging": [], "flatfield": [], "volumes": [], "poses": [], "beads": []}
    for cam, model in zip(scene.rig, scene.imaging, strict=True):
        p = out / "rig" / f"{cam.name}.txt"
        p.parent.mkdir(parents=True, exist_ok=True)
        write_mayacam(cam, p, version=2)
        files["rig"].append(rel(p))
        p = out / "imaging" / f"{cam.name}.json"
        _atomic_bytes(p, _json_bytes(model.to_dict()))
        files["imaging"].append(rel(p))
        p = out / "imaging" / f"flatfield_{cam.name}.tif"
        _atomic_bytes(p, _tiff_bytes(model.flatfield(cam.image_shape).astype(np.float32)))
        files["flatfield"].append(rel(p))
    p = out / "rig" / "rig.json"
    _atomic_bytes(p, _json_bytes({"lab_frame": "x walking direction, y left, z up; mm",
                                  "cameras": [_camera_dict(c) for c in scene.rig]}))
    files["rig"].append(rel(p))
    for vol in (*scene.bones, *scene.tissue):
        files["volumes"] += [rel(q) for q in write_volume(vol, out / "volumes" / f"{vol.name}.tif")]
    for b, name in enumerate(scene.names):
        T = scene.trajectories[b]
        _atomic_bytes(out / "poses" / f"{name}.npy", _npy_bytes(T))
        head = "frame," + ",".join(f"T{r}{c}" for r in range(4) for c in range(4))
        rows = [f"{i}," + ",".join(repr(float(x)) for x in T[i].ravel()) for i in range(len(T))]
        _atomic_bytes(out / "poses" / f"{name}.csv", ("\n".join([head, *rows]) + "\n").encode())
        files["poses"] += [rel(out / "poses" / f"{name}.npy"), rel(out / "poses" / f"{name}.csv")]
    _atomic_bytes(out / "poses" / "all.npy", _npy_bytes(np.asarray(scene.trajectories)))
    files["poses"].append(rel(out / "poses" / "all.npy"))
    lines = ["bead,bone,x_mm,y_mm,z_mm,diameter_mm"]
    k = 0
    for bs in scene.beads:
        bone = "lab" if bs.bone < 0 else scene.names[bs.bone]
        for c, d in zip(bs.centers, bs.diameters, strict=True):
            lines.append(f"{k},{bone}," + ",".join(repr(float(a)) for a in (*c, d)))
            k += 1
    _atomic_bytes(out / "beads" / "beads.csv", ("\n".join(lines) + "\n").encode())
    files["beads"].append(rel(out / "beads" / "beads.csv"))
    for v, cam in enumerate(scene.rig):
        for kind, dist in (("uv", True), ("uv_ideal", False)):
            uv = np.stack([scene.bead_uv(i, distorted=dist)[v] for i in range(scene.n_frames)])
            p = out / "beads" / f"{kind}_{cam.name}.npy"
            _atomic_bytes(p, _npy_bytes(uv))
            files["beads"].append(rel(p))
    return files


def make_demo_study(
    out_dir,
    *,
    n_frames: int = 10,
    pixels: int = 512,
    seed: int = 0,
    device: str | None = None,
    progress: Callable[[int, int], None] | None = None,
    cancel: Callable[[], bool] | None = None,
    spacing: float = 0.5,
    tissue_spacing: float = 2.0,
    calibration_session: bool = True,
) -> dict:
    """Render :func:`~core.synthetic.scene.make_foot_scene` and write it as a study folder.

    Parameters
    ----------
    out_dir : str or Path
        Destination folder (created; existing files of the same names are replaced).
    n_frames, pixels, seed : int
        Trial length, image size (square) and master seed.
    device : str, optional
        Warp device for the DRRs (default: CUDA when present, else CPU).
    progress : callable(i, n[, stage]), optional
        Called after each trial frame is written (``i`` frames done of ``n``), then after each
        step of the calibration session as ``(i, n, "calibration session")``.
    cancel : callable() -> bool, optional
        Checked before each frame; when it returns True the run stops cleanly.
    spacing, tissue_spacing : float
        Voxel sizes of the bone and soft-tissue volumes, mm.
    calibration_session : bool
        Also write ``calibration_session/`` (:func:`core.synthetic.session.write_calibration_session`
        with its defaults: 40 spiral, 5 grid, 5 lattice, 5 dark and 10 empty-field frames per
        camera) from the same rig, image chains and seed.

    Returns
    -------
    dict
        The content of ``summary.json`` (status, counts, parameters, relative file paths).
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ValueError(f"out_dir: {out} exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)

    def rel(p: Path) -> str:
        return p.relative_to(out).as_posix()

    scene = make_foot_scene(n_frames=n_frames, pixels=pixels, seed=seed, spacing=spacing,
                            tissue_spacing=tissue_spacing)
    # a session of an earlier demo in this folder may belong to another rig: never keep it
    shutil.rmtree(out / "calibration_session", ignore_errors=True)
    files = _write_static(scene, out, rel)
    renderer = scene.renderer(device=device)
    files["frames"] = {cam.name: [] for cam in scene.rig}
    done, status = 0, "complete"
    for i in range(scene.n_frames):
        if cancel is not None and cancel():
            status = "cancelled"
            break
        imgs = scene.render_frame(i, renderer=renderer)
        for cam, img in zip(scene.rig, imgs, strict=True):
            p = out / "frames" / cam.name / f"frame_{i:04d}.tif"
            _atomic_bytes(p, _tiff_bytes(img, photometric="minisblack"))
            files["frames"][cam.name].append(rel(p))
        done = i + 1
        if progress is not None:
            progress(done, scene.n_frames)
    session = None
    if calibration_session and status == "complete" and done > 0:
        from .session import write_calibration_session

        def session_progress(i: int, n: int) -> None:
            if progress is not None:
                progress(i, n, "calibration session")

        if write_calibration_session(out / "calibration_session", scene=scene, seed=seed,
                                     progress=session_progress, cancel=cancel) is None:
            status = "cancelled"
        else:
            session = "calibration_session"
    _, d, _ = scene.bead_positions(0)
    summary = {
        "format": "talus-synthetic-study", "version": 1, "status": status,
        "n_frames": scene.n_frames, "frames_written": done, "pixels": pixels, "seed": seed,
        "bones": list(scene.names), "n_beads": len(d), "bit_depth": scene.imaging[0].bits,
        "voxel_spacing_mm": spacing, "tissue_spacing_mm": tissue_spacing,
        "mu_water_per_mm": scene.mu_water, "floor": None if scene.floor is None else {
            "z_top_mm": scene.floor[0], "thickness_mm": scene.floor[1], "mu_per_mm": scene.floor[2]},
        "tissue_follows": {t.name: scene.names[b] for t, b in zip(scene.tissue, scene.tissue_bones,
                                                                 strict=True)},
        "renderer_device": str(renderer._bones.device) if renderer.backend == "warp" else "numpy",
        "conventions": {"lab": "x walking direction, y left, z up, mm",
                        "pixels": "(u, v) = (column, row), origin at the centre of the top-left pixel",
                        "poses": "T_lab_from_bone maps the volume's physical mm into the lab"},
        "files": files,
        "calibration_session": session,
    }
    if status == "complete" and done > 0:
        summary["study"] = _write_study(scene, out)
        if session is not None:
            summary["calibration"] = _calibrate(out, pixels, progress, cancel)
    _atomic_bytes(out / "summary.json", _json_bytes(summary))
    return summary


def _calibrate(out: Path, pixels: int, progress, cancel) -> dict:
    """Calibrate the study from its session as a lab would (``talus calibrate``): the trial then
    uses the estimated rig and correction, never the generator's truth. Beads of fewer than
    ~4 pixels (images under 256²) cannot be localised: the trial keeps the true rig then."""
    if pixels < 256:
        return {"skipped": f"{pixels}-pixel images are too coarse to calibrate (256 or more needed); "
                           "the trial uses the true rig without correction"}
    from ..study import Study
    from ..study.calibrations import calibrate_study

    shutil.rmtree(out / "calibrations", ignore_errors=True)  # versions of an earlier demo's rig
    step = None if progress is None else (lambda s, i, n: progress(i, n, f"calibration: {s}"))
    try:
        with Study.open(out, mode="w") as st:
            saved, cal = calibrate_study(st, out / "calibration_session", trials="all", progress=step,
                                         cancel=cancel)
    except ValueError as exc:
        return {"error": str(exc)}
    return {"calibration": saved.name, "reprojection_rms_px": cal.bundle.rms_px}


def _write_study(scene: BiplaneScene, out: Path) -> str:
    """Describe the folder as a :class:`core.study.Study` (``study.json``): the MayaCam rig,
    the bone CTs (as MetaImage volumes, which keep origin and direction), and one trial over
    the frame folders with every bone's true frame-0 pose recorded as its starting keyframe.
    A previous study manifest and its results in ``out`` are replaced."""
    import SimpleITK as sitk

    from ..io.atomic import atomic_path
    from ..study import Study

    (out / "study.json").unlink(missing_ok=True)
    shutil.rmtree(out / "results", ignore_errors=True)
    bones = [n for n in scene.names]
    with Study.create(out, name="talus-demo") as st:
        st.add_calibration("rig", [out / "rig" / f"{c.name}.txt" for c in scene.rig],
                           pixel_size_mm=scene.rig[0].pixel_size)
        for name, vol in zip(scene.names, scene.bones, strict=True):
            img = sitk.GetImageFromArray(np.ascontiguousarray(vol.data))
            img.SetSpacing([float(v) for v in vol.spacing])
            img.SetOrigin([float(v) for v in vol.origin])
            img.SetDirection([float(v) for v in np.asarray(vol.direction).ravel()])
            dest = out / "volumes" / f"{name}.mha"
            with atomic_path(dest) as tmp:
                sitk.WriteImage(img, str(tmp))
            st.add_volume(name, dest)
            st.add_bone(name, volume=name)
        st.add_trial("walk", [out / "frames" / c.name for c in scene.rig], calibration="rig",
                     bones=bones, bit_depth=scene.imaging[0].bits)
        trial = st.trial("walk")
        for k, name in enumerate(bones):
            trial.record_pose(name, 0, scene.trajectories[k][0])
    return "study.json"
