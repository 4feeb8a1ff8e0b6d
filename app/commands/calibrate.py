"""``talus calibrate``: turn a calibration session into a study's correction and rig.

Usage::

    talus calibrate SESSION --study STUDY [--object NAME|FILE] [--model auto|poly N,M|tps|lwm]
                    [--lab-frame static|object] [--report DIR] [--series NAME]
                    [--trials series|all|none|a,b] [--quiet]

Runs :func:`core.study.calibrations.calibrate_study`, as a script does: the session folder
(:func:`core.io.read_session`) calibrated by :func:`core.calibration.session.calibrate_session`
(flatfield → distortion grid → beads → DLT start → bundle adjustment) and saved into the study
as the next version of a calibration series
(:func:`core.study.calibrations.save_session_calibration`: MayaCam rig, parameter SDs, one
correction pipeline per camera, the report); the trials of the series (or those named) then use
it. With lead-disc (``glare``) frames in the session the veiling glare is measured and undone
in the pipelines; the summary's ``glare`` gives its fraction and width per camera. Nothing is
saved when a step fails or on Ctrl-C: the study is unchanged. A progress bar goes to stderr,
the JSON summary to stdout. The lab frame is the static cube's: a cube frame that cannot be
labelled is an error unless ``--lab-frame object`` asks for the spiral's first frame; whenever
the lab frame is not the cube's a warning goes to stderr and into the summary's ``warnings``.
Exit status: 0 done, 1 bad input (the message names the step, the file and frame, and what can
be done), 3 study locked by another writer, 130 interrupted.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ._shared import (
    EXIT_CANCELLED,
    EXIT_OK,
    PROG,
    CancelToken,
    CliError,
    Progress,
    names,
    print_json,
    sigint_cancels,
    stdout_to_stderr,
    study_folder,
    text_bar,
)

__all__ = ["HELP", "configure", "parse_model", "run", "unused_note"]

HELP = "calibrate a study's rig and image correction from a session"


def parse_model(words: list[str] | None) -> str:
    """``--model auto | poly N,M | tps | lwm`` (or a label such as ``poly(5,5)``) → a model label."""
    if not words:
        return "auto"
    text = " ".join(words).strip().lower()
    if text in ("auto", "tps", "lwm"):
        return text
    if text.startswith("poly"):
        rest = text[4:].strip().strip("()").replace(" ", "")
        try:
            n, m = (int(v) for v in rest.split(",")) if "," in rest else (int(rest), int(rest))
        except ValueError:
            raise ValueError(f"--model: expected 'poly N,M' (two orders), got {text!r}") from None
        return f"poly({n},{m})"
    return text  # any other label is checked by the library (e.g. tps(0.01), lwm(16), cheb(9,9))


def configure(p: argparse.ArgumentParser) -> None:
    p.description = ("Calibrate from a calibration session (dark, empty-field, distortion-grid, "
                     "cube and spiral frames of both cameras): flatfield, distortion model, bead "
                     "labelling, DLT start and bundle adjustment. The correction pipelines and the "
                     "rig with its uncertainties are saved into the study as a new calibration "
                     "version (earlier versions are kept). JSON summary on stdout.")
    p.add_argument("session", help="calibration session folder (session.json)")
    p.add_argument("--study", required=True, help="study folder (study.json) to save into")
    p.add_argument("--object", default=None, metavar="NAME|FILE",
                   help="the object moved through the volume: a built-in (spiral33, spiral23, cube15) "
                        "or a definition file (.csv/.json); default: the session's")
    p.add_argument("--model", nargs="+", default=None, metavar="MODEL",
                   help="distortion model: auto (cross-validated choice, default), poly N,M, tps, lwm")
    p.add_argument("--lab-frame", default="static", choices=("static", "object"),
                   help="what defines the lab frame: the static object (cube) frame (default; an error "
                        "when it was recorded but cannot be labelled) or the moving object's first "
                        "labelled frame")
    p.add_argument("--report", default=None, metavar="DIR",
                   help="also write the report (JSON and figures) here")
    p.add_argument("--series", default="session", help="calibration series name (default session)")
    p.add_argument("--trials", default="series",
                   help="trials that use the new calibration: series (those on an earlier version, "
                        "default), all, none, or comma-separated names")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(run=run)


class _Steps:
    """``progress(step, done, total)`` of the calibration as a bar with the step's name."""

    def __init__(self, progress: Progress) -> None:
        self.progress = progress

    def __call__(self, step: str, done: int, total: int) -> None:
        self.progress(done, total, f"{text_bar(done, total)} {step}")


def _copy_report(src: Path, dest: Path) -> dict:
    """The report saved with the calibration (``report.json`` and its figures, as
    :func:`core.calibration.report.write_report` wrote them into ``src``) copied into ``dest``,
    each file atomically; the paths as ``write_report`` returns them."""
    import json

    from core.io.atomic import atomic_write

    figures = json.loads((src / "report.json").read_text(encoding="utf-8"))["figures"]
    dest.mkdir(parents=True, exist_ok=True)
    out = {"report": dest / "report.json", **{k: dest / name for k, name in figures.items()}}
    for p in out.values():
        atomic_write(p, (src / p.name).read_bytes())
    return out


def unused_note(saved, in_use: dict[str, str], folder: Path, *, trials="series") -> str | None:
    """A line for a saved calibration no trial uses (``--trials series`` on a study whose trials are
    on no earlier version of the series, e.g. the first calibration of an imported study): the
    trials' calibrations and how to point them at it without calibrating again. None where
    ``--trials none`` asked for exactly that."""
    if saved.trials or not in_use or trials == "none":
        return None
    uses = ", ".join(f"{t} uses {c}" for t, c in in_use.items())
    return (f"no trial uses {saved.name} yet ({uses}); point them at it with '{PROG} study "
            f"use-calibration {folder} {saved.name}' (--trials a,b for some)")


def run(a: argparse.Namespace) -> int:
    session_dir = Path(a.session).expanduser()
    if session_dir.name == "session.json" and session_dir.is_file():  # the manifest stands for its folder
        session_dir = session_dir.parent
    if not session_dir.is_dir():
        raise CliError(f"SESSION: no calibration session folder at {session_dir}")
    folder = study_folder(a.study, "--study")
    model = parse_model(a.model)
    trials = a.trials if a.trials in ("series", "all", "none") else names(a.trials)
    from core.calibration.session import CalibrationCancelled
    from core.study import Study
    from core.study.calibrations import calibrate_study, lab_frame_note

    token = CancelToken()
    progress = Progress("calibrate", quiet=a.quiet)
    cal = saved = None
    with Study.open(folder, mode="w") as study, sigint_cancels(token, "calibrate"):
        unknown = [t for t in trials if t not in study.trials] if isinstance(trials, list) else []
        if unknown:  # before minutes of calibrating, not after
            raise CliError(f"--trials: the study has no trial {', '.join(map(repr, unknown))} "
                           f"(has {', '.join(study.trials) or 'none'}; or give series, all or none)")
        in_use = {t: study.trial(t).calibration for t in study.trials}
        try:
            with stdout_to_stderr():
                saved, cal = calibrate_study(study, session_dir, object=a.object, model=model,
                                             lab_frame=a.lab_frame, series=a.series, trials=trials,
                                             progress=_Steps(progress), cancel=token)
        except (CalibrationCancelled, KeyboardInterrupt):
            token.set()
        finally:
            progress.close()
    if token.is_set() and saved is None:
        print_json({"status": "cancelled", "saved": None})
        print(f"{PROG} calibrate: cancelled; the study is unchanged", file=sys.stderr)
        return EXIT_CANCELLED
    report_files = None
    if a.report:
        report_files = {k: str(p) for k, p in _copy_report(saved.folder / "report",
                                                           Path(a.report).expanduser()).items()}
    rep = cal.report
    for w in rep.get("warnings", []):
        print(f"{PROG} calibrate: WARNING: {w}", file=sys.stderr)
    note = unused_note(saved, in_use, folder, trials=a.trials)
    if note:
        print(f"{PROG} calibrate: {note}", file=sys.stderr)
    warnings = list(rep.get("warnings", []))
    with Study.open(folder) as study:
        for t in saved.trials:
            moved = lab_frame_note(study, t, in_use[t], saved.name)
            if moved:
                print(f"{PROG} calibrate: WARNING: {moved}", file=sys.stderr)
                warnings.append(moved)
    out = {"status": "complete", "saved": {"calibration": saved.name, "folder": str(saved.folder),
                                           "trials": list(saved.trials)},
           "rig": [{k: c[k] for k in ("name", "fx_px", "sid_mm", "source_mm", "std")} for c in rep["rig"]],
           "reprojection_rms_px": rep["bundle"]["rms_px"],
           "frames_labelled": rep["n_frames_labelled"], "frames": len(rep["frames"]),
           "distortion": {c["name"]: {"model": c["distortion"]["model"],
                                      "grid_residual_rms_mm": c["distortion"]["residuals"]["mm"]["rms"],
                                      "lattice_check": c.get("lattice_check")} for c in rep["cameras"]},
           "glare": {c["name"]: None if not c.get("glare") else
                     {k: c["glare"].get(k) for k in ("fraction", "fraction_sd", "sigma_px", "sigma_mm",
                                                     "sigma_mm_sd")} for c in rep["cameras"]},
           "error_volume_rms_mm": rep["error_volume"].get("rms_mm"), "lab_frame": rep.get("lab_frame"),
           "warnings": warnings, "notes": rep["notes"],
           "report": report_files}
    print_json(out)
    return EXIT_OK
