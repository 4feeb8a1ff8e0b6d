"""``talus track``: track bones of a study trial from the command line.

Usage::

    talus track STUDY --trial T [--bones a,b] [--frames 0:500] [--backward] [--device cuda:0]
                [--resume] [--guess velocity|previous|spline] [--mode auto|sequential|joint]
                [--sequential-subtract auto|on|off] [--joint-rounds N] [--joint-restart]
                [--metric magnitudes|components]
                [--search newton|local] [--scale S] [--final none|likelihood]
                [--max-uncertainty MM,DEG] [--no-confidence]
                [--collapse-ratio R] [--motion-limit K] [--motion-floor MM,DEG] [--sigma-limit K]
                [--stage-move-limit K] [--stage-move-sigmas S] [--stage-move-frames N]
                [--keep-stage-moves] [--trajectory-limit K|off] [--no-trajectory-check]
                [--backward-limit K|off] [--no-backward-check] [--smooth] [--quiet]

Every registered frame is saved to the study's pose journal as it finishes; the tracking report
(``results/reports/tracking/<trial>.json``) lists per-frame scores and the frames flagged for
review. A progress bar goes to stderr, the JSON summary to stdout. Ctrl-C stops after the
registration in flight (``--resume`` continues later). Exit status: 0 done, 1 bad input,
3 study locked by another writer, 4 no bone could be tracked, 130 interrupted.

``--final likelihood`` ends every registration with the weighted least-squares refinement of the
pose against the line-integral image (:mod:`core.tracking.final_stage`). It compares DRRs with
``-log`` of the flatfield-normalised fluence, so it needs flatfield-corrected frames: a trial whose
frames are only divided by the full scale is refused (exit 1) before any tracking, naming it
(:class:`core.tracking.from_study.FinalStageError`: the trial's correction is read once, by the
tracker).
The JSON summary then says in how many bone-frames the refinement was kept (``"final_stage"``: a
refinement that moves the pose too far, or fails, leaves the similarity's pose; ``"rejected"``
counts those the move check below sent back to it). The options come
from :func:`options_from_choices`, which the window's *Tracking options* dialog
(:mod:`app.tracking_options`) uses too.

``--sequential-subtract auto|on|off`` (:data:`SUBTRACTS`; ``TrackingOptions.sequential_subtract``):
whether a bone tracked sequentially is searched with its neighbours' DRRs subtracted (those
registered earlier in the frame at their poses, the others at their guesses). ``auto`` (the
default): on where the trial's frames are flatfield-corrected — the test ``--mode auto`` makes, so
it matters with ``--mode sequential`` — and off on frames divided by the full scale only, whose
intensities the DRRs do not match; ``on`` and ``off`` are used as given. The JSON summary says
which was used (``"sequential_subtract"``, sequential runs only; false when one bone is tracked),
and ``"sequential_subtract_note"`` (also on stderr) why where it is not the plain choice: one bone
tracked, or ``--resume`` keeping what the frames tracked before did (auto: the choice the run being
resumed recorded, else the trial's other runs' where they agree; :mod:`core.tracking.from_study`).

``--joint-rounds N`` (:data:`ROUNDS_HELP`; ``TrackingOptions.joint_rounds``): joint tracking's rounds
per frame, 1 by default. ``--joint-restart`` (:data:`RESTART_HELP`; ``TrackingOptions.joint_restart``):
joint tracking's rounds after the first start each bone from its prediction, not its previous round's
pose; off by default. One round has nothing to restart: ``--joint-restart`` alone implies
``--joint-rounds 2``, and ``--joint-rounds 1 --joint-restart`` is refused naming both (exit 1). The
report's ``"options"`` and the JSON summary record both for joint runs (``"joint_rounds"``,
``"joint_restart"``, with ``"joint_restart_note"`` where ``--resume`` uses other rounds or the other
restart choice than the run being resumed did); with ``--mode sequential`` they do nothing (a note).

Failure checks (:data:`CHECKS`; the fields of :class:`core.tracking.options.TrackingOptions` of
the same names, :mod:`core.tracking.checks`): ``--collapse-ratio R`` — a score below R × the
bone's recent median score is a *score collapse*, always flagged (default 0.6, in [0, 1]);
``--motion-limit K`` — a pose farther from the constant-velocity prediction than K × the bone's
recent median miss of it is *unexpected motion* (default 6, ≥ 1); ``--motion-floor MM,DEG`` — that
limit is never below MM and DEG for consecutive frames (default 1,2; ≥ 0); ``--sigma-limit K`` — a
confidence σ over K × the bone's recent median σ is *uncertain* (default 3, ≥ 1). A lower limit
or floor, or a higher ratio, sends more frames for review; out-of-range values are refused naming
the option (exit 1).

The final stage's move check (the same table; with ``--final likelihood`` only, ignored with a
note otherwise; :func:`core.tracking.frame_step.stage_move_check`): a frame whose stage moved the
pose (translation) more than ``--stage-move-limit K`` × the median move of the bone's last good
frames (default 4, ≥ 1) and more than ``--stage-move-sigmas S`` × its own translation σ (default
0.5, ≥ 0) is flagged *uncertain*, once the bone has ``--stage-move-frames N`` good frames with a
move (default 5, an integer ≥ 1); such a frame keeps the similarity's pose unless
``--keep-stage-moves`` is given (``TrackingOptions.stage_move_reject=False``: the stage's pose is
kept, still flagged). A flagged move is first confirmed: where the stage run again from the far
side of its pose lands on the same pose, the frame keeps the stage's pose, unflagged, with a note
(:func:`core.tracking.final_stage.confirm_move`).

The trajectory check (the same table; :mod:`core.tracking.flags_post`, run once the run is
complete): a frame whose pose stands off the local fit through its neighbours' poses by more than
``--trajectory-limit K`` × the bone's median residual is flagged *off the trajectory* (default 2.5,
≥ 1), and so is a frame next to flagged ones that stands off by more than K × with them in its fit
and 0.7 K × without (*off the trajectory next to flagged frames*, ``flags_post.NEAR``): K scales both
rules; ``--trajectory-limit off`` or ``--no-trajectory-check`` turns both off
(``TrackingOptions.trajectory_limit=None``).

``--smooth`` (:data:`SMOOTH_HELP`): once the run is complete, each tracked bone's poses are also
smoothed over the trial (:func:`core.tracking.smoothing_trial.smooth_trial`) into
``results/reports/smoothing/<trial>.json`` with their covariance; the journal's poses stay the
results. The JSON summary's ``"smoothed"`` names the report and the bones (a bone with too few poses
is skipped, saying why).

The backward check (the same table; :mod:`core.tracking.backward_check`, run once the run is complete,
before the trajectory check): the run's first frame, registered from a keyframe, is registered again as
any later frame from the frames after it, and flagged *first frame off its backward registration* where
the two registrations disagree by more than ``--backward-limit K`` × the bone's median trajectory
residual (default 1.25, > 0; the pose is kept, the frame sent for review), else noted with the
distance; ``--backward-limit off`` or ``--no-backward-check`` skips it
(``TrackingOptions.backward_limit=None``). The report's ``"options"`` record both limits
(``"trajectory_limit"``, ``"backward_limit"``; null where off).
"""

from __future__ import annotations

import argparse
import sys

from ._shared import (
    EXIT_CANCELLED,
    EXIT_NOTHING_DONE,
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
    warp_device,
)
from .track_options import (
    CHECKS,
    DEFAULT_SEARCH,
    FINALS,
    METRICS,
    RESTART_HELP,
    ROUNDS_HELP,
    SEARCHES,
    STAGE_MOVES,
    SUBTRACT_HELP,
    SUBTRACTS,
    TRAJECTORY_OFF,
    add_check_arguments,
    check_choices,
    check_choices_of_args,
    check_error,
    choices_of,
    joint_rounds_of_args,
    options_from_choices,
    parse_frames,
    parse_limits,
    registration_terms,
    stage_move_note,
    subtract_choice,
)

# the options' names (app.commands.track_options) stay importable from here, as before the split
__all__ = ["CHECKS", "DEFAULT_SEARCH", "FINALS", "HELP", "METRICS", "RESTART_HELP", "ROUNDS_HELP", "SEARCHES",
           "STAGE_MOVES",
           "SUBTRACTS", "SUBTRACT_HELP", "TRAJECTORY_OFF", "add_check_arguments", "check_choices",
           "choices_of", "configure", "final_stage_problem", "options_from_choices", "parse_frames",
           "registration_terms", "resumed_frames", "run", "stage_move_note", "stopped_lines",
           "subtract_choice"]

HELP = "track bones of a study trial, saving each pose as it finishes"

#: ``--smooth``'s help (core.tracking.smoothing_trial)
SMOOTH_HELP = ("once the run is complete, also smooth each bone's poses over the trial (a constant-"
               "acceleration Rauch-Tung-Striebel smoother, its smoothing and the confidence's scale by "
               "maximum likelihood) into results/reports/smoothing/TRIAL.json with their covariance; the "
               "journal's poses stay the results. On the synthetic walking trial's stored runs (seeds 0/3/4, "
               "both modes, this 2-core CPU) x the single-frame Cramer-Rao bound 0.55-1.13 mm / 0.42-1.21 "
               "deg against 1.18-1.92 / 1.27-1.81 per frame, no frame over 4x against 21; it pools frames, "
               "so that bound does not bound it. Default off")


def final_stage_problem(study, trial: str) -> str | None:
    """Why the likelihood final stage cannot run on ``trial`` of ``study`` (an open
    :class:`core.study.Study`), or None: :func:`core.tracking.from_study.final_stage_problem`, the
    test :func:`~core.tracking.from_study.track_study` makes, asked before any work starts."""
    from core.tracking.from_study import final_stage_problem as problem

    return problem(study, trial)


def configure(p: argparse.ArgumentParser) -> None:
    p.description = ("Track bones of a study trial frame after frame. Each pose is saved to the "
                     "study's journal as it finishes; Ctrl-C stops after the registration in "
                     "flight (exit 130) and --resume carries on. JSON summary on stdout.")
    p.add_argument("study", help="study folder (study.json)")
    p.add_argument("--trial", required=True, help="trial name")
    p.add_argument("--bones", default=None, help="comma-separated bone names (default: the trial's bones)")
    p.add_argument("--frames", default=None, help="START:STOP (STOP exclusive; default all frames)")
    p.add_argument("--backward", action="store_true", help="track from the last frame to the first")
    p.add_argument("--device", default=None,
                   help="Warp device: cpu, cuda, cuda:1 (default CUDA when present)")
    p.add_argument("--resume", action="store_true", help="skip frames that already have a pose")
    p.add_argument("--guess", choices=("velocity", "previous", "spline"), default="velocity",
                   help="each frame's starting pose: velocity (constant velocity from the last good "
                        "frames, the default), previous (the last good frame's pose) or spline (a "
                        "spline through the bone's keyframes, between the first and the last)")
    p.add_argument("--mode", choices=("auto", "sequential", "joint"), default="auto",
                   help="joint: register each bone with the others' DRRs subtracted (needs DRR "
                        "intensities that match the radiographs: flatfield-corrected frames and a "
                        "calibrated HU transfer); auto (the default): joint when the trial's frames "
                        "are flatfield-corrected, else sequential")
    p.add_argument("--sequential-subtract", choices=tuple(SUBTRACTS), default="auto", help=SUBTRACT_HELP)
    p.add_argument("--joint-rounds", type=int, default=None, metavar="N", help=ROUNDS_HELP)
    p.add_argument("--joint-restart", action="store_true", help=RESTART_HELP)
    p.add_argument("--metric", default="magnitudes", metavar="magnitudes|components|KIND",
                   help="gradient correlation of gradient magnitudes (default; also 'gc') or of the "
                        "gradient components (Penney's form; better on overlapping bones in our harder "
                        "trial, slower); another core.similarity batched kind (e.g. ncc) as one term")
    p.add_argument("--search", choices=SEARCHES, default=DEFAULT_SEARCH,
                   help="search of a tracked frame: newton (Gauss-Newton steps, the default) or local "
                        "(fitted quadratic models, the default before). On the synthetic 1024^2 walking "
                        "trial (one NVIDIA H200, three bones jointly) newton took 22.5 against 326 ms per "
                        "frame, left 5 frames over 4x their Cramer-Rao bound against 15 and captured first "
                        "frames from 10 mm / 10 deg in 30 of 30 starts against 29; the talus's translation "
                        "was 1.80x its bound against 1.59x. On a CPU at coarse views local was still the "
                        "more accurate in places (harder trial at 192^2: talus 0.055 against 0.130 mm RMS; "
                        "acceptance trial at 256^2: the tibia's rotation 0.29 against 0.76 deg), at 3-6x "
                        "the renders. First frames and retries search globally")
    p.add_argument("--scale", type=float, default=1.0, metavar="S",
                   help="track at reduced resolution: S detector pixels per DRR pixel (1 = full "
                        "resolution, 2 = half: about 4x less work per evaluation, e.g. without a GPU)")
    p.add_argument("--final", choices=FINALS, default="none",
                   help="likelihood: end every registration with a robustly weighted least-squares "
                        "refinement of the pose against the line-integral image; a frame whose refinement "
                        "moves the pose far more than on the bone's other frames is flagged and keeps the "
                        "similarity's pose (the move check below). On the synthetic 1024^2 walking trial "
                        "(100 frames, grid-estimated correction, three bones jointly, 4 px high-pass; one "
                        "NVIDIA H200) against the tracker alone (Gauss-Newton), x the Cramer-Rao bound "
                        "(mm/deg): tibia 1.73/1.85 -> 1.50/1.42, talus 1.80/1.57 -> 1.38/1.31, calcaneus "
                        "1.31/1.52 -> 1.20/1.36, no frame over 4x; 13.9 ms per bone-frame for the stage "
                        "on one NVIDIA H100. Needs flatfield-corrected frames (a trial without is "
                        "refused). Default none")
    p.add_argument("--threshold", type=float, default=200.0, help="bone threshold, HU")
    p.add_argument("--no-confidence", action="store_true", help="skip the per-frame uncertainty")
    p.add_argument("--max-uncertainty", default=None, metavar="MM,DEG",
                   help="flag frames for review whose confidence (length of the sigma vector) exceeds "
                        "MM in translation or DEG in rotation, e.g. 0.3,0.6")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--smooth", action="store_true", help=SMOOTH_HELP)
    add_check_arguments(p)
    p.set_defaults(run=run)


class _Bar:
    """The tracking progress callback ``(done, total, frame_result)``: a bar with the score."""

    def __init__(self, progress: Progress, resumed=frozenset()) -> None:
        self.progress = progress
        self.final = [0, 0, 0]  # bone-frames the final stage ran on, of those took, and rejected
        self.resumed, self.worked = resumed, 0  # (bone, frame) done before (--resume); new ones

    def __call__(self, done: int, total: int, fr) -> None:
        if (fr.bone, fr.frame) in self.resumed:  # taken back from the journal: the ETA starts after it
            self.progress.resumed(done)
        else:  # the steps not reported (poses set by hand) are not this run's work either
            self.worked += 1
            self.progress.resumed(done - self.worked, restart=False)
        taken = (fr.timing or {}).get("likelihood_taken")
        if taken is not None:
            self.final[0] += 1
            self.final[1] += int(bool(taken))  # older results: summed over registrations
            self.final[2] += int(bool((fr.timing or {}).get("likelihood_rejected")))
        self.progress(done, total, f"{text_bar(done, total, 30)} {fr.bone}@{fr.frame} score {fr.score:.3f}")
        if fr.flags:
            self.progress.note(f"flagged {fr.bone}@{fr.frame}: {', '.join(map(str, fr.flags))}")


def run(a: argparse.Namespace) -> int:
    folder = study_folder(a.study)
    limits = parse_limits(a.max_uncertainty)
    if not (a.scale >= 1 and a.scale == a.scale and a.scale < float("inf")):
        raise CliError(f"--scale: expected a number >= 1 (detector pixels per DRR pixel), got {a.scale!r}")
    from core.study import Study
    from core.tracking.from_study import FinalStageError, track_study

    warp_device(a.device)
    checks = check_choices_of_args(a)
    rounds = joint_rounds_of_args(a)
    try:
        opts = options_from_choices(search=a.search, scale=a.scale, mode=a.mode, guess=a.guess,
                                    confidence=not a.no_confidence, metric=a.metric, final=a.final,
                                    max_uncertainty=limits, sequential_subtract=a.sequential_subtract,
                                    joint_restart=a.joint_restart, joint_rounds=rounds, **checks)
    except ValueError as exc:
        raise (check_error(exc) or exc) from None
    note = stage_move_note(checks, a.final)
    if note:
        print(f"{PROG} track: {note}", file=sys.stderr)
    given = [f for f, on in (("--joint-rounds", rounds is not None), ("--joint-restart", a.joint_restart))
             if on]
    if given and a.mode == "sequential":
        print(f"{PROG} track: {', '.join(given)}: no effect with --mode sequential", file=sys.stderr)
    token = CancelToken()
    progress = Progress("track", quiet=a.quiet)
    bar = None
    with Study.open(folder, mode="w") as study, sigint_cancels(token, "track"):
        try:
            trial = study.trial(a.trial)
            frames = parse_frames(a.frames, trial.n_frames)
            if a.backward:
                frames = frames[::-1]
            bones = names(a.bones) or None
            bar = _Bar(progress, resumed_frames(trial, bones, frames) if a.resume else frozenset())
            progress.note(f"trial {a.trial}, frames {frames[0]}-{frames[-1]}: loading the bones' CTs, "
                          "then the first frame (it searches wider: the longest)")
            with stdout_to_stderr():
                result, report = track_study(study, a.trial, bones, frames, options=opts,
                                             device=a.device, resume=a.resume,
                                             threshold_hu=a.threshold, progress=bar,
                                             cancel=token)
        except FinalStageError as exc:  # track_study's refusal, before any work
            raise CliError(f"--final likelihood: {exc}") from None
        except KeyboardInterrupt:  # a second Ctrl-C: stop at once (the journal stays valid)
            token.set()
            result, report = None, {}
        finally:
            progress.close()
    cancelled = token.is_set() or (result is not None and result.status == "cancelled")
    summary = dict(report.get("summary") or {})
    if cancelled:
        summary["status"] = "cancelled"  # never "complete" once the user has pressed Ctrl-C
    out = {"trial": a.trial, "summary": summary, "stopped": report.get("stopped"),
           "flagged": [(f["bone"], f["frame"], f["flags"]) for f in report.get("flagged", [])],
           "normalisation": report.get("normalisation")}
    used = (report.get("options") or {}).get("sequential_subtract")
    if used is not None:  # sequential runs: the neighbours subtracted in each bone's search or not
        out["sequential_subtract"] = used
    why = (report.get("options") or {}).get("sequential_subtract_note")
    if why:  # one bone (nothing to subtract), or resumed with the recorded choice
        out["sequential_subtract_note"] = why
        print(f"{PROG} track: {why}", file=sys.stderr)
    # joint runs: the rounds and their starts (--joint-rounds, --joint-restart), and the note of a resume
    # with other ones
    out.update((k, v) for k, v in (report.get("options") or {}).items()
               if k.startswith(("joint_restart", "joint_rounds")))
    if out.get("joint_restart_note"):
        print(f"{PROG} track: {out['joint_restart_note']}", file=sys.stderr)
    if a.final == "likelihood" and bar is not None:
        # a refinement that moves the pose beyond final_reach, or fails, is not kept, nor one the move
        # check rejected (stage_move_reject)
        ran, took, rejected = bar.final
        out["final_stage"] = {"method": "likelihood", "bone_frames": ran, "refined": took,
                              "rejected": rejected}
        if ran > took:
            why = "it moved them too far or failed"
            if rejected:
                why += f"; the move check rejected it in {rejected}"
            print(f"{PROG} track: the likelihood refinement was kept in {took} of {ran} bone-frames; the "
                  f"others keep the similarity's pose ({why})", file=sys.stderr)
    if a.smooth and result is not None and not cancelled:
        out["smoothed"] = _smooth(folder, a.trial, result.bones, a.threshold)
    print_json(out)
    for line in stopped_lines(report.get("stopped"), tracked=result is not None or cancelled):
        print(f"{PROG} track: {line}", file=sys.stderr)
    if cancelled:
        print(f"{PROG} track: cancelled; the poses finished so far are saved "
              f"('{PROG} track ... --resume' carries on)", file=sys.stderr)
        return EXIT_CANCELLED
    return EXIT_NOTHING_DONE if result is None else EXIT_OK


def _smooth(folder, trial: str, bones, threshold_hu: float) -> dict:
    """``--smooth``: the tracked bones' smoothed poses written beside the results
    (:func:`core.tracking.smoothing_trial.smooth_trial`); the JSON summary's ``"smoothed"``."""
    from core.study import Study
    from core.tracking.smoothing_trial import REPORT_KIND, smooth_trial

    with Study.open(folder, mode="w") as study:
        rep = smooth_trial(study, trial, list(bones), threshold_hu=threshold_hu)
    for b, why in rep["skipped"].items():
        print(f"{PROG} track: {b} not smoothed: {why}", file=sys.stderr)
    return {"report": f"results/reports/{REPORT_KIND}/{trial}.json", "bones": sorted(rep["bones"]),
            "skipped": rep["skipped"]}


def resumed_frames(trial, bones, frames) -> frozenset:
    """``(bone, frame)`` of ``frames`` that ``--resume`` takes back from the bones' journals."""
    rng = set(frames)
    return frozenset((b, f) for b in (bones or trial.bones) if b in trial.bones
                     for f in trial.results(b).done if f in rng)


#: What to do about a bone without a keyframe, after the library's reason.
KEYFRAME_HINT = ("pose it at a frame and mark a keyframe in the window (drag it, then Review > Mark "
                 "keyframe, K), or from Python: Trial.record_pose(bone, frame, T_lab_from_bone)")


def stopped_lines(stopped: dict | None, *, tracked: bool) -> list[str]:
    """The lines on stderr for the bones that were not tracked (``report["stopped"]``: bone ->
    reason), with what to do about a missing keyframe; and, when nothing was tracked, a last
    line saying so (the exit status is then 4)."""
    lines = []
    for bone, why in (stopped or {}).items():
        hint = f"; {KEYFRAME_HINT}" if "no keyframe" in str(why) else ""
        lines.append(f"{bone} not tracked: {why}{hint}")
    if not tracked:
        lines.append("nothing was tracked (exit status 4)")
    return lines
