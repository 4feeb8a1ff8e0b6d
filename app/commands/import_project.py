"""``talus import``: open an Autoscoper or XMALab project as a Talus study.

Usage::

    talus import PROJECT.cfg --out STUDY [--tra POSES.tra] [--trial NAME] [--hu-offset -1024]
    talus import PROJECT.xma --out STUDY [--search DIR ...]

An Autoscoper ``.cfg``: the study references the project's files (cameras, radiograph folders,
volumes); poses of a ``.tra`` are converted from Autoscoper's volume frame and saved as
keyframes, so ``talus track`` can start from them (:func:`core.study.import_project.import_autoscoper`).

An XMALab ``.xma``: its cameras become a calibration, its undistortion grids the calibration's
correction, its trials reference their images (found under ``--search`` folders when the project
was moved), its markers a report (:func:`core.study.import_xma.import_xma`).

``--study`` is another name of ``--out``. JSON summary on stdout.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ._shared import EXIT_OK, PROG, CliError, print_json

__all__ = ["HELP", "configure", "run"]

HELP = "open an Autoscoper (.cfg) or XMALab (.xma) project as a study"


def configure(p: argparse.ArgumentParser) -> None:
    p.description = ("Create a study from an Autoscoper trial configuration (.cfg 1.0-1.2: its cameras, "
                     "radiograph folders and volumes are referenced, not copied; poses of a .tra become "
                     "keyframes, T_lab_from_bone) or an XMALab project (.xma: cameras, undistortion, "
                     "trials and markers).")
    p.add_argument("project", metavar="PROJECT", help="Autoscoper .cfg or XMALab .xma")
    p.add_argument("--out", "--study", required=True, metavar="STUDY", dest="out", help="new study folder")
    p.add_argument("--tra", default=None,
                   help=".cfg: Autoscoper .tra poses (one 16- or 6-value block per volume)")
    p.add_argument("--trial", default="trial", help=".cfg: name of the study's trial (default 'trial')")
    p.add_argument("--hu-offset", type=float, default=-1024.0,
                   help=".cfg: added to the stacks' values to get HU (default -1024: CT number + 1024)")
    p.add_argument("--search", action="append", default=[], metavar="DIR",
                   help=".xma: a folder to look for the trials' images in (repeatable)")
    p.set_defaults(run=run)


def run(a: argparse.Namespace) -> int:
    src = Path(a.project).expanduser()
    if not src.is_file():
        raise CliError(f"PROJECT: no such file {src}")
    out = Path(a.out).expanduser()
    if (out / "study.json").exists():
        raise CliError(f"--out: {out} already holds a study")
    suffix = src.suffix.lower()
    if suffix not in (".cfg", ".xma"):
        raise CliError(f"PROJECT: expected an Autoscoper .cfg or an XMALab .xma, got {src}")
    if suffix == ".xma":
        summary = _xma(src, out, a)
    else:
        if a.search:
            raise CliError("--search: only for an XMALab .xma")
        summary = _cfg(src, out, a)
    print(f"{PROG} import: created {out}", file=sys.stderr)
    print_json(summary)
    return EXIT_OK


def _cfg(src: Path, out: Path, a) -> dict:
    import numpy as np

    from core.study.import_project import import_project

    with import_project(src, out, trial=a.trial, tra=a.tra, hu_offset=a.hu_offset) as study:
        tr = study.trial(a.trial)
        keyframes = {b: int((~np.isnan(tr.poses(b)).any(axis=(1, 2))).sum()) for b in study.bones}
        return {"study": str(study.folder), "format": "autoscoper-cfg", "trial": a.trial,
                "frames": tr.n_frames, "bones": list(study.bones), "keyframes": keyframes}


def _xma(src: Path, out: Path, a) -> dict:
    if a.tra is not None:
        raise CliError("--tra: only for an Autoscoper .cfg")
    from core.study.import_xma import import_xma

    with import_xma(src, out, search=a.search) as study:
        return {"study": str(study.folder), "format": "xmalab-xma",
                "trials": {t: study.trial(t).n_frames for t in study.trials},
                "calibrations": list(study.calibrations),
                "markers": {t: len(study.read_report("markers", t)["markers"]) for t in study.trials}}
