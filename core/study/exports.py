"""Pose exports of a study trial, by format name: what *File → Export…* and the trial report use.

:data:`POSE_FORMATS` maps a format name to its file suffix, a description and a writer
``write(path, poses, trial)`` (``poses``: bone -> ``(n_frames, 4, 4)`` ``T_lab_from_bone``, mm,
NaN for untracked frames). Built in: Autoscoper ``.tra``, CSV (row-major 4×4 per bone, or 6-DOF),
JSON; the formats of ``talus export`` (:mod:`core.study.export_trial`: XROMM CSV, .tfm, .jts,
C3D, OpenSim .mot/.trc, JCS CSV, Autoscoper-frame .tra) are added when that module is there
(:func:`available_formats`). Every writer writes atomically.

Frame numbers are 0-based in Talus; a format that numbers frames from 1 says so in its own docs.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["POSE_FORMATS", "PoseFormat", "available_formats", "export_poses", "trial_poses"]


@dataclass(frozen=True)
class PoseFormat:
    name: str
    suffix: str
    description: str
    write: Callable[[Path, Mapping[str, np.ndarray], object], None]


def _tra(path, poses, trial):
    from ..tracking.kinematics import export_tra

    export_tra(path, poses)


def _csv(layout):
    def write(path, poses, trial):
        from ..tracking.kinematics import export_csv

        export_csv(path, poses, layout=layout)

    return write


def _json(path, poses, trial):
    from ..tracking.kinematics import export_json

    scores = {b: trial.scores(b) for b in poses} if trial is not None else None
    export_json(path, poses, scores=scores)


POSE_FORMATS: dict[str, PoseFormat] = {
    "tra": PoseFormat("tra", ".tra", "Autoscoper .tra (row-major 4x4 per bone, one row per frame)", _tra),
    "csv": PoseFormat("csv", ".csv", "CSV, frame then row-major 4x4 T_lab_from_bone per bone (mm)",
                      _csv("matrix")),
    "csv-6dof": PoseFormat("csv-6dof", ".csv", "CSV, frame then tx, ty, tz (mm) and xyz Euler angles (deg) "
                           "per bone", _csv("6dof")),
    "json": PoseFormat("json", ".json", "JSON, poses and scores per bone", _json),
}


_SUFFIX = {"xromm-csv": ".csv", "tfm": "", "jts": "", "c3d": ".c3d", "mot": ".mot", "trc": ".trc",
           "jcs": ".csv", "tra": ".tra"}


def _optional() -> dict[str, PoseFormat]:
    """The formats of :func:`core.study.export_trial.export_trial` (``talus export``: XROMM CSV,
    Slicer .tfm and JointTrack .jts folders, C3D, OpenSim .mot/.trc, JCS CSV, and Autoscoper .tra
    in Autoscoper's volume frame as ``tra-autoscoper``) when that module is present."""
    try:
        from .export_trial import FORMATS, export_trial
    except ImportError:
        return {}
    out = {}
    for fmt in FORMATS:
        name = "tra-autoscoper" if fmt == "tra" else fmt

        def write(path, poses, trial, fmt=fmt):
            export_trial(trial._study, trial.name, fmt, path, bones=list(poses))

        what = ", a folder of files" if _SUFFIX.get(fmt) == "" else ""
        out[name] = PoseFormat(name, _SUFFIX.get(fmt, ""), f"{name}: as talus export --format {fmt}{what}",
                               write)
    return out


def available_formats() -> dict[str, PoseFormat]:
    """:data:`POSE_FORMATS` and the optional :mod:`core.io` writers present in this install."""
    return {**POSE_FORMATS, **_optional()}


def trial_poses(trial, bones=None) -> dict[str, np.ndarray]:
    """``{bone: (n_frames, 4, 4)}`` recorded poses of a :class:`core.study.Trial` (NaN: none)."""
    names = list(trial.bones if bones is None else bones)
    for b in names:
        if b not in trial.bones:
            raise ValueError(f"bones: trial {trial.name!r} has no bone {b!r} (has {list(trial.bones)})")
    return {b: trial.poses(b) for b in names}


def export_poses(trial, path: str | os.PathLike, fmt: str, *, bones=None) -> Path:
    """Write the poses of ``trial`` (a :class:`core.study.Trial`) as format ``fmt`` to ``path``."""
    formats = available_formats()
    if fmt not in formats:
        raise ValueError(f"fmt: expected one of {sorted(formats)}, got {fmt!r}")
    p = Path(path)
    if formats[fmt].suffix == "":  # a folder of files (one per bone)
        p.mkdir(parents=False, exist_ok=True)
    if not p.parent.is_dir():
        raise ValueError(f"path: the folder {p.parent} does not exist")
    formats[fmt].write(p, trial_poses(trial, bones), trial)
    return p
