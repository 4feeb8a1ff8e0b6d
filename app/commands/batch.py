"""``talus batch``: track many trials and bones of one or more studies on a Dask cluster.

Usage::

    talus batch STUDY... [--trials a,b] [--bones a,b] [--mode auto|joint|sequential] [--joint]
                [--split-bones] [--sequential-subtract auto|on|off] [--joint-rounds N] [--joint-restart]
                [--ranges] [--workers N]
                [--scheduler ADDRESS]
                [--device cpu|cuda] [--frames START:STOP] [--metric gc|components]
                [--final none|likelihood] [--threshold HU]
                [--no-confidence] [--max-uncertainty MM,DEG] [--collapse-ratio R] [--motion-limit K]
                [--motion-floor MM,DEG] [--sigma-limit K] [--trajectory-limit K|off]
                [--no-trajectory-check] [--backward-limit K|off] [--no-backward-check]
                [--stage-move-limit K] [--stage-move-sigmas S] [--stage-move-frames N]
                [--keep-stage-moves] [--smooth] [--out SUMMARY.json] [--quiet]

Tasks follow ``--mode`` as ``talus track --mode`` tracks (:mod:`core.tracking.batch`): ``auto`` (the
default) makes one task of each trial whose frames are flatfield-corrected (a calibrated study), its
bones tracked jointly — each with its neighbours' DRRs subtracted — and one task per (trial, bone)
of any other trial (whose bones are searched alone, independent of each other; one task of the
trial's bones with ``--sequential-subtract on``); ``joint`` (or ``--joint``) one joint task per
trial; ``sequential`` one task per trial, its bones tracked one after another with the others' DRRs
subtracted, as ``talus track --mode sequential`` tracks them (the same poses). ``--split-bones``
(with ``--mode sequential``) makes one task per (trial, bone) instead, to spread a trial over more
workers: a task of one bone has no neighbour to subtract, so each bone is searched against the whole
image — less accurate where bones overlap — and stderr says so. With ``--ranges`` each frame range
between the bone's (the group's common) keyframes is one, so one long trial spreads over the workers
too. Tasks run on a local Dask cluster (one worker process per GPU, else per CPU core; ``--workers``
sets how many) or on the cluster of ``--scheduler``. Each task tracks into its study's journal as
``talus track --resume`` would, so a batch that was stopped, or whose worker died, carries on where
it was; a failed task is retried once and then reported. ``--workers 0`` runs the tasks one after
the other in this process, without Dask. Progress goes to stderr (the Dask dashboard address first),
the JSON summary to stdout. With ``--ranges``, once all the ranges of a trial's bone are done the
trajectory check judges their frames together (:mod:`core.tracking.batch_pass`): the journal, the
range reports and the summary's task records give the flags after it, and stderr gets a line per
trial's bone(s) — bone-frames judged, frames off the trajectory and flagged for review, frames the
check changed (the first 10 named). ``--final likelihood`` ends every registration with the weighted
least-squares refinement, as ``talus track --final likelihood`` does; every trial of the batch must
have flatfield-corrected frames (the trials without are named, and nothing is tracked). The failure
checks' thresholds (``--collapse-ratio``, ``--motion-limit``, ``--motion-floor``, ``--sigma-limit``)
and the final stage's move check (``--stage-move-limit``, ``--stage-move-sigmas``,
``--stage-move-frames``, ``--keep-stage-moves``; with ``--final likelihood`` only) and the
trajectory check run once a task's run is complete (``--trajectory-limit K|off``, which scales
its rule for frames next to flagged ones too and turns both off, ``--no-trajectory-check``) and the
backward check of its first frame (``--backward-limit K|off``, ``--no-backward-check``) are
``talus track``'s (:data:`app.commands.track.CHECKS`), for every
task; out-of-range values are refused naming the option before any task starts.
``--sequential-subtract auto|on|off`` is ``talus track``'s and goes to every task; what each
sequential task's searches did — the neighbours subtracted or not, auto resolved, and kept on resume
as its report recorded — is in its record (``sequential_subtract``, with
``sequential_subtract_note`` where it is not the plain choice) and gets a line on stderr.
``--joint-rounds N`` and ``--joint-restart`` are ``talus track``'s (one round and off by default;
``--joint-restart`` alone implies two rounds, ``--joint-rounds 1 --joint-restart`` is refused) and go to
every task; a joint task's record says its rounds (``joint_rounds``) and whether those after the first
started from the prediction (``joint_restart``; a task run again uses them as given,
``joint_restart_note`` saying when the frames it resumes ran with other ones). ``--smooth`` is
``talus track --smooth`` for each trial whose tasks all complete, once the batch has run
(:mod:`app.commands.batch_smooth`): the summary's ``"smoothed"`` lists per trial the report and the
bones, or why it was not smoothed, and stderr gets a line each. Exit
status: 0 all tasks complete, 1 a task failed (twice) or bad input, 4 a task had nothing it could
track, 130 interrupted (the frames finished so far are saved; run it again to go on).
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
from pathlib import Path

from ._shared import (
    EXIT_CANCELLED,
    EXIT_ERROR,
    EXIT_NOTHING_DONE,
    EXIT_OK,
    PROG,
    CliError,
    Progress,
    print_json,
    stdout_to_stderr,
    study_folder,
    text_bar,
    warp_device,
)
from .track import RESTART_HELP, ROUNDS_HELP, SMOOTH_HELP, add_check_arguments

__all__ = ["HELP", "configure", "final_stage_problems", "mode_note", "run", "subtract_messages"]

#: --mode's choices (core.tracking.batch.MODES; not imported here, to keep --help free of core)
MODES = ("auto", "joint", "sequential")

HELP = "track many trials and bones of studies on a Dask cluster"


def _names(text: str | None) -> list[str] | None:
    return None if text is None else [s for s in (t.strip() for t in text.split(",")) if s]


def configure(p: argparse.ArgumentParser) -> None:
    p.description = ("Track the trials and bones of one or more studies as independent tasks on "
                     "Dask distributed: a local cluster (one worker per GPU, else per CPU core) or "
                     "--scheduler's. As talus track does, a trial whose frames are flatfield-"
                     "corrected (a calibrated study) is one task tracking its bones jointly, any "
                     "other trial one task per bone (--mode). Poses go to the studies' journals as "
                     "with 'talus track --resume': run it again to carry on. JSON summary on stdout.")
    p.add_argument("studies", nargs="+", metavar="STUDY", help="study folders (study.json)")
    p.add_argument("--trials", default=None, help="comma-separated trial names (default: all)")
    p.add_argument("--bones", default=None, help="comma-separated bone names (default: each trial's)")
    p.add_argument("--mode", choices=MODES, default="auto",
                   help="auto (the default, as talus track): one task per trial tracking its bones "
                        "jointly, each with the others' DRRs subtracted, when the trial's frames are "
                        "flatfield-corrected (a calibrated study), else one task per bone; joint: one "
                        "joint task per trial; sequential: one task per trial, its bones tracked one after "
                        "another with the others' DRRs subtracted, as talus track --mode sequential")
    p.add_argument("--joint", action="store_true", help="the same as --mode joint")
    p.add_argument("--split-bones", action="store_true",
                   help="with --mode sequential: one task per (trial, bone) instead of per trial, to spread "
                        "a trial over more workers; a task of one bone has no neighbour to subtract, so "
                        "each bone is searched against the whole image (less accurate where bones overlap)")
    p.add_argument("--sequential-subtract", choices=("auto", "on", "off"), default="auto",
                   help="as talus track --sequential-subtract, for every task: whether a sequential task "
                        "searches each bone with the trial's other bones' DRRs subtracted (auto: where the "
                        "frames are flatfield-corrected). Default auto")
    p.add_argument("--joint-rounds", type=int, default=None, metavar="N",
                   help="as talus track --joint-rounds, for every joint task: " + ROUNDS_HELP)
    p.add_argument("--joint-restart", action="store_true",
                   help="as talus track --joint-restart, for every joint task: " + RESTART_HELP)
    p.add_argument("--ranges", action="store_true",
                   help="one task per frame range between each bone's keyframes (a joint task's: "
                        "the keyframes all its bones share; from a keyframe "
                        "back to the first frame, or forward to the frame before the next "
                        "keyframe), so the ranges of one bone run side by side")
    p.add_argument("--workers", type=int, default=None,
                   help="local worker processes (default: one per GPU, else per CPU core; "
                        "0: run the tasks here, one after the other, without Dask)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="an existing Dask scheduler, e.g. tcp://head:8786 (its workers must see the "
                        "study folders at the same paths)")
    p.add_argument("--device", default=None, help="Warp device of every task: cpu or cuda (default: "
                                                  "the worker's GPU when it has one, else cpu)")
    p.add_argument("--frames", default=None, help="START:STOP of every trial (default: all frames)")
    p.add_argument("--metric", default="gc", metavar="gc|components|KIND",
                   help="similarity, as talus track --metric: gc (the default: gradient correlation of the "
                        "gradient magnitudes; also 'magnitudes'), components (of the gradient components) "
                        "or another core.similarity batched kind as one term")
    p.add_argument("--final", choices=("none", "likelihood"), default="none",
                   help="as talus track --final: likelihood ends every registration with a weighted "
                        "least-squares refinement against the line-integral image (better talus and "
                        "rotation accuracy on the synthetic trial, worse calcaneus translation jointly, "
                        "several times slower; needs flatfield-corrected frames in every trial). Default "
                        "none")
    p.add_argument("--threshold", type=float, default=200.0, help="bone threshold, HU")
    p.add_argument("--no-confidence", action="store_true", help="skip the per-frame uncertainty")
    p.add_argument("--max-uncertainty", default=None, metavar="MM,DEG",
                   help="flag frames whose confidence exceeds MM or DEG for review (as talus track)")
    p.add_argument("--smooth", action="store_true",
                   help="as talus track --smooth, for each trial whose tasks all complete, once the batch "
                        "has run: " + SMOOTH_HELP.replace("once the run is complete, also ", ""))
    p.add_argument("--out", default=None, help="also write the JSON summary to this file")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    add_check_arguments(p)  # as talus track
    p.set_defaults(run=run)


def _frames(text: str | None) -> tuple[int, int] | None:
    if text is None:
        return None
    try:
        a, b = text.split(":", 1)
        lo, hi = int(a), int(b)
    except ValueError:
        raise ValueError(f"--frames: expected START:STOP (two frame numbers), got {text!r}") from None
    if not 0 <= lo < hi:
        raise ValueError(f"--frames: {text!r} is not a non-empty range START:STOP with 0 <= START")
    return lo, hi


def final_stage_problems(tasks) -> list[str]:
    """Why the likelihood final stage cannot run on the trials of ``tasks``
    (:func:`app.commands.track.final_stage_problem`, one line per trial; empty: it can)."""
    from core.study import Study

    from .track import final_stage_problem

    out = []
    for folder in sorted({t.study for t in tasks}):
        with Study.open(folder) as study:
            for trial in sorted({t.trial for t in tasks if t.study == folder}):
                problem = final_stage_problem(study, trial)
                if problem:
                    out.append(f"{folder}: {problem}")
    return out


def mode_note(tasks, mode: str) -> str:
    """One line saying how ``mode`` grouped the bones of each trial into ``tasks``."""
    groups = [t for t in tasks if len(t.bones) > 1]
    joint = sorted({t.trial for t in groups if t.tracking_mode == "joint"})
    seq = sorted({t.trial for t in groups if t.tracking_mode == "sequential"} - set(joint))
    alone = sorted({t.trial for t in tasks if len(t.bones) == 1} - set(joint) - set(seq))
    parts = ([f"bones tracked jointly in {', '.join(joint)}"] if joint else []) + (
        [f"bones tracked one after another in {', '.join(seq)}"] if seq else []) + (
        [f"one task per bone in {', '.join(alone)}"] if alone else [])
    why = " (jointly where the frames are flatfield-corrected)" if mode == "auto" else ""
    return f"mode {mode}{why}: {'; '.join(parts)}"


def subtract_text(record: dict) -> str | None:
    """What a task's searches did with the other bones (its record's ``mode`` and
    ``sequential_subtract``), e.g. ``"sequential, neighbours subtracted"``; None for a task that did
    not say (failed, cancelled before it started)."""
    if record.get("mode") == "joint":
        return "joint, neighbours subtracted"
    used = record.get("sequential_subtract")
    if used is None:
        return None
    return f"sequential, neighbours {'subtracted' if used else 'not subtracted'}"


def subtract_messages(records) -> list[str]:
    """One line per sequential task record: whether its searches subtracted the neighbours (auto
    resolved, or kept on resume), and why where the record says (a task of one bone, a resumed run)."""
    out = []
    for r in records:
        if r.get("mode") != "sequential" or r.get("sequential_subtract") is None:
            continue
        note = r.get("sequential_subtract_note")
        out.append(f"{r['key']}: {subtract_text(r)}" + (f" ({note})" if note else ""))
    return out


class _Follow:
    """Worker events → progress lines: tasks done of all, and the frame of the task that moved."""

    def __init__(self, progress: Progress, n_tasks: int) -> None:
        self.progress, self.n_tasks, self.done = progress, n_tasks, 0

    def __call__(self, e: dict) -> None:
        kind, key = e.get("kind"), e.get("key", "?")
        if kind == "start":
            self.progress.note(f"{key}: started on {e.get('host')} (pid {e.get('pid')}, "
                               f"device {e.get('device')})")
        elif kind == "frame":
            score = e.get("score")
            self.progress(self.done, self.n_tasks,
                          f"tasks | {key} {text_bar(e['done'], e['total'])} frame {e['done']}/{e['total']}"
                          + ("" if score is None else f" score {score:.3f}"))
        elif kind == "end":
            self.done += 1
            self.progress.note(f"{key}: {e.get('status')} in {e.get('seconds', 0.0):.1f} s "
                               f"({self.done}/{self.n_tasks} tasks)")


def _check_device(device: str | None, scheduler: str | None) -> None:
    """``--device`` checked before any task, as talus track checks it (``_shared.warp_device``:
    'gpu' failed every task with 'Invalid device identifier: gpu', 'cuda' without a GPU with a
    RuntimeError). With ``--scheduler`` the cluster's workers have the GPUs, not this machine:
    only the form (cpu, cuda, cuda:N) is checked."""
    if scheduler is None:
        warp_device(device)
        return
    head, _, index = (device or "cpu").partition(":")
    if (head == "cpu" and not index) or (head == "cuda" and (not index or index.isdigit())):
        return
    raise CliError(f"--device: expected cpu, cuda or cuda:N (a GPU's number), got {device!r}")


def run(a: argparse.Namespace) -> int:
    for s in a.studies:
        study_folder(s)
    if a.workers is not None and a.workers < 0:
        raise CliError(f"--workers: expected 0 or more worker processes, got {a.workers}")
    if a.workers == 0 and a.scheduler:
        raise CliError("--workers 0 runs the tasks here; it cannot be combined with --scheduler")
    if a.joint and a.mode not in ("auto", "joint"):
        raise CliError(f"--joint: contradicts --mode {a.mode} (--joint is --mode joint)")
    mode = "joint" if a.joint else a.mode
    _check_device(a.device, a.scheduler)
    from .track import check_choices_of_args, check_error, joint_rounds_of_args, parse_limits, stage_move_note

    limits = parse_limits(a.max_uncertainty)
    checks = check_choices_of_args(a)
    if checks:  # refused here, naming the option, rather than in every task
        from core.tracking.options import TrackingOptions

        try:
            TrackingOptions(**checks)
        except ValueError as exc:
            raise (check_error(exc) or exc) from None
        note = stage_move_note(checks, a.final)
        if note:
            print(f"{PROG} batch: {note}", file=sys.stderr)
    subtract = getattr(a, "sequential_subtract", "auto")
    restart = bool(getattr(a, "joint_restart", False))
    rounds = joint_rounds_of_args(a)  # refused here, naming the options, rather than in every task
    given = [f for f, on in (("--joint-rounds", rounds is not None), ("--joint-restart", restart)) if on]
    if given and mode == "sequential":
        print(f"{PROG} batch: {', '.join(given)}: no effect with --mode sequential", file=sys.stderr)
    if rounds is None:  # --joint-restart alone: two rounds
        rounds = 2 if restart else 1
    split = bool(getattr(a, "split_bones", False))
    if split and mode != "sequential":
        raise CliError(f"--split-bones: one task per bone is a choice of --mode sequential, "
                       f"not --mode {mode}")
    if split:
        print(f"{PROG} batch: --split-bones: one task per bone, each searched against the whole image: a "
              f"task of one bone has no neighbour to subtract (without --split-bones a trial's bones are one "
              f"task, each searched with the others subtracted, as talus track --mode sequential)",
              file=sys.stderr)
    frames = _frames(a.frames)
    if a.workers != 0 and importlib.util.find_spec("distributed") is None:
        raise CliError(f"{PROG} batch needs Dask distributed, which is not installed: "
                       "pip install 'talus-biplane[batch]' (or run with --workers 0, without Dask)")
    from core.tracking.batch import TaskSettings, build_tasks, run_batch, run_serial

    tasks = build_tasks([Path(s).expanduser() for s in a.studies], _names(a.trials), _names(a.bones),
                        mode=mode, ranges=a.ranges, frames=frames, split_bones=split,
                        subtract={"on": True, "off": False}.get(subtract))
    if a.final == "likelihood":
        problems = final_stage_problems(tasks)
        if problems:
            raise CliError("--final likelihood: " + "; ".join(problems))
    settings = TaskSettings(device=a.device, metric=a.metric, threshold_hu=a.threshold,
                            confidence=not a.no_confidence, max_uncertainty=limits, frames=frames,
                            options=((("refine_likelihood", True),) if a.final == "likelihood" else ())
                            + ((("sequential_subtract", subtract == "on"),) if subtract != "auto" else ())
                            + ((("joint_restart", True),) if restart else ())
                            + ((("joint_rounds", rounds),) if rounds != 1 else ())
                            + tuple(checks.items()))
    progress = Progress("batch", quiet=a.quiet)
    follow = _Follow(progress, len(tasks))
    progress.note(f"{len(tasks)} tasks: {', '.join(t.key for t in tasks[:6])}"
                  + (" ..." if len(tasks) > 6 else ""))
    progress.note(mode_note(tasks, mode))

    def started(info: dict) -> None:
        progress.note(f"Dask dashboard: {info['dashboard']} (scheduler {info['scheduler']}, "
                      f"{info['workers']} workers)")

    try:
        with stdout_to_stderr():
            if a.workers == 0:
                summary = run_serial(tasks, settings, progress=follow)
            else:
                summary = run_batch(tasks, settings, workers=a.workers, scheduler=a.scheduler,
                                    on_event=follow, on_start=started)
    except KeyboardInterrupt:
        progress.close()
        print(f"{PROG} batch: interrupted; the frames finished so far are saved (run the same "
              f"'{PROG} batch' again to carry on)", file=sys.stderr)
        return EXIT_CANCELLED
    finally:
        progress.close()
    if getattr(a, "smooth", False):  # after the trajectory pass, whose flags the smoother weighs
        from .batch_smooth import smooth_trials

        summary["smoothed"] = smooth_trials(tasks, summary.get("task_records") or (),
                                            threshold_hu=a.threshold)
    print_json(summary, a.out)
    for line in subtract_messages(summary.get("task_records") or ()):  # the choice each task ran
        print(f"{PROG} batch: {line}", file=sys.stderr)
    for r in summary.get("task_records") or ():  # a joint task run again with other rounds or restart
        if r.get("joint_restart_note"):
            print(f"{PROG} batch: {r['key']}: {r['joint_restart_note']}", file=sys.stderr)
    if summary.get("trajectory_pass"):
        from core.tracking.batch_pass import pass_messages

        for entry in summary["trajectory_pass"]:  # per trial's bone(s): judged, flagged, changed
            for line in pass_messages(entry):
                print(f"{PROG} batch: {line}", file=sys.stderr)
    if summary.get("smoothed"):
        from .batch_smooth import smooth_messages

        smooth_messages(summary["smoothed"])
    for f in summary["failures"]:
        print(f"{PROG} batch: task {f['key']} failed after {f['attempts']} attempts: {f['error']}",
              file=sys.stderr)
    if summary["status"] == "failed":
        return EXIT_ERROR
    return EXIT_NOTHING_DONE if summary["status"] == "stopped" else EXIT_OK
