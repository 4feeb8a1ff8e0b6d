"""Pose exports of a study trial, by format name: what *File → Export…*, ``talus export`` and
the trial report use.

:func:`available_formats` maps a format name to a :class:`PoseFormat`: its file suffix (``""``
for a folder of files, one per bone), a one-line ``label`` for menus, a ``description`` that
says which coordinate frame the numbers are in, and a writer ``write(path, poses, trial,
**options)`` (``poses``: bone -> ``(n_frames, 4, 4)`` ``T_lab_from_bone``, mm, NaN for
untracked frames). Every writer writes atomically.

Two ``.tra`` formats
--------------------
Autoscoper's ``.tra`` layout (a row of 16 numbers per frame and bone) is written in two frames,
and the names say which:

* ``tra-talus`` — Talus's ``T_lab_from_bone``: the bone's CT *physical* frame (the file's
  origin, spacing and direction) to the lab, as :meth:`core.study.Trial.export_tra` writes
  them. Talus reads them back as they are; **Autoscoper does not** (it expects its own volume
  frame).
* ``tra-autoscoper`` — Autoscoper's volume frame (:mod:`core.io.autoscoper_pose`: its flip,
  the stack's corner and pivot), the file Autoscoper (and SlicerAutoscoperM) opens with the
  bones' TIFF stacks; ``talus export --format tra`` writes this one.

The old name ``tra`` still works here and means ``tra-talus`` (what it always wrote), but menus
list only the explicit names (:data:`ALIASES`).

The other built-in formats: CSV (row-major 4×4 per bone, or 6-DOF), JSON; then the formats of
:mod:`core.study.export_trial` (XROMM CSV, Slicer ``.tfm`` and JointTrack ``.jts`` folders, C3D,
OpenSim ``.mot``/``.trc``, JCS CSV) when that module is there.

Frame numbers are 0-based in Talus; a format that numbers frames from 1 says so in its label.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["ALIASES", "POSE_FORMATS", "PoseFormat", "available_formats", "default_path", "export_poses",
           "recording_rate", "trial_poses"]


@dataclass(frozen=True)
class PoseFormat:
    name: str
    suffix: str
    description: str
    write: Callable[..., None]
    label: str = ""  # short menu text; the description when empty

    @property
    def folder(self) -> bool:
        """Written as a folder of files (one per bone)."""
        return self.suffix == ""

    @property
    def text(self) -> str:
        return self.label or self.description


def _tra(path, poses, trial, **_):
    from ..tracking.kinematics import export_tra

    export_tra(path, poses)


def _csv(layout):
    def write(path, poses, trial, **_):
        from ..tracking.kinematics import export_csv

        export_csv(path, poses, layout=layout)

    return write


def _json(path, poses, trial, **_):
    from ..tracking.kinematics import export_json

    scores = {b: trial.scores(b) for b in poses} if trial is not None else None
    export_json(path, poses, scores=scores)


POSE_FORMATS: dict[str, PoseFormat] = {
    "tra-talus": PoseFormat(
        "tra-talus", ".tra",
        "T_lab_from_bone in Talus's frame (the CT file's physical frame to the lab, mm) in Autoscoper's "
        ".tra layout: 16 numbers (row-major 4x4) per bone, a row per frame. Not Autoscoper's volume "
        "frame: for Autoscoper use tra-autoscoper.", _tra,
        "Talus-frame .tra (T_lab_from_bone; not for Autoscoper)"),
    "csv": PoseFormat("csv", ".csv", "CSV: frame (0-based), then the row-major 4x4 T_lab_from_bone per bone "
                      "(mm)", _csv("matrix"), "CSV, 4x4 T_lab_from_bone per bone"),
    "csv-6dof": PoseFormat("csv-6dof", ".csv", "CSV: frame (0-based), then tx, ty, tz (mm) and xyz Euler "
                           "angles (deg) of T_lab_from_bone per bone", _csv("6dof"),
                           "CSV, 6-DOF (mm, xyz Euler deg) per bone"),
    "json": PoseFormat("json", ".json", "JSON: T_lab_from_bone and scores per bone and frame", _json,
                       "JSON, poses and scores"),
}

#: Old names still accepted by :func:`export_poses`: ``tra`` is ``tra-talus``.
ALIASES = {"tra": "tra-talus"}

_OPTIONAL = {
    # export_trial name: (our name, suffix, label, description)
    "tra": ("tra-autoscoper", ".tra", "Autoscoper .tra (Autoscoper's volume frame)",
            "Autoscoper .tra in Autoscoper's volume frame (its flip, the stack's corner and pivot), "
            "16 numbers per bone a row per frame: opens in Autoscoper and SlicerAutoscoperM with the "
            "bones' TIFF stacks (talus export --format tra)."),
    "xromm-csv": ("xromm-csv", ".csv", "XMALab / XROMM rigid-body CSV (Maya)",
                  "XMALab's rigid-body transformation CSV (<bone>_R11 ... _1 columns, frames from 1), "
                  "T_lab_from_bone: Maya's XROMM tools import it."),
    "tfm": ("tfm", "", "Slicer .tfm, one per bone (one frame; a folder)",
            "One ITK .tfm per bone (<bone>.tfm) of one frame, the lab as Slicer's world: a folder."),
    "jts": ("jts", "", "JointTrack .jts, one per bone (camera 1's frame; a folder)",
            "One JointTrack .jts per bone in the first camera's frame: a folder."),
    "c3d": ("c3d", ".c3d", "C3D with 4x4 rotations (Visual3D)",
            "C3D with each bone's 4x4 rotation and axis points (Visual3D)."),
    "mot": ("mot", ".mot", "OpenSim .mot kinematics (Z-X-Y angles, metres)",
            "OpenSim coordinates of every bone: Z-X-Y angles (deg) and translations (m)."),
    "trc": ("trc", ".trc", "OpenSim .trc markers (origin and 10 mm axis points)",
            "OpenSim markers: each bone's origin and points 10 mm along its axes (mm, frames from 1)."),
    "jcs": ("jcs", ".csv", "Joint angles, Grood-Suntay JCS CSV",
            "Grood-Suntay angles of the default joints from principal-axes anatomical frames."),
}


def _optional() -> dict[str, PoseFormat]:
    """The formats of :func:`core.study.export_trial.export_trial` when that module is present."""
    try:
        from .export_trial import FORMATS, export_trial
    except ImportError:
        return {}
    out = {}
    for fmt in FORMATS:
        name, suffix, label, description = _OPTIONAL.get(fmt, (fmt, "", fmt, f"talus export --format {fmt}"))

        def write(path, poses, trial, fmt=fmt, **options):
            export_trial(trial._study, trial.name, fmt, path, bones=list(poses), poses=poses, **options)

        out[name] = PoseFormat(name, suffix, description, write, label)
    return out


def available_formats() -> dict[str, PoseFormat]:
    """:data:`POSE_FORMATS` and the optional :mod:`core.io` writers present in this install (the
    old names of :data:`ALIASES` are not listed)."""
    opt = _optional()
    first = {k: f for k, f in (("tra-autoscoper", opt.get("tra-autoscoper")),
                                ("tra-talus", POSE_FORMATS["tra-talus"])) if f is not None}
    return {**first, **POSE_FORMATS, **opt}  # the two .tra side by side, Autoscoper's first


def default_path(study_folder: str | os.PathLike, trial: str, fmt: str) -> Path:
    """Where an export of ``trial`` as ``fmt`` goes unless told otherwise (*File → Export…* and
    ``talus export``): ``<study>/exports/<trial>_<fmt><suffix>``, a folder ``<trial>_<fmt>`` for the
    formats written one file per bone. The format's name is in the file's, so two formats (the
    4x4 CSV and XMALab's CSV, the two ``.tra``) never write the same file."""
    formats = available_formats()
    fmt = ALIASES.get(fmt, fmt)
    if fmt not in formats:
        raise ValueError(f"fmt: expected one of {sorted(formats)}, got {fmt!r}")
    return Path(study_folder) / "exports" / f"{trial}_{fmt}{formats[fmt].suffix}"


def recording_rate(study, trial: str, default: float = 100.0) -> float:
    """The frame rate of ``trial`` (Hz) for the formats that record one: an imported XMALab
    trial's recording speed (``settings["imported_from"]``), else ``default``."""
    imp = study.settings.get("imported_from") or {}
    try:
        rate = float(imp["trials"][trial]["recording_speed_hz"])
    except (KeyError, TypeError, ValueError):
        return float(default)
    return rate if rate > 0 and np.isfinite(rate) else float(default)


def trial_poses(trial, bones=None) -> dict[str, np.ndarray]:
    """``{bone: (n_frames, 4, 4)}`` recorded poses of a :class:`core.study.Trial` (NaN: none)."""
    names = list(trial.bones if bones is None else bones)
    if not names:
        raise ValueError(f"bones: expected at least one bone of trial {trial.name!r}")
    for b in names:
        if b not in trial.bones:
            raise ValueError(f"bones: trial {trial.name!r} has no bone {b!r} (has {list(trial.bones)})")
    return {b: trial.poses(b) for b in names}


def export_poses(trial, path: str | os.PathLike, fmt: str, *, bones=None, poses=None, **options) -> Path:
    """Write the poses of ``trial`` (a :class:`core.study.Trial`) as format ``fmt`` to ``path``.

    ``poses``: bone -> ``(n_frames, 4, 4)`` written instead of the recorded ones (the bones'
    ``bones``, default the trial's; e.g. the smoothed poses of
    :func:`core.tracking.smoothing_trial.smoothed_poses`). ``options`` go to the formats of
    :func:`core.study.export_trial.export_trial` (``rate``, ``frame``, ``camera``). Returns ``path``.
    """
    formats = available_formats()
    fmt = ALIASES.get(fmt, fmt)
    if fmt not in formats:
        raise ValueError(f"fmt: expected one of {sorted(formats)}, got {fmt!r}")
    p = Path(path)
    if not p.parent.is_dir():
        raise ValueError(f"path: the folder {p.parent} does not exist")
    if formats[fmt].folder:  # a folder of files (one per bone)
        p.mkdir(parents=False, exist_ok=True)
    chosen = trial_poses(trial, bones)
    if poses is not None:
        chosen = {b: np.asarray(poses[b], float) for b in chosen}
    formats[fmt].write(p, chosen, trial, **options)
    return p
