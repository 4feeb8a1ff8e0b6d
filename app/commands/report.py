"""``talus report``: a one-page trial report, HTML or PDF.

Usage::

    talus report STUDY --trial T [--out FILE.html|FILE.pdf]

The report (:func:`core.study.report.write_report`) holds the calibration summary, the tracking
summary per bone (frames tracked, flagged, keyframes, hand edits, median score and confidence),
plots of the scores and of the joints' Grood–Suntay angles with the flagged frames shaded, and
the list of flagged frames with their reasons. The study is opened read-only (a study open for
writing elsewhere can be reported on). Default output: ``STUDY/results/reports/<trial>.html``.
Prints the written path as JSON. Exit status: 0 done, 1 bad input.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ._shared import EXIT_OK, PROG, CliError, print_json, stdout_to_stderr, study_folder

__all__ = ["HELP", "configure", "run"]

HELP = "one-page trial report (HTML or PDF)"


def configure(p: argparse.ArgumentParser) -> None:
    p.description = ("Write a one-page report of a study trial: calibration summary, tracking "
                     "summary, score and joint-angle plots, flagged frames. HTML or PDF by the "
                     "--out suffix.")
    p.add_argument("study", help="study folder (study.json)")
    p.add_argument("--trial", required=True, help="trial name")
    p.add_argument("--out", default=None, metavar="FILE",
                   help="FILE.html or FILE.pdf (default STUDY/results/reports/TRIAL.html)")
    p.set_defaults(run=run)


def run(a: argparse.Namespace) -> int:
    folder = study_folder(a.study)
    out = Path(a.out).expanduser() if a.out else folder / "results" / "reports" / f"{a.trial}.html"
    if out.suffix.lower() not in (".html", ".htm", ".pdf"):
        raise CliError(f"--out: expected a .html or .pdf file, got {a.out!r}")
    if not out.parent.is_dir():
        if a.out:
            raise CliError(f"--out: the folder {out.parent} does not exist")
        out.parent.mkdir(parents=True)
    from core.study import Study
    from core.study.report import write_report

    with Study.open(folder, mode="r") as study:
        if a.trial not in study.trials:
            raise CliError(f"--trial: the study has no trial {a.trial!r} (has {list(study.trials)})")
        with stdout_to_stderr():
            path = write_report(study, a.trial, out)
    print_json({"trial": a.trial, "report": str(path)})
    print(f"{PROG} report: wrote {path}", file=sys.stderr)
    return EXIT_OK
