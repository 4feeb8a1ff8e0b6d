"""Open an XMALab project (``.xma``) as a Talus study.

:func:`import_xma` makes a study in a new folder from a project read by
:func:`core.io.xma_project.read_xma_project`:

* **cameras**: for each trial's reference calibration frame, XMALab's OpenCV cameras
  (``x ~ K [R | t] X``, the calibration object's frame as the lab) become a calibration
  ``xmalab.v<k>`` of MayaCam 2.0 files written into ``calibrations/xmalab/v<k>/`` (XMALab's
  cameras are in pixels of the *undistorted* image, as Talus's are after correction);
* **undistortion**: a camera's grid (its distorted and reference points, inliers only) becomes
  the correction pipeline saved with that calibration (``correction_<camera>.json``, read by
  :func:`core.study.calibrations.trial_correction`): one
  :class:`~core.imaging.pipeline.UndistortStep` of a local weighted mean
  (:class:`~core.imaging.pointmaps.LocalWeightedMeanMap`, ``lwm(12)``) fitted ideal → distorted,
  XMALab's own model: it refits a local weighted mean of 2nd-order polynomials with 12
  neighbours per point, radius = distance to the 12th nearest point, weight ``1 - 3R² + 2R³``,
  to the inlier pairs when a project opens (``src/processing/LocalUndistortion.cpp`` 116-139
  and 247-328, ``src/core/Settings.cpp`` 72; the map is evaluated by
  ``UndistortionObject::transformLWM``, ``src/core/UndistortionObject.cpp`` 339-400). The two
  differ outside every point's support, where XMALab leaves a point where it is (409-415)
  and Talus extrapolates the nearest point's polynomial, and where a point's 12th-nearest
  neighbour is a tie (a perfect lattice of reference points), which the two sorts may break
  differently (1.2e-3 px at most on a 4-px test lattice; 1e-8 px without ties,
  ``tests/core/io/test_xma_project_format.py``). A camera that also has OpenCV lens
  coefficients (``UndistortionParameter``, applied after the grid: ``Camera::undistortPoint``,
  ``src/core/Camera.cpp`` 672-684) gets one local weighted mean fitted to the composition sampled
  every 16 pixels (1024² images);
* **trials**: each trial (not XMALab's ``Default`` placeholder) references its images, one
  sequence per camera: the video file, or the folder of the TIFF frames it lists (the folder must
  hold exactly those frames). The absolute paths XMALab saved are tried as they are, then
  relative to the project's folder, then under each ``search`` folder by their last one, two and
  three path parts (a project moved to another machine);
* **markers**: each marker's 2-D points (raw image pixels, NaN where XMALab's status is 0 or
  below), status codes and 3-D points are saved as the study report ``markers/<trial>``
  (:meth:`Study.read_report`), frames numbered from 0 (XMALab's frame 1 is frame 0), with the
  rigid bodies' names.

Light (video) cameras are left out of the calibration and the trials (their marker points stay
in the report). The study has no bones (an XMALab project holds no CT); add volumes and bones to
track. What the study has no place for (recording speed, filter cut-off, light cameras, the lens coefficients)
is kept under ``settings["imported_from"]``.

A camera whose images XMALab mirrors (``isFlipped``) is refused: its calibration is that of the
mirror image, which no proper camera of the unmirrored images matches.
"""

from __future__ import annotations

import datetime as _dt
import os
import re
import shutil
from collections.abc import Sequence
from pathlib import Path, PurePosixPath, PureWindowsPath

import numpy as np

from ..errors import FileError
from .errors import StudyError
from .study_edit import entry_name

__all__ = ["import_xma", "xma_distortion_model", "xma_markers"]

SERIES = "xmalab"
_VIDEO = (".avi", ".cine", ".mp4", ".mov", ".mkv", ".m4v", ".tif", ".tiff")


def _opencv_distort(uv: np.ndarray, K: np.ndarray, k: np.ndarray) -> np.ndarray:
    """OpenCV's lens model (``cv::projectPoints``: ``k1 k2 p1 p2 k3 k4 k5 k6``) applied to ideal
    pixel positions ``(n, 2)``."""
    x = (uv[:, 0] - K[0, 2]) / K[0, 0]
    y = (uv[:, 1] - K[1, 2]) / K[1, 1]
    r2 = x * x + y * y
    k1, k2, p1, p2, k3, k4, k5, k6 = k
    radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.column_stack([K[0, 0] * xd + K[0, 2], K[1, 1] * yd + K[1, 2]])


def xma_distortion_model(grid, *, coeffs=None, K=None, size=None, n_neighbours: int = 12,
                         step: int | None = None):
    """The :class:`~core.imaging.distortion_models.DistortionModel` (ideal → distorted pixels) of
    an XMALab camera: its grid's local weighted mean, composed with OpenCV's lens model when
    ``coeffs`` (8 values, with the camera matrix ``K`` and the image ``size`` ``(width,
    height)``) are given and not all zero (sampled every ``step`` pixels, default a 32nd of the
    smaller side, 4 to 16 pixels). None when the camera has neither."""
    from ..imaging.distortion_models import fit_distortion

    lens = coeffs is not None and np.any(np.asarray(coeffs, float) != 0)
    grid_model = None
    if grid is not None:
        keep = np.asarray(grid.inlier, bool)
        if keep.sum() < n_neighbours:
            raise ValueError(f"grid: {int(keep.sum())} inlier grid points, the local weighted mean needs at "
                             f"least {n_neighbours}")
        grid_model = fit_distortion(grid.references[keep], grid.distorted[keep], f"lwm({n_neighbours})")
    if not lens:
        return grid_model
    if K is None or size is None:
        raise ValueError("K, size: the camera matrix and image size are needed with lens coefficients")
    w, h = size
    step = int(step or min(16, max(4, min(w, h) // 32)))
    u, v = np.meshgrid(np.arange(0, w + step - 1, step, dtype=float),
                       np.arange(0, h + step - 1, step, dtype=float))
    ideal = np.column_stack([np.minimum(u.ravel(), w - 1), np.minimum(v.ravel(), h - 1)])
    mid = _opencv_distort(ideal, np.asarray(K, float), np.asarray(coeffs, float))
    dist = grid_model.forward(mid) if grid_model is not None else mid
    return fit_distortion(ideal, dist, f"lwm({n_neighbours})")


def _candidates(p: str, base: Path, search: Sequence[Path]):
    yield Path(p)
    parts = (PureWindowsPath(p) if ("\\" in p or re.match(r"^[A-Za-z]:", p)) else PurePosixPath(p)).parts
    parts = [q for q in parts if q not in ("/", "\\") and not re.match(r"^[A-Za-z]:\\?$", q)]
    if not Path(p).is_absolute():
        yield base / p
    for s in (base, *search):
        for n in (1, 2, 3):
            if len(parts) >= n:
                yield Path(s, *parts[-n:])


def _find(p: str, base: Path, search: Sequence[Path]) -> Path | None:
    return next((c for c in _candidates(p, base, search) if c.exists()), None)


def _view(files: list[str], where: str, base: Path, search: Sequence[Path]) -> Path:
    """The sequence path of one camera's file list (module docs)."""
    first = _find(files[0], base, search)
    if first is None:
        looked = ", ".join(str(c) for c in list(_candidates(files[0], base, search))[:6])
        raise StudyError(f"{where}: image {files[0]} not found (looked at {looked}; pass search folders)",
                         path=files[0], expected="an existing image file")
    if len(files) == 1:
        if first.suffix.lower() not in _VIDEO:
            raise StudyError(f"{where}: {first}: expected a video (.avi, .cine, …) or multipage TIFF",
                             path=first, expected="a video")
        return first
    if first.suffix.lower() not in (".tif", ".tiff"):
        raise StudyError(f"{where}: {first}: Talus reads image sequences of TIFF frames, not "
                         f"{first.suffix or 'files without a suffix'}", path=first, expected="TIFF frames")
    folder = first.parent
    from ..io.sequences import open_sequence

    seq = open_sequence(folder)
    try:
        n, held = len(seq), [f.name for f in seq.files]
    finally:
        seq.close()
    listed = [PureWindowsPath(f).name if "\\" in f else PurePosixPath(f).name for f in files]
    if n == len(files) and held != listed:
        raise StudyError(f"{where}: the folder {folder} holds other frames than the trial lists (e.g. "
                         f"{next(a for a, b in zip(held, listed, strict=True) if a != b)}); expected "
                         "exactly the trial's frames in its order", path=folder,
                         expected="the trial's frames")
    if n != len(files):
        raise StudyError(f"{where}: the folder {folder} holds {n} TIFF frames but the trial lists "
                         f"{len(files)}; expected a folder of exactly the trial's frames", path=folder,
                         expected=f"{len(files)} TIFF frames")
    return folder


def _none(a: np.ndarray | None):
    return None if a is None else np.where(np.isnan(a), None, a.astype(object)).tolist()


def xma_markers(project, trial: str) -> dict:
    """The marker report of ``trial`` (module docs): JSON types, NaN as None."""
    t = project.trial(trial)
    out = []
    for m in t.markers:
        entry = {"id": m.id, "description": m.description, "points2d": None, "status2d": None,
                 "points3d": None}
        if m.points2d is not None:
            entry["points2d"] = _none(project.marker_points(trial, m.id))
            s = project.marker_status(trial, m.id)
            entry["status2d"] = None if s is None else s.tolist()
            entry["points3d"] = _none(project.marker_points3d(trial, m.id))
        out.append(entry)
    return {"source": "xmalab", "project": str(project.path), "trial": trial,
            "cameras": [c.name for c in project.cameras], "frame_base": 0,
            "pixels": "raw (distorted) image, (column, row), origin at the centre of the top-left pixel",
            "markers": out, "rigid_bodies": list(t.rigid_bodies)}


def import_xma(project: str | os.PathLike, out: str | os.PathLike, *, name: str | None = None,
               search: Sequence[str | os.PathLike] = (), n_neighbours: int = 12):
    """Create a study in ``out`` from the XMALab project ``project`` (see the module docs).

    Parameters
    ----------
    project : path
        The ``.xma`` file.
    out : path
        A new (or empty) study folder.
    search : sequence of paths
        Folders to look for the trials' images in when the paths the project saved are gone.
    n_neighbours : int
        Points per local quadratic of the undistortion (XMALab's default 12).

    Returns the open (writable) :class:`~core.study.Study`; close it when done. On an error
    nothing is left in ``out``.

    Raises
    ------
    FileError
        The project is malformed (naming the file and what was expected).
    StudyError
        ``out`` holds files already, a camera is mirrored or uncalibrated, a trial's images are
        missing or are not a sequence Talus reads.
    """
    src = Path(project).absolute()
    try:
        return _import_xma(src, Path(out), name=name, search=search, n_neighbours=n_neighbours)
    except FileError:
        raise
    except ValueError as exc:  # what the project's numbers make impossible (a singular K, ...)
        text = str(exc)
        raise StudyError(text if str(src) in text else f"{src}: {text}", path=src,
                         expected="an XMALab project Talus can open") from exc


def _import_xma(src: Path, out: Path, *, name, search, n_neighbours):
    from ..geometry.mayacam import write_mayacam
    from ..imaging.pipeline import Pipeline, UndistortStep
    from ..io.atomic import atomic_write_json
    from ..io.sequences import open_sequence
    from ..io.xma_project import read_xma_project
    from .manifest import store_path
    from .study import Study

    prj = read_xma_project(src)
    search = [Path(s).expanduser() for s in search]
    xray = [k for k, c in enumerate(prj.cameras) if not c.light]  # light (video) cameras are left out
    if not xray:
        raise StudyError(f"{src}: every camera is a light camera; expected X-ray cameras", path=src,
                         expected="X-ray cameras")
    for c in (prj.cameras[k] for k in xray):
        if c.flipped:
            raise StudyError(f"{src}: camera {c.name!r} is mirrored (isFlipped=\"1\"): its calibration is of "
                             "the mirror image; expected unmirrored cameras (turn the flip off in XMALab and "
                             "recalibrate)", path=src, expected="unmirrored cameras")
    trials = [t for t in prj.trials if not t.default]
    if not trials:
        raise StudyError(f"{src}: the project has no trial with images", path=src, expected="a trial")
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise StudyError(f"out: {out} exists and is not an empty folder", path=out, expected="a new folder")
    created = not out.exists()
    base = src.parent
    # resolve the images first: nothing is written when a trial's images are missing
    views = {}
    for t in trials:
        lists = prj.view_files(t.name)
        views[t.name] = [_view(lists[k], f"trial {t.name!r}, camera {prj.cameras[k].name!r}", base, search)
                         for k in xray]
    study = Study.create(out, name=name or src.stem)
    try:
        taken_trials: set[str] = set()
        names: list[str] = []
        cal_of_ref: dict[int, str] = {}
        files_entries = dict(study.settings.get("calibration_files", {}))
        now = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
        cams_info = {}
        for t in trials:
            ref = t.reference_calibration
            if ref not in cal_of_ref:
                sizes = []
                for v in views[t.name]:
                    seq = open_sequence(v)
                    try:
                        sizes.append((seq.frame_shape[1], seq.frame_shape[0]))
                    finally:
                        seq.close()
                rig = prj.rig(t.name, sizes=sizes, cameras=xray)
                k = len(cal_of_ref) + 1
                cal = f"{SERIES}.v{k}"
                folder = study.folder / "calibrations" / SERIES / f"v{k}"
                folder.mkdir(parents=True)
                taken_cams: set[str] = set()
                cam_files, corr_files = [], []
                for xc, cam in zip([prj.cameras[i] for i in xray], rig, strict=True):
                    stem = entry_name(xc.name, taken_cams, fallback="item")
                    write_mayacam(cam, folder / f"{stem}.txt", version=2)
                    cam_files.append(folder / f"{stem}.txt")
                    try:
                        model = xma_distortion_model(prj.grid(xc.name), coeffs=xc.distortion_coeffs, K=cam.K,
                                                     size=(cam.width, cam.height), n_neighbours=n_neighbours)
                    except FileError:
                        raise
                    except ValueError as exc:
                        raise StudyError(f"{src}: camera {xc.name!r}: undistortion: {exc}", path=src,
                                         expected="a usable undistortion grid") from None
                    steps = () if model is None else (UndistortStep(model),)
                    atomic_write_json(folder / f"correction_{stem}.json", Pipeline(steps).to_dict())
                    corr_files.append(folder / f"correction_{stem}.json")
                    g = prj.grid(xc.name)
                    cams_info[xc.name] = {
                        "light": xc.light,
                        "grid_points": None if g is None else len(g.inlier),
                        "grid_inliers": None if g is None else int(np.sum(g.inlier)),
                        "lens_coefficients": None if xc.distortion_coeffs is None else
                        [float(v) for v in xc.distortion_coeffs]}
                meta = {"name": cal, "series": SERIES, "version": k, "created": now, "session": None,
                        "object": f"XMALab project {src.name}, calibration frame {ref}",
                        "static_object": None}
                atomic_write_json(folder / "version.json", {**meta, "files": {
                    "cameras": [p.name for p in cam_files], "corrections": [p.name for p in corr_files]}})
                study.add_calibration(cal, cam_files)
                files_entries[cal] = {"series": SERIES, "version": k, "created": now,
                                      "folder": store_path(study.folder, folder), "calibration": None,
                                      "corrections": [store_path(study.folder, p) for p in corr_files],
                                      "report": None, "session": None, "source": str(src),
                                      "reference_frame": ref}
                study.update_settings(calibration_files=files_entries)
                cal_of_ref[ref] = cal
            tname = entry_name(t.name, taken_trials, fallback="item")
            names.append(tname)
            study.add_trial(tname, views[t.name], calibration=cal_of_ref[ref])
            study.write_report("markers", tname, xma_markers(prj, t.name))
        study.update_settings(imported_from={
            "format": "xmalab-xma", "path": str(src), "version": prj.version,
            "calibration_type": prj.calibration_type, "cameras": cams_info,
            "light_cameras": [c.name for c in prj.cameras if c.light],
            "trials": {_n: {"xmalab_name": t.name, "start_frame": t.start_frame, "end_frame": t.end_frame,
                            "reference_calibration": t.reference_calibration,
                            "recording_speed_hz": t.recording_speed,
                            "cutoff_frequency_hz": t.cutoff_frequency,
                            "rigid_bodies": list(t.rigid_bodies)}
                       for _n, t in zip(names, trials, strict=True)},
        })
    except BaseException:
        study.close()
        if created:
            shutil.rmtree(out, ignore_errors=True)
        else:
            for p in list(out.iterdir()):
                shutil.rmtree(p, ignore_errors=True) if p.is_dir() else p.unlink(missing_ok=True)
        raise
    return study
