"""``talus study …``: look after a study folder.

``talus study repair STUDY [--dry-run]`` salvages pose journals that fail their checksums:
every record whose checksum holds is kept, the rest are reported (and, without ``--dry-run``,
set aside by the library so the study opens again). The JSON report says what was kept and
what was dropped, per journal.

``talus study use-calibration STUDY NAME [--trials a,b]`` points trials (default: all) at a saved
calibration version such as ``session.v2`` (:func:`core.study.calibrations.use_calibration`):
what ``talus calibrate --trials`` (and the wizard's *Trials using it*) does at the end of a
calibration, without calibrating again. The JSON says each trial's calibration before and after.
"""

from __future__ import annotations

import argparse
import inspect
import sys
from pathlib import Path

from ._shared import EXIT_OK, PROG, CliError, print_json, stdout_to_stderr, study_folder
from ._shared import names as listed

HELP = "repair pose journals, choose trials' calibration"


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    repair = sub.add_parser(
        "repair", help="salvage damaged pose journals (keep every record whose checksum holds)",
        description="Check every pose journal of the study; keep each record whose checksum "
        "holds and report the rest. With --dry-run only report what would be done.")
    repair.add_argument("study", metavar="STUDY", help="study folder (study.json)")
    repair.add_argument("--dry-run", action="store_true",
                        help="report what would be kept and dropped; change nothing")
    repair.set_defaults(run=run_repair)
    use = sub.add_parser(
        "use-calibration", help="point trials at a saved calibration version (e.g. session.v2)",
        description="Point trials of the study (default: all) at a calibration the study holds, e.g. "
        "a version 'talus calibrate' saved. Tracking then reads their frames through its correction "
        "and rig.")
    use.add_argument("study", metavar="STUDY", help="study folder (study.json)")
    use.add_argument("calibration", metavar="NAME", help="calibration name, e.g. session.v2")
    use.add_argument("--trials", default=None, help="comma-separated trial names (default: all)")
    use.set_defaults(run=run_use_calibration)


def _salvage(folder: Path, dry_run: bool) -> dict:
    """The library's salvage: ``Study.repair(dry_run=...)``, else ``salvage_journal`` per file."""
    from core.study import Study

    if hasattr(Study, "repair"):
        with Study.open(folder, mode="r" if dry_run else "w", check_files=False) as study:
            return study.repair(dry_run=dry_run)
    from core.study import results

    salvage = getattr(results, "salvage_journal", None)
    if salvage is None:
        raise CliError("'talus study repair' needs core.study.Study.repair (or "
                       "core.study.results.salvage_journal), which this installation does not "
                       "provide")
    takes_dry_run = "dry_run" in inspect.signature(salvage).parameters
    if dry_run and not takes_dry_run:
        raise CliError("--dry-run: this installation's journal salvage cannot run without writing")
    # hold the study's write lock while journals are rewritten
    with Study.open(folder, mode="r" if dry_run else "w", check_files=False):
        journals = sorted((folder / "results").glob("*/poses/*.jsonl"))
        done = {str(p.relative_to(folder)): (salvage(p, dry_run=dry_run) if takes_dry_run
                                              else salvage(p)) for p in journals}
    return {"study": str(folder), "dry_run": dry_run, "journals": done}


def run_repair(args: argparse.Namespace) -> int:
    folder = study_folder(args.study)
    with stdout_to_stderr():
        result = _salvage(folder.absolute(), bool(args.dry_run))
    print_json(result)
    if not args.dry_run:
        print(f"{PROG} study repair: done ({folder})", file=sys.stderr)
    return EXIT_OK


def run_use_calibration(args: argparse.Namespace) -> int:
    folder = study_folder(args.study)
    from core.study import Study
    from core.study.calibrations import lab_frame_note, use_calibration

    with Study.open(folder, mode="w") as study:
        names = listed(args.trials) if args.trials else list(study.trials)
        unknown = [t for t in names if t not in study.trials]
        if not names:
            raise CliError(f"STUDY: {folder} has no trial to point at a calibration")
        if unknown:
            raise CliError(f"--trials: the study has no trial {', '.join(map(repr, unknown))} "
                           f"(has {', '.join(study.trials)})")
        before = {t: study.trial(t).calibration for t in names}
        for t in names:
            use_calibration(study, t, args.calibration)
        after = {t: study.trial(t).calibration for t in names}
        warnings = [w for t in names if (w := lab_frame_note(study, t, before[t], after[t]))]
    for w in warnings:
        print(f"{PROG} study use-calibration: WARNING: {w}", file=sys.stderr)
    print_json({"study": str(folder), "calibration": args.calibration,
                "trials": {t: {"before": before[t], "after": after[t]} for t in names},
                "warnings": warnings})
    verb = "uses" if len(names) == 1 else "use"
    print(f"{PROG} study use-calibration: {', '.join(names)} now {verb} {args.calibration}", file=sys.stderr)
    return EXIT_OK
