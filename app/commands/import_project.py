"""``talus import``: open an Autoscoper project as a Talus study.

Usage::

    talus import PROJECT.cfg --out STUDY [--tra POSES.tra] [--trial NAME] [--hu-offset -1024]

The study references the project's files (cameras, radiograph folders, volumes); poses of a
``.tra`` are converted from Autoscoper's volume frame and saved as keyframes, so ``talus track``
can start from them. JSON summary on stdout.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ._shared import EXIT_OK, PROG, CliError, print_json

__all__ = ["HELP", "configure", "run"]

HELP = "open an Autoscoper project (.cfg) as a study"


def configure(p: argparse.ArgumentParser) -> None:
    p.description = ("Create a study from an Autoscoper trial configuration (.cfg 1.0-1.2): its "
                     "cameras, radiograph folders and volumes are referenced, not copied; poses of "
                     "a .tra become keyframes (T_lab_from_bone).")
    p.add_argument("project", metavar="PROJECT", help="Autoscoper .cfg")
    p.add_argument("--out", required=True, metavar="STUDY", help="new study folder")
    p.add_argument("--tra", default=None, help="Autoscoper .tra poses (one 16- or 6-value block per volume)")
    p.add_argument("--trial", default="trial", help="name of the study's trial (default 'trial')")
    p.add_argument("--hu-offset", type=float, default=-1024.0,
                   help="added to the stacks' values to get HU (default -1024: CT number + 1024)")
    p.set_defaults(run=run)


def run(a: argparse.Namespace) -> int:
    src = Path(a.project).expanduser()
    if not src.is_file():
        raise CliError(f"PROJECT: no such file {src}")
    out = Path(a.out).expanduser()
    if (out / "study.json").exists():
        raise CliError(f"--out: {out} already holds a study")
    import numpy as np

    from core.study.import_project import import_project

    with import_project(src, out, trial=a.trial, tra=a.tra, hu_offset=a.hu_offset) as study:
        tr = study.trial(a.trial)
        keyframes = {b: int((~np.isnan(tr.poses(b)).any(axis=(1, 2))).sum()) for b in study.bones}
        summary = {"study": str(study.folder), "trial": a.trial, "frames": tr.n_frames,
                   "bones": list(study.bones), "keyframes": keyframes}
    print(f"{PROG} import: created {out}", file=sys.stderr)
    print_json(summary)
    return EXIT_OK
