"""``talus gui``: open the Talus window."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from ._shared import CliError, load

HELP = "open the Talus window"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.description = ("Open the Talus window; with --demo DIR (a study folder, e.g. one "
                          "written by 'talus demo'), show that study.")
    parser.add_argument("--demo", metavar="DIR", help="open this study folder at start")
    # start-up check of an installation (installer/smoke_bundle.sh): close once up, report times
    parser.add_argument("--smoke", action="store_true", help=argparse.SUPPRESS)
    parser.set_defaults(run=run)


def check_display() -> None:
    """Qt aborts the process when it finds no display: say so clearly instead."""
    if not sys.platform.startswith("linux") or os.environ.get("QT_QPA_PLATFORM"):
        return
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise CliError(
            "'talus gui' needs a display: DISPLAY is not set (run it from a desktop session, "
            "over ssh -X, or under xvfb-run)"
        )


def run(args: argparse.Namespace) -> int:
    demo = None
    if args.demo is not None:
        demo = Path(args.demo).expanduser()
        if demo.name == "study.json" and demo.is_file():  # the manifest stands for its folder
            demo = demo.parent
        if not demo.is_dir():
            raise CliError(f"--demo: expected a study folder, '{demo}' is not a directory")
    check_display()
    run_gui = load("app.main_window:run_gui", needed_for="'talus gui'",
                   hint="Install the GUI extra: pip install 'talus-biplane[gui]'.")
    if getattr(args, "smoke", False):
        load("app.smoke:arm", needed_for="'talus gui --smoke'")(demo)
    return int(run_gui(demo=demo))
