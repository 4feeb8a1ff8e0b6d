"""Calibrations saved in a study: versioned rigs and correction pipelines, and which one a trial uses.

A session calibration (:func:`core.calibration.session.calibrate_session`) is saved as one
*version* of a named calibration series::

    calibrations/<series>/v<N>/
        <camera>.txt                 MayaCam 2.0, one per camera (the rig, corrected pixels)
        calibration.json             Talus calibration file: cameras, parameter SDs, quality
        correction_<camera>.json     imaging pipeline (dark → flatfield → [glare →] undistort), arrays in
        correction_<camera>_<k>.npy  .npy files beside it
        report/report.json, *.png    the calibration report
        version.json                 what was saved, from which session, when

and registered in the manifest as the calibration ``<series>.v<N>`` (its MayaCam files), with
``settings["calibration_files"]["<series>.v<N>"]`` naming the files above. Which version a
trial uses is its manifest entry ``trials[<trial>]["calibration"]``; :func:`trial_correction`
gives the trial's saved pipelines. An earlier version is never changed or removed.

Saving is atomic: the version folder is written under a temporary name and renamed, then the
manifest is replaced in one write; if anything fails the folder is removed and the study is as
it was.
"""

from __future__ import annotations

import copy
import datetime as _dt
import json
import os
import re
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..io.atomic import atomic_write_json
from .errors import StudyError
from .manifest import store_path

__all__ = ["SavedCalibration", "calibrate_study", "calibration_versions", "lab_frame_note",
           "load_correction", "pose_shift_mm", "save_session_calibration", "source_shift_mm",
           "trial_correction", "use_calibration"]

FILES_KEY = "calibration_files"
_SERIES_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_\-]{0,40}$")


@dataclass(frozen=True)
class SavedCalibration:
    """A saved calibration version: its manifest ``name`` (``<series>.v<N>``), ``series``,
    ``version``, ``folder`` and the ``trials`` that now use it."""

    name: str
    series: str
    version: int
    folder: Path
    trials: tuple[str, ...]


def _versions_on_disk(base: Path) -> list[int]:
    if not base.is_dir():
        return []
    return sorted(int(p.name[1:]) for p in base.iterdir() if re.fullmatch(r"v\d+", p.name) and p.is_dir())


def calibration_versions(study, series: str | None = None) -> list[dict]:
    """Saved versions (oldest first): name, series, version, created, folder and the trials using it."""
    files = study.settings.get(FILES_KEY, {})
    uses: dict[str, list[str]] = {}
    for t, entry in study.manifest["trials"].items():
        uses.setdefault(entry["calibration"], []).append(t)
    out = []
    for name, f in files.items():
        if series is not None and f.get("series") != series:
            continue
        out.append({"name": name, "series": f.get("series"), "version": f.get("version"),
                    "created": f.get("created"), "folder": f.get("folder"), "trials": uses.get(name, [])})
    return sorted(out, key=lambda d: (str(d["series"]), int(d["version"] or 0)))


def _encoder(folder: Path, stem: str):
    count = [0]

    def enc(a: np.ndarray) -> dict:
        name = f"{stem}_{count[0]}.npy"
        count[0] += 1
        np.save(folder / name, np.ascontiguousarray(a))
        return {"__npy__": name}

    return enc


def _decoder(folder: Path):
    from ..imaging.serialize import decode_array

    def dec(d):
        if isinstance(d, dict) and "__npy__" in d:
            p = folder / str(d["__npy__"])
            if not p.is_file():
                raise StudyError(f"{p}: array file of a saved correction pipeline is missing")
            return np.load(p, allow_pickle=False)
        return decode_array(d)

    return dec


def load_correction(path) -> object:
    """The :class:`~core.imaging.pipeline.Pipeline` saved at ``path`` (a ``correction_*.json``)."""
    from ..imaging.pipeline import Pipeline

    p = Path(path)
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise StudyError(f"{p}: cannot read the saved correction pipeline ({exc})") from None
    try:
        return Pipeline.from_dict(doc, array_decoder=_decoder(p.parent))
    except (ValueError, KeyError, TypeError) as exc:
        raise StudyError(f"{p}: not a correction pipeline ({exc})") from None


def trial_correction(study, trial: str) -> list | None:
    """The correction pipelines (one per view) saved with the calibration ``trial`` uses, or None
    when that calibration was not made by :func:`save_session_calibration`."""
    entry = study.manifest["trials"].get(trial)
    if entry is None:
        raise StudyError(f"trial: no trial named {trial!r} (have {list(study.trials)})")
    f = study.settings.get(FILES_KEY, {}).get(entry["calibration"])
    if not f or not f.get("corrections"):
        return None
    return [load_correction(study.path(p)) for p in f["corrections"]]


def _write_version(tmp: Path, cal, report: bool, meta: dict) -> dict:
    from ..calibration.io import save_calibration
    from ..geometry.mayacam import write_mayacam

    files = {"cameras": [], "corrections": []}
    for cam, c in zip(cal.rig, cal.cameras, strict=True):
        write_mayacam(cam, tmp / f"{cam.name}.txt", version=2)
        files["cameras"].append(f"{cam.name}.txt")
        d = c.pipeline.to_dict(array_encoder=_encoder(tmp, f"correction_{cam.name}"))
        atomic_write_json(tmp / f"correction_{cam.name}.json", d)
        files["corrections"].append(f"correction_{cam.name}.json")
    save_calibration(tmp / "calibration.json", cal.bundle, metadata={**meta, "camera_names": [
        c.name for c in cal.rig]})
    if report:
        from ..calibration.report import write_report

        write_report(cal, tmp / "report")
        files["report"] = "report/report.json"
    atomic_write_json(tmp / "version.json", {**meta, "files": files})
    return files


def save_session_calibration(study, cal, *, series: str = "session", trials="series",
                             session_path=None, report: bool = True) -> SavedCalibration:
    """Save ``cal`` (a :class:`~core.calibration.session.SessionCalibration`) as the next version
    of ``series`` (module docs) and point ``trials`` at it.

    Parameters
    ----------
    study : Study
        Open for writing.
    trials : "series", "all", "none" or sequence of str
        Trials that use the new version: those on an earlier version of ``series`` (default),
        every trial, none, or the named ones.
    session_path : path, optional
        Recorded with the version (where the frames came from).
    report : bool
        Also write the report (JSON and figures) into the version folder.
    """
    study._require_write()
    if not isinstance(series, str) or not _SERIES_RE.match(series):
        raise ValueError(f"series: expected 1-41 letters, digits, '_' or '-', got {series!r}")
    doc = copy.deepcopy(study._doc)
    if isinstance(trials, str):
        if trials == "all":
            names = list(doc["trials"])
        elif trials == "none":
            names = []
        elif trials == "series":
            names = [t for t, e in doc["trials"].items() if e["calibration"].startswith(f"{series}.v")]
        else:
            raise ValueError(f"trials: expected 'series', 'all', 'none' or trial names, got {trials!r}")
    else:
        names = [str(t) for t in trials]
    for t in names:
        if t not in doc["trials"]:
            raise StudyError(f"trials: no trial named {t!r} (have {list(doc['trials'])})")
        views = len(doc["trials"][t]["views"])
        if views != len(cal.rig):
            raise StudyError(f"trials: trial {t!r} has {views} views but the calibration has "
                             f"{len(cal.rig)} cameras")
    base = study.folder / "calibrations" / series
    base.mkdir(parents=True, exist_ok=True)
    known = [int(f.get("version", 0)) for f in doc["settings"].get(FILES_KEY, {}).values()
             if f.get("series") == series]
    n = max([0, *known, *_versions_on_disk(base)]) + 1
    name = f"{series}.v{n}"
    final = base / f"v{n}"
    now = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
    meta = {"name": name, "series": series, "version": n, "created": now,
            "session": None if session_path is None else str(Path(session_path).absolute()),
            "object": cal.target.name,
            "static_object": None if cal.static_target is None else cal.static_target.name,
            "rms_px": float(cal.bundle.rms_px)}
    tmp = Path(tempfile.mkdtemp(prefix=f".v{n}.", suffix=".partial", dir=base))
    try:
        files = _write_version(tmp, cal, report, meta)
        os.replace(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    try:
        rel = lambda f: store_path(study.folder, final / f)  # noqa: E731
        px = [c.pixel_size for c in cal.rig]
        doc["calibrations"][name] = {"format": "mayacam", "cameras": [rel(f) for f in files["cameras"]],
                                     "pixel_size_mm": float(np.mean(px)) if all(px) else None}
        entry = {"series": series, "version": n, "created": now, "folder": store_path(study.folder, final),
                 "calibration": rel("calibration.json"),
                 "corrections": [rel(f) for f in files["corrections"]],
                 "report": rel(files["report"]) if "report" in files else None,
                 "session": meta["session"]}
        doc["settings"].setdefault(FILES_KEY, {})[name] = entry
        for t in names:
            doc["trials"][t]["calibration"] = name
        study._commit(doc)
    except BaseException:
        shutil.rmtree(final, ignore_errors=True)
        raise
    return SavedCalibration(name, series, n, final, tuple(names))


def use_calibration(study, trial: str, calibration: str) -> None:
    """Point ``trial`` at the saved calibration version ``calibration`` (e.g. ``"session.v1"``)."""
    study._require_write()
    doc = copy.deepcopy(study._doc)
    if trial not in doc["trials"]:
        raise StudyError(f"trial: no trial named {trial!r} (have {list(doc['trials'])})")
    if calibration not in doc["calibrations"]:
        have = list(doc["calibrations"])
        raise StudyError(f"calibration: no calibration named {calibration!r} (have {have})")
    doc["trials"][trial]["calibration"] = calibration
    study._commit(doc)


def source_shift_mm(study, old: str, new: str) -> list[float] | None:
    """How far each camera's X-ray source (``C = -Rᵀt``, mm) lies from its place in calibration
    ``old`` in calibration ``new``, camera by camera; None when their camera counts differ. Both
    are in their own lab frames: a shift far beyond the calibrations' uncertainty means the lab
    frame moved (the cube placed elsewhere, or ``lab_frame="object"``) or the rig did."""
    a, b = study.rig(old), study.rig(new)
    if len(a) != len(b):
        return None
    return [float(np.linalg.norm(ca.source - cb.source)) for ca, cb in zip(a, b, strict=True)]


def pose_shift_mm(study, old: str, new: str, poses) -> float | None:
    """How far calibration ``new`` sees the lab poses ``poses`` (``(n, 4, 4)``, mm) from where
    ``old`` sees them: each pose's origin projected by both calibrations' cameras, the image
    displacement in mm at the point (pixels × its depth / the focal length, ``old``'s camera), the
    largest over cameras and poses; None when the camera counts differ or there is no pose. Two
    calibrations of the same lab frame see a pose within their reprojection errors, a moved lab
    frame (or rig) by the move. The sources alone are no test: 200 single-frame cube DLTs of the
    1024² foot rig at 0.05 px noise (``core.studies.calibration.study.dlt_instability``, seed 0)
    put the worse camera's source 3.3 mm from the truth at the median (7.4 at the 95th
    percentile, 10.1 at most; over 2 mm in 73 % of the draws), while they saw points within
    60 mm of the capture centre at most 0.09 mm from where the true rig sees them."""
    a, b = study.rig(old), study.rig(new)
    P = np.asarray(poses, dtype=float).reshape(-1, 4, 4)[:, :3, 3]
    if len(a) != len(b) or not len(P):
        return None
    worst = 0.0
    for ca, cb in zip(a, b, strict=True):
        ua, depth = ca.project(P, return_depth=True)
        d = np.linalg.norm(cb.project(P) - ua, axis=-1) * np.abs(depth) / ca.fx
        worst = max(worst, float(np.nanmax(d)) if np.isfinite(d).any() else np.inf)
    return worst


def lab_frame_note(study, trial: str, old: str, new: str, *, tolerance_mm: float = 2.0) -> str | None:
    """A warning for ``trial`` moved from calibration ``old`` to ``new`` with poses recorded
    (keyframes or tracked) when ``new``'s cameras see them more than ``tolerance_mm`` (at the bone)
    from where ``old``'s do (:func:`pose_shift_mm`): those poses are in ``old``'s lab frame and no
    longer fit the frames seen through ``new`` (the demo's keyframes, after a calibration with the
    spiral's lab frame, drew the tibia across the image). The sources' shift
    (:func:`source_shift_mm`) is named too; on its own it is no test: a DLT's sources lie mm from
    a bundle adjustment's of the same lab frame. None when nothing is recorded or the poses fit."""
    if old == new:
        return None
    tr = study.trial(trial)
    states = [tr.results(b) for b in tr.bones]
    poses = [r.pose for st in states for r in st.records.values() if r.pose is not None]
    keyframes = sum(len(st.keyframes) for st in states)
    try:
        seen = pose_shift_mm(study, old, new, poses) if poses else None
        moved_far = seen is not None and seen > tolerance_mm
        shift = (source_shift_mm(study, old, new) or []) if moved_far else []
    except (OSError, ValueError, KeyError) as e:  # the old calibration's cameras unreadable (removed by hand)
        return (f"trial {trial!r} moved from calibration {old} to {new} with {len(poses)} recorded poses, "
                f"but {old}'s cameras cannot be read to check they still fit ({e}): if the lab frame "
                "changed, set the keyframes again")
    if seen is None or seen <= tolerance_mm:
        return None
    moved = ", ".join(f"{d:.1f}" for d in shift)
    return (f"trial {trial!r} moved from calibration {old} to {new}, whose cameras see its recorded poses "
            f"up to {seen:.1f} mm (at the bone) from where {old}'s do (the X-ray sources lie {moved} mm "
            f"from where {old} has them): the lab frame (or the rig) changed, and the trial's "
            f"{len(poses)} recorded poses ({keyframes} of them keyframes) are in {old}'s lab frame. Set "
            "the keyframes again and track anew, or keep the trial on its calibration")


def calibrate_study(study, session, *, object=None, model: str = "auto", lab_frame: str = "static",
                    series: str = "session", trials="series", progress=None, cancel=None):
    """Calibrate the session folder ``session`` (:func:`core.io.read_session`) and save the result
    into ``study`` (open for writing) as the next version of ``series``.

    ``object``, ``model`` and ``lab_frame`` are those of
    :func:`~core.calibration.session.calibrate_session`: ``lab_frame="static"`` (default) puts the
    lab in the static object's (cube's) frame, and a cube frame that was recorded but cannot be
    labelled is then an error naming its file; ``"object"`` accepts the moving object's first
    labelled frame as the lab frame, with a warning in ``calibration.report["warnings"]`` (saved
    with the version's report).

    Returns ``(saved, calibration)``: the :class:`SavedCalibration` and the
    :class:`~core.calibration.session.SessionCalibration`. Raises what
    :func:`~core.calibration.session.calibrate_session` raises; nothing is saved then. ``cancel()``
    is polled once more before saving (a cancel during the bundle adjustment saves nothing:
    :class:`~core.calibration.session.CalibrationCancelled`).
    """
    from ..calibration.session import CalibrationCancelled, calibrate_session
    from ..io.calibration_session import read_session

    sess = read_session(session)
    cal = calibrate_session(sess, object=object, model=model, lab_frame=lab_frame, progress=progress,
                            cancel=cancel)
    if cancel is not None and cancel():
        raise CalibrationCancelled("cancelled before saving")
    return save_session_calibration(study, cal, series=series, trials=trials, session_path=session), cal
