"""``talus export``: write a trial's poses for the peers' and downstream tools.

Usage::

    talus export STUDY --trial T --format F [--out PATH] [--bones a,b] [--rate HZ] [--frame F]
                 [--camera C]

Formats (see :mod:`core.study.export_trial` and :mod:`core.study.exports`): ``tra`` or
``tra-autoscoper``: Autoscoper ``.tra`` in Autoscoper's volume frame; ``tra-talus``: the same
layout holding Talus's ``T_lab_from_bone`` (the CT's physical frame; what ``Trial.export_tra``
writes; not for Autoscoper); XMALab / XROMM rigid-body CSV, one Slicer ``.tfm`` per bone (one
frame), one JointTrack ``.jts`` per bone (a camera's frame), C3D (4x4 rotations), OpenSim
``.mot`` / ``.trc``, JCS angle CSV; CSV of 4x4 or 6-DOF poses, JSON. Default output: what
*File → Export…* proposes, ``STUDY/exports/<trial>_<format>.<ext>`` (a folder
``<trial>_<format>`` for tfm and jts; :func:`core.study.exports.default_path`), so no two formats
write the same file; ``tra`` is named ``tra-autoscoper`` there. An ``--out`` that is an existing
folder gets that file name inside it (tfm and jts write their files into ``--out``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ._shared import EXIT_OK, PROG, names, print_json, study_folder

__all__ = ["HELP", "configure", "posed_frames", "run"]

HELP = "write a trial's poses for other tools (.tra, C3D, .mot...)"
TRIAL_FORMATS = ("tra", "xromm-csv", "tfm", "jts", "c3d", "mot", "trc", "jcs")  # export_trial's names
POSE_FORMATS = ("tra-talus", "csv", "csv-6dof", "json")  # core.study.exports
FORMATS = (*TRIAL_FORMATS, "tra-autoscoper", *POSE_FORMATS)


def configure(p: argparse.ArgumentParser) -> None:
    p.description = ("Write the poses of a study trial in another tool's format. NaN / empty "
                     "where a bone has no pose. JSON summary (files written) on stdout.")
    p.add_argument("study", metavar="STUDY", help="study folder (study.json)")
    p.add_argument("--trial", required=True, help="trial name")
    p.add_argument("--format", required=True, choices=FORMATS, dest="fmt",
                   help="tra = tra-autoscoper (Autoscoper's volume frame); tra-talus: T_lab_from_bone")
    p.add_argument("--out", default=None, metavar="PATH",
                   help="output file (folder for tfm, jts); an existing folder gets the default name "
                        "inside it. Default: STUDY/exports/TRIAL_FORMAT.EXT (FORMAT tra-autoscoper for tra)")
    p.add_argument("--bones", default=None, help="comma-separated bones (default: the trial's)")
    p.add_argument("--rate", type=float, default=None,
                   help="frame rate, Hz (default: an imported XMALab trial's recording speed, else 100)")
    p.add_argument("--frame", type=int, default=None, help="tfm: the frame (default the first with poses)")
    p.add_argument("--camera", type=int, default=0, help="jts: camera index (default 0)")
    p.set_defaults(run=run)


def run(a: argparse.Namespace) -> int:
    folder = study_folder(a.study)
    from core.study import Study
    from core.study.export_trial import export_trial
    from core.study.exports import default_path

    fmt = "tra" if a.fmt == "tra-autoscoper" else a.fmt
    bones = names(a.bones) or None
    # the name the window's dialog proposes; 'tra' here is Autoscoper's frame (tra-talus's alias there)
    default = default_path(folder, a.trial, "tra-autoscoper" if fmt == "tra" else fmt)
    out = Path(a.out).expanduser() if a.out else default
    if fmt not in ("tfm", "jts") and out.is_dir():  # a folder given: the default file name inside it
        out = out / default.name
    with Study.open(folder, mode="r") as study:
        study.trial(a.trial)  # a misspelt trial refused before the output's folder is made
        if fmt not in ("tfm", "jts"):
            out.parent.mkdir(parents=True, exist_ok=True)
        if a.rate is None:
            from core.study.exports import recording_rate

            a.rate = recording_rate(study, a.trial)
        if fmt in POSE_FORMATS:
            from core.study.exports import export_poses

            paths = [export_poses(study.trial(a.trial), out, fmt, bones=bones)]
        else:
            paths = export_trial(study, a.trial, fmt, out, bones=bones, rate=a.rate, frame=a.frame,
                                 camera=a.camera)
        posed, n = posed_frames(study.trial(a.trial), bones)
    counts = ", ".join(f"{b} {k}" for b, k in posed.items())
    print(f"{PROG} export: wrote {len(paths)} file(s); frames with a pose, of {n}: {counts}", file=sys.stderr)
    if not any(posed.values()):
        print(f"{PROG} export: WARNING: no bone has a pose in trial {a.trial!r}: the file holds no numbers "
              "(NaN / empty); track the trial or set keyframes first", file=sys.stderr)
    print_json({"format": a.fmt, "files": [str(p) for p in paths], "frames": n, "frames_with_pose": posed})
    return EXIT_OK


def posed_frames(trial, bones=None) -> tuple[dict[str, int], int]:
    """``({bone: frames with a pose}, frames)`` of what an export of ``trial`` holds (NaN elsewhere)."""
    import numpy as np

    n = trial.n_frames
    return {b: int(np.isfinite(trial.poses(b)).all(axis=(1, 2)).sum()) for b in (bones or trial.bones)}, n
