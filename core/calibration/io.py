"""Calibration files: the versioned Talus calibration (JSON), MayaCam 1.0/2.0 and DLT CSV.

Talus calibration file (``*.json``, UTF-8, written atomically)::

    {
      "format": "talus-calibration", "version": 1,
      "units": {"length": "mm", "angle": "rad", "image": "px"},
      "conventions": "x ~ K [R | t] X; (u, v) = (column, row), origin at the centre of the
                      top-left pixel; R, t map lab -> camera; source = -R^T t",
      "created": "2025-01-01T12:00:00+00:00",
      "cameras": [{"name", "width", "height", "pixel_size_mm", "K", "R", "t",
                   "source_mm", "sid_mm", "std": {"f_px", "cu_px", "cv_px", "source_mm", "sid_mm"}}],
      "quality": {"method", "rms_px", "sigma0", "n_frames", "n_observations", "n_outliers"},
      "metadata": {...}
    }

``K``, ``R``, ``t`` are authoritative; ``source_mm`` and ``sid_mm`` are derived and only
written for the reader's convenience. A file of a newer version is refused with a clear message;
older versions are migrated when read (none yet: version 1 is the first).

Interop: MayaCam 1.0 / 2.0 (XMALab, Autoscoper) through :mod:`core.geometry.mayacam`, and
11-coefficient DLT CSV files (XMALab / DLTdv / easyWand) through :mod:`core.io.xmalab`.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..geometry.camera import Camera, Rig
from ..geometry.mayacam import rig_from_mayacam, write_mayacam
from ..io.atomic import atomic_write_json
from ..io.xmalab import dlt_csv_from_rig, rig_from_dlt_csv
from .bundle import BundleResult

__all__ = ["CalibrationFile", "export_rig", "load_calibration", "read_dlt_csv_rig", "read_mayacam_rig",
           "save_calibration"]

FORMAT = "talus-calibration"
VERSION = 1
_CONVENTIONS = ("x ~ K [R | t] X; (u, v) = (column, row), origin at the centre of the top-left "
                "pixel; R, t map lab -> camera; X-ray source = -R^T t; lab frame defined by the "
                "calibration object")


@dataclass(frozen=True, eq=False)
class CalibrationFile:
    """Content of a Talus calibration file: the ``rig``, per-camera ``std`` dicts (may be
    empty), ``quality`` and free ``metadata``, the file's ``version`` and ``created`` stamp."""

    rig: Rig
    std: list = field(default_factory=list)
    quality: dict = field(default_factory=dict)
    metadata: dict = field(default_factory=dict)
    version: int = VERSION
    created: str = ""


def _num(x) -> float | None:
    x = float(x)
    return x if np.isfinite(x) else None


def _camera_dict(cam: Camera, std: dict | None) -> dict:
    d = {"name": cam.name, "width": cam.width, "height": cam.height, "pixel_size_mm": cam.pixel_size,
         "K": cam.K.tolist(), "R": cam.R.tolist(), "t": cam.t.tolist(),
         "source_mm": cam.source.tolist(),
         "sid_mm": cam.sid if cam.pixel_size is not None else None}
    if std:
        d["std"] = {"f_px": _num(std["f"]), "cu_px": _num(std["cu"]), "cv_px": _num(std["cv"]),
                    "source_mm": [_num(v) for v in std["source"]],
                    "sid_mm": _num(std["sid"]) if "sid" in std else None}
    return d


def save_calibration(path, calibration: Rig | BundleResult, *, metadata: dict | None = None) -> None:
    """Write a calibrated rig (or a bundle adjustment result with its uncertainties and
    quality figures) as a Talus calibration file, atomically.

    Raises
    ------
    ValueError
        If ``calibration`` is a failed :class:`BundleResult` or neither type.
    """
    if isinstance(calibration, BundleResult):
        if not calibration.ok:
            raise ValueError(f"calibration: the bundle adjustment failed ({calibration.reason}); "
                             "nothing to save")
        rig, stds = calibration.rig, calibration.camera_std
        quality = {"method": "bundle adjustment", "rms_px": calibration.rms_px,
                   "sigma0": calibration.sigma0,
                   "n_frames": int(np.unique(calibration.frame_index).size),
                   "n_observations": len(calibration.frame_index),
                   "n_outliers": int(calibration.outliers.sum())}
    elif isinstance(calibration, Rig):
        rig, stds, quality = calibration, [None] * len(calibration), {}
    else:
        raise ValueError(f"calibration: expected a Rig or a BundleResult, got {type(calibration).__name__}")
    doc = {"format": FORMAT, "version": VERSION,
           "units": {"length": "mm", "angle": "rad", "image": "px"}, "conventions": _CONVENTIONS,
           "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
           "cameras": [_camera_dict(c, s) for c, s in zip(rig, stds, strict=True)],
           "quality": {k: (_num(v) if isinstance(v, float) else v) for k, v in quality.items()},
           "metadata": dict(metadata or {})}
    atomic_write_json(path, doc)


def _migrate(doc: dict, path: Path) -> dict:
    """Bring an older document to the current version (none exist yet)."""
    ver = doc.get("version")
    if not isinstance(ver, int) or ver < 1:
        raise ValueError(f"{path}: version: expected a positive integer, got {ver!r}")
    if ver > VERSION:
        raise ValueError(f"{path}: written by a newer Talus (calibration file version {ver}); this "
                         f"version reads up to {VERSION}")
    return doc


def load_calibration(path) -> CalibrationFile:
    """Read a Talus calibration file (see the module docstring).

    Raises
    ------
    ValueError
        Naming the file and the key on a missing file, invalid JSON, wrong format, a newer
        version, wrong units or a malformed camera.
    """
    p = Path(os.fspath(path))
    if not p.is_file():
        raise ValueError(f"path: no such calibration file: {p}")
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{p}: not a JSON calibration file ({exc})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ValueError(f"{p}: format: expected {FORMAT!r}")
    doc = _migrate(doc, p)
    units = doc.get("units", {})
    if units.get("length") != "mm" or units.get("image", "px") != "px":
        raise ValueError(f"{p}: units: expected lengths in mm and images in px, got {units!r}")
    cams, stds = [], []
    for i, c in enumerate(doc.get("cameras") or []):
        try:
            cams.append(Camera(np.array(c["K"], float), np.array(c["R"], float), np.array(c["t"], float),
                               int(c["width"]), int(c["height"]), c.get("pixel_size_mm"),
                               str(c.get("name", f"cam{i + 1:02d}"))))
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{p}: cameras[{i}]: {exc}") from None
        stds.append(c.get("std") or {})
    if not cams:
        raise ValueError(f"{p}: cameras: expected at least one camera")
    return CalibrationFile(Rig(tuple(cams)), stds, doc.get("quality") or {}, doc.get("metadata") or {},
                           int(doc["version"]), str(doc.get("created", "")))


def read_mayacam_rig(paths: Sequence, *, pixel_size=None) -> Rig:
    """A rig from MayaCam 1.0/2.0 files (one per camera, :func:`core.geometry.rig_from_mayacam`)."""
    return rig_from_mayacam(list(paths), pixel_size=pixel_size)


def read_dlt_csv_rig(path, image_sizes, *, pixel_size=None) -> Rig:
    """A rig from an 11-coefficient DLT CSV in DLTdv coordinates (:mod:`core.io.xmalab`)."""
    return rig_from_dlt_csv(path, image_sizes, convention="dltdv", pixel_size=pixel_size)


def export_rig(calibration: Rig | BundleResult, folder, *, stem: str = "calibration",
               formats: Sequence[str] = ("talus", "mayacam2", "mayacam1", "dlt")) -> dict[str, list[Path]]:
    """Write a calibration in several formats into ``folder`` (created if missing).

    ``"talus"``: ``<stem>.json``; ``"mayacam2"``: ``<stem>_cam01.txt``, ...; ``"mayacam1"``:
    ``<stem>_cam01.csv``, ... (single focal length: the mean of fx, fy); ``"dlt"``:
    ``<stem>_DLTcoefs.csv`` (DLTdv image coordinates). Returns the paths per format.
    """
    rig = calibration.rig if isinstance(calibration, BundleResult) else calibration
    if not isinstance(rig, Rig):
        raise ValueError("calibration: expected a Rig or a successful BundleResult")
    known = {"talus", "mayacam2", "mayacam1", "dlt"}
    bad = set(formats) - known
    if bad:
        raise ValueError(f"formats: unknown {sorted(bad)}, expected some of {sorted(known)}")
    out_dir = Path(folder)
    out_dir.mkdir(parents=True, exist_ok=True)
    out: dict[str, list[Path]] = {}
    if "talus" in formats:
        p = out_dir / f"{stem}.json"
        save_calibration(p, calibration)
        out["talus"] = [p]
    for fmt, ext, ver in (("mayacam2", "txt", 2), ("mayacam1", "csv", 1)):
        if fmt in formats:
            out[fmt] = []
            for k, cam in enumerate(rig, start=1):
                p = out_dir / f"{stem}_cam{k:02d}.{ext}"
                write_mayacam(cam, p, version=ver, average_focal=True)
                out[fmt].append(p)
    if "dlt" in formats:
        p = out_dir / f"{stem}_DLTcoefs.csv"
        dlt_csv_from_rig(rig, p, convention="dltdv")
        out["dlt"] = [p]
    return out
