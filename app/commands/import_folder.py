"""``talus import``: a study from a lab's collection folder (or an Autoscoper project).

Usage::

    talus import FOLDER [--out STUDY] [--bit-depth N] [--trial NAME] [--bones a,b,...]
    talus import PROJECT.cfg --out STUDY [--tra POSES.tra] ...   (app.commands.import_project)

FOLDER holds two views (folders of TIFF frames or .cine files), the cameras (two MayaCam files
or a DLT CSV) and one CT (or a CT and a label map, or one CT per bone):
:func:`core.study.import_folder.scan_folder` reads them and detects the frames' bit depth (cine
header, TIFF tags, the frames' maximum); the study is written by
:func:`~core.study.import_folder.make_study_from_folder` (default ``FOLDER/study``), only when
nothing is wrong. A bit depth guessed from the values is said on stderr with how to override it
(``--bit-depth``); views whose pixels are mostly unusable at that depth are reported before any
tracking. JSON summary on stdout. Exit status: 0 done, 1 bad input (every problem named, nothing
written).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ._shared import EXIT_OK, PROG, CliError, print_json

__all__ = ["HELP", "bones_by_name", "configure", "run"]

HELP = "make a study from a lab folder or a .cfg/.xma project"


def configure(p: argparse.ArgumentParser) -> None:
    p.description = ("Make a study from what a lab has after a collection: two frame folders or cine "
                     "files, the cameras (MayaCam or DLT CSV) and the CT (a CT, a CT and a label map, or "
                     "one CT per bone), found anywhere in FOLDER. The frames' bit depth is detected (cine "
                     "header, TIFF tags or the frames' maximum) and printed; give --bit-depth when it is "
                     "wrong. CT orientation: LPS inside Talus (NIfTI headers store RAS and are converted "
                     "on reading). An Autoscoper .cfg (--tra, --hu-offset) or an XMALab .xma (--search) "
                     "is imported as a study too.")
    p.add_argument("source", metavar="FOLDER|PROJECT",
                   help="collection folder, Autoscoper .cfg or XMALab .xma")
    p.add_argument("--out", "--study", default=None, metavar="STUDY", dest="out",
                   help="new study folder (default FOLDER/study)")
    p.add_argument("--bit-depth", type=int, default=None, choices=(8, 10, 12, 14, 16),
                   help="significant bits of the frames (default: detected)")
    p.add_argument("--trial", default=None,
                   help="name of the study's trial (default trial1; 'trial' for .cfg)")
    p.add_argument("--bones", default=None,
                   help="comma-separated bone names, in the order of the label map's labels or of the "
                        "per-bone CTs (default: bone<label> / the CT file names)")
    p.add_argument("--check", action="store_true", help="only say what was found; write nothing")
    p.add_argument("--tra", default=None, help="(.cfg) Autoscoper .tra poses")
    p.add_argument("--hu-offset", type=float, default=-1024.0, help="(.cfg) added to the stacks' values")
    p.add_argument("--search", action="append", default=[], metavar="DIR",
                   help="(.xma) a folder to look for the trials' images in (repeatable)")
    p.set_defaults(run=run)


def bones_by_name(names: list[str], default: dict) -> dict:
    """``--bones`` names -> the scan's bones (``default``: file-name bones of per-bone CTs, or
    ``bone<label>`` -> label), in the scan's order. A name that is one of the default names (case
    aside) takes that bone: ``--bones talus,calcaneus`` over ``calcaneus.mha`` and ``talus.mha``
    (listed alphabetically) gave the talus the calcaneus's CT, and so did ``--bones talus,tibia``
    or ``Talus,Calcaneus``. The other names take the remaining bones in order."""
    keys = list(default)
    folded = {k.casefold(): k for k in keys}
    taken: dict[str, str] = {}  # default name -> given name
    for n in names:
        k = folded.get(n.casefold())
        if k is not None and k not in taken:
            taken[k] = n
    rest = iter(n for n in names if n not in taken.values())
    given = {k: taken[k] if k in taken else next(rest) for k in keys}
    return {given[k]: default[k] for k in keys}


def run(a: argparse.Namespace) -> int:
    src = Path(a.source).expanduser()
    if src.is_file() and src.suffix.lower() in (".cfg", ".xma"):
        from . import import_project

        if a.out is None:
            raise CliError("--out: required for an Autoscoper or XMALab project")
        a.project, a.trial = str(src), a.trial or "trial"
        return import_project.run(a)
    if src.is_file():
        what = ("a Talus study's manifest: the study exists already (track it, or open it with "
                f"'{PROG} gui --demo {src.parent}')" if src.name == "study.json" else "a file")
        raise CliError(f"FOLDER: {src} is {what}; expected a collection folder, an Autoscoper .cfg "
                       "or an XMALab .xma")
    if not src.is_dir():
        raise CliError(f"FOLDER: no folder at {src} (nor an Autoscoper .cfg or XMALab .xma file)")
    from core.study.import_folder import ImportFolderError, make_study_from_folder, scan_folder

    scan = scan_folder(src, bit_depth=a.bit_depth)
    summary = scan.summary()
    for v in scan.views:
        how = "given" if a.bit_depth else v.bit_depth.text
        print(f"{PROG} import: {v.path}: {a.bit_depth or v.bit_depth.bits}-bit frames ({how})",
              file=sys.stderr)
    if scan.questions and not a.bit_depth:
        print(f"{PROG} import: not read from the files (defaults used): {scan.questions}; "
              "override with --bit-depth / --bones", file=sys.stderr)
    for w in scan.warnings:
        print(f"{PROG} import: warning: {w}", file=sys.stderr)
    if scan.problems:
        raise CliError(str(ImportFolderError(src, scan.problems)))
    if a.check:
        print_json({**summary, "study": None})
        return EXIT_OK
    bones = None
    if a.bones:
        names = [b.strip() for b in a.bones.split(",") if b.strip()]
        default = scan.bones()
        if len(names) != len(default):
            raise CliError(f"--bones: expected {len(default)} names (for {list(default)}), got {names}")
        if len(set(names)) != len(names):
            raise CliError(f"--bones: a name given twice in {names}")
        bones = bones_by_name(names, default)
        sources = (list(scan.bone_volumes.values()) if scan.bone_volumes else
                   [f"label {v} of {scan.labels}" if scan.labels is not None else scan.ct
                    for v in default.values()])
        for name, source in zip(bones, sources, strict=True):
            print(f"{PROG} import: bone {name} from {source}", file=sys.stderr)
    out = Path(a.out).expanduser() if a.out else src / "study"
    try:
        made = make_study_from_folder(scan, out, bit_depth=a.bit_depth, bones=bones,
                                      trial=a.trial or "trial1")
    except ImportFolderError as exc:
        raise CliError(str(exc)) from None
    print(f"{PROG} import: created {made}", file=sys.stderr)
    print_json({**summary, "study": str(made), "bit_depth": a.bit_depth or scan.bit_depth,
                "trial": a.trial or "trial1", "bones": list(bones or scan.bones())})
    return EXIT_OK
