"""``talus export``: write a trial's poses for the peers' and downstream tools.

Usage::

    talus export STUDY --trial T --format F [--out PATH] [--bones a,b] [--rate HZ] [--frame F]
                 [--camera C] [--smooth [--threshold HU]]

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

``--smooth`` (:data:`SMOOTH_HELP`; off by default) writes each bone's poses smoothed over the
trial in place of the tracked ones, in any format: the poses of *File → Export…*'s *Smoothed
poses* (:func:`core.tracking.smoothing_trial.smoothed_poses`, computed afresh from the journal;
the rotation centre the bone model's centroid at ``--threshold``, tracking's 200 HU by default). A
bone with too few poses to smooth is written as NaN, with a warning; the JSON summary's
``"smoothed"`` is true and its ``frames_with_pose`` counts the smoothed poses written.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ._shared import EXIT_OK, PROG, names, print_json, study_folder

__all__ = ["HELP", "SMOOTH_HELP", "configure", "posed_frames", "run"]

HELP = "write a trial's poses for other tools (.tra, C3D, .mot...)"
TRIAL_FORMATS = ("tra", "xromm-csv", "tfm", "jts", "c3d", "mot", "trc", "jcs")  # export_trial's names
POSE_FORMATS = ("tra-talus", "csv", "csv-6dof", "json")  # core.study.exports
FORMATS = (*TRIAL_FORMATS, "tra-autoscoper", *POSE_FORMATS)
#: ``--smooth``'s help (core.tracking.smoothing_trial.smoothed_poses, the dialog's Smoothed poses)
SMOOTH_HELP = ("write each bone's poses smoothed over the trial (a constant-acceleration Rauch-Tung-"
               "Striebel smoother, its smoothing and the confidence's scale from the data) instead of the "
               "tracked ones, as File > Export... 'Smoothed poses'; the journal's poses are not changed")


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
    p.add_argument("--smooth", action="store_true", help=SMOOTH_HELP)
    p.add_argument("--threshold", type=float, default=200.0,
                   help="--smooth: bone threshold, HU, of the model whose centroid is the rotation centre "
                        "(default 200, tracking's)")
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
        poses, unsmoothed = _smoothed(study, a.trial, bones, a.threshold) if a.smooth else (None, [])
        if fmt in POSE_FORMATS:
            from core.study.exports import export_poses

            paths = [export_poses(study.trial(a.trial), out, fmt, bones=bones, poses=poses)]
        else:
            paths = export_trial(study, a.trial, fmt, out, bones=bones, rate=a.rate, frame=a.frame,
                                 camera=a.camera, poses=poses)
        posed, n = posed_frames(study.trial(a.trial), bones, poses)
    for b in unsmoothed:
        print(f"{PROG} export: WARNING: {b} has too few poses to smooth: written as NaN", file=sys.stderr)
    counts = ", ".join(f"{b} {k}" for b, k in posed.items())
    print(f"{PROG} export: wrote {len(paths)} file(s); frames with a pose, of {n}: {counts}", file=sys.stderr)
    if not any(posed.values()):
        print(f"{PROG} export: WARNING: no bone has a pose in trial {a.trial!r}: the file holds no numbers "
              "(NaN / empty); track the trial or set keyframes first", file=sys.stderr)
    print_json({"format": a.fmt, "files": [str(p) for p in paths], "frames": n, "frames_with_pose": posed,
                **({"smoothed": True} if a.smooth else {})})
    return EXIT_OK


def _smoothed(study, trial: str, bones, threshold_hu: float) -> tuple[dict, list[str]]:
    """``--smooth``: bone -> the smoothed poses to write (:func:`core.tracking.smoothing_trial.
    smoothed_poses`), and the bones with poses that came back all NaN (too few to smooth)."""
    import numpy as np

    from core.tracking.smoothing_trial import smoothed_poses

    tr = study.trial(trial)
    names = list(bones or tr.bones)
    poses = smoothed_poses(study, trial, names, threshold_hu=threshold_hu)
    lost = [b for b in names if np.isfinite(tr.poses(b)).all(axis=(1, 2)).any()
            and not np.isfinite(poses[b]).all(axis=(1, 2)).any()]
    return poses, lost


def posed_frames(trial, bones=None, poses=None) -> tuple[dict[str, int], int]:
    """``({bone: frames with a pose}, frames)`` of what an export of ``trial`` holds (NaN elsewhere);
    ``poses``: bone -> the poses written instead of the recorded ones (``--smooth``)."""
    import numpy as np

    def of(b):
        return trial.poses(b) if poses is None else poses[b]

    n = trial.n_frames
    return {b: int(np.isfinite(of(b)).all(axis=(1, 2)).sum()) for b in (bones or trial.bones)}, n
