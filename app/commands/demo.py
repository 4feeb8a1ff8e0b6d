"""``talus demo``: write (once) and open the built-in synthetic biplane study."""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from ._shared import (
    EXIT_CANCELLED,
    EXIT_OK,
    PROG,
    CancelToken,
    CliError,
    Progress,
    load,
    print_json,
    sigint_cancels,
    stdout_to_stderr,
    warp_device,
)
from .types import int_at_least

HELP = "write (once) and open the synthetic demo study"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Write the built-in synthetic biplane study (rig, CT volumes, fluoroscope frames "
        "rendered at known bone poses, ground truth) to --out, print its summary as JSON and "
        "open it in the window when a display is available. A study already in --out made with "
        "the same options is reused. Ctrl-C cancels cleanly after the frame in progress.")
    parser.add_argument("--out", default="demo_out", metavar="DIR", help="output folder")
    parser.add_argument("--frames", type=int_at_least(1), metavar="N",
                        help="number of frames (default: the demo's, 10)")
    parser.add_argument("--pixels", type=int_at_least(1), metavar="N",
                        help="image size in pixels, N x N (default: the demo's, 512)")
    parser.add_argument("--seed", type=int_at_least(0), metavar="N", help="random seed (default 0)")
    parser.add_argument("--device", choices=["cpu", "cuda"],
                        help="Warp device for the DRRs (default: cuda when present, else cpu)")
    parser.add_argument("--no-gui", action="store_true",
                        help="only write the study (the window opens when a display is available)")
    parser.add_argument("--regenerate", action="store_true",
                        help="rebuild the study even if --out already holds one made with the "
                        "same options")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from ..demo_cache import write_demo

    out = Path(args.out).expanduser()
    cached = None if args.regenerate else _cached_demo(out, args)
    if cached is None:
        check_out(out)
        warp_device(args.device)
        if any((out / "results").glob("*/poses/*.jsonl")):  # an earlier demo, tracked
            why = "--regenerate" if args.regenerate else "made with other options or incomplete"
            print(f"{PROG} demo: rebuilding the demo study in {out} ({why}): the poses tracked there "
                  "are replaced", file=sys.stderr)
    if cached is not None:
        print(f"{PROG} demo: using the demo study already in {out} (--regenerate to rebuild)",
              file=sys.stderr)
        print_json(cached)
        _say_calibration(cached, out)
        return _open_demo_gui(out, args)
    token = CancelToken()
    progress = _SetUpFirst(Progress("demo", "frame"))
    print(f"{PROG} demo: writing the synthetic study to {out}; building its bones, soft tissue and "
          "renderer first (tens of seconds or more without a GPU)", file=sys.stderr, flush=True)
    with sigint_cancels(token, "demo"):
        try:
            # options left out take the defaults of make_demo_study
            given = {"n_frames": args.frames, "pixels": args.pixels, "seed": args.seed,
                     "device": args.device}
            options = {k: v for k, v in given.items() if v is not None}
            with stdout_to_stderr():
                result = write_demo(out, **options, progress=progress, cancel=token)
        except KeyboardInterrupt:
            token.set()
            result = None
        except Exception:
            if not token.is_set():
                raise
            result = None
        finally:
            progress.close()
    if result is not None:
        print_json(result)  # also after a cancel: the summary says what was written
        _say_calibration(result, out)
    if token.is_set():
        print(f"{PROG} demo: cancelled; complete frames so far are in {out}", file=sys.stderr)
        return EXIT_CANCELLED
    return _open_demo_gui(out, args)


def check_out(out: Path) -> None:
    """Refuse an ``--out`` the demo would damage: a file, or a folder that is not empty and holds no
    demo (``summary.json`` of ``talus demo``). The generator replaces ``study.json``, ``frames/``,
    ``volumes/``, ``rig/`` and deletes ``results/`` (the pose journals) of the folder it writes
    to: 'talus demo --out' a lab's study folder (or the working folder) lost its results."""
    if not out.exists():
        return
    if not out.is_dir():
        raise CliError(f"--out: {out} is a file; give a folder for the demo study")
    if not any(out.iterdir()):
        return
    summary = out / "summary.json"
    text = summary.read_text(encoding="utf-8", errors="replace") if summary.is_file() else ""
    if '"talus-synthetic-study"' in text or _unfinished_demo(out):
        return
    if (out / "study.json").is_file():
        raise CliError(f"--out: {out} holds a study that is not a demo (study.json without the demo's "
                       "summary.json): the demo would replace its files and delete its results/ (the pose "
                       "journals); give a new or empty folder")
    raise CliError(f"--out: {out} is not empty and holds no demo (no summary.json of 'talus demo'): the "
                   "demo would replace files there and delete a results/ folder; give a new or empty folder")


def _unfinished_demo(out: Path) -> bool:
    """``out`` holds a demo that stopped before its ``summary.json`` (written last): its study
    (``study.json`` named ``talus-demo``: a Ctrl-C during the demo's calibration, which raises
    out of the generator) or, before the study, its rig (``rig/rig.json`` in the demo's lab
    frame: the process killed while frames were written). Such a folder was refused as 'a study
    that is not a demo', even with --regenerate, until removed by hand."""
    study = out / "study.json"
    if study.is_file():
        try:
            doc = json.loads(study.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return False
        return isinstance(doc, dict) and doc.get("name") == DEMO_STUDY_NAME
    rig = out / "rig" / "rig.json"
    try:
        return rig.is_file() and DEMO_LAB_FRAME in rig.read_text(encoding="utf-8", errors="replace")
    except OSError:
        return False


#: the demo study's name (core.synthetic.demo._write_study) and its rig.json's lab frame line
DEMO_STUDY_NAME = "talus-demo"
DEMO_LAB_FRAME = '"lab_frame": "x walking direction, y left, z up; mm"'


class _SetUpFirst:
    """The demo's progress: its first frame's step also built the scene (tens of seconds on a
    2-core CPU at 128 px, before any line), so the ETA is timed from the first frame on, not from
    the start (which said 'ETA 1 min 14 s' for two frames that then took no time)."""

    def __init__(self, progress: Progress) -> None:
        self.progress, self.first = progress, True

    def __call__(self, *args, **kwargs) -> None:
        if self.first and len(args) >= 2:
            self.first = False
            self.progress.resumed(int(args[0]))  # the ETA: timed from now, over the steps after it
        self.progress(*args, **kwargs)

    def close(self) -> None:
        self.progress.close()


def _say_calibration(summary: dict, out: Path) -> None:
    """Say on stderr how the demo's trial is calibrated when the summary's ``calibration`` is not a
    saved one: skipped (images under 256 px) or failed (the error was only in the JSON, and the
    trial silently kept the generator's rig)."""
    cal = summary.get("calibration") if isinstance(summary, dict) else None
    if not isinstance(cal, dict):
        return
    if cal.get("error"):
        session = out / str(summary.get("calibration_session") or "calibration_session")
        print(f"{PROG} demo: WARNING: the study could not be calibrated from its session, so its "
              f"trial uses the generator's rig without correction: {cal['error']} (try again with "
              f"'{PROG} calibrate {session} --study {out}' and the options the message suggests)",
              file=sys.stderr)
    elif cal.get("skipped"):
        print(f"{PROG} demo: not calibrated: {cal['skipped']}", file=sys.stderr)


def _cached_demo(out: Path, args: argparse.Namespace) -> dict | None:
    """The summary of a complete demo study in ``out`` (with its calibration session) made with the
    same options, if any."""
    from ..demo_cache import complete_demo

    return complete_demo(out, options={"n_frames": args.frames, "pixels": args.pixels, "seed": args.seed})


def _open_demo_gui(out: Path, args: argparse.Namespace) -> int:
    """Show the demo study in the window when asked to and a display is available."""
    if args.no_gui:
        return EXIT_OK
    if sys.platform.startswith("linux") and not (
            os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        print(f"{PROG} demo: no display; view the study with '{PROG} gui --demo {out}'",
              file=sys.stderr)
        return EXIT_OK
    try:
        run_gui = load("app.main_window:run_gui", needed_for="showing the demo",
                       hint="Install the GUI extra: pip install 'talus-biplane[gui]'.")
    except CliError as exc:
        print(f"{PROG} demo: {exc}", file=sys.stderr)
        return EXIT_OK
    return int(run_gui(demo=out))
