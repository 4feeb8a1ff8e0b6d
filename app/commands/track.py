"""``talus track``: track bones of a study trial from the command line.

Usage::

    talus track STUDY --trial T [--bones a,b] [--frames 0:500] [--backward] [--device cuda:0]
                [--resume] [--guess velocity|previous|spline] [--mode auto|sequential|joint]
                [--sequential-subtract auto|on|off] [--joint-restart] [--metric magnitudes|components]
                [--search newton|local] [--scale S] [--final none|likelihood]
                [--max-uncertainty MM,DEG] [--no-confidence]
                [--collapse-ratio R] [--motion-limit K] [--motion-floor MM,DEG] [--sigma-limit K]
                [--stage-move-limit K] [--stage-move-sigmas S] [--stage-move-frames N]
                [--keep-stage-moves] [--trajectory-limit K|off] [--no-trajectory-check] [--quiet]

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

``--joint-restart`` (:data:`RESTART_HELP`; ``TrackingOptions.joint_restart``): joint tracking's rounds
after the first start each bone from its prediction, not its previous round's pose; off by default.
The report's ``"options"`` and the JSON summary record it for joint runs (``"joint_restart"``, with
``"joint_restart_note"`` where ``--resume`` uses the other choice than the run being resumed did).

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
kept, still flagged).

The trajectory check (the same table; :mod:`core.tracking.flags_post`, run once the run is
complete): a frame whose pose stands off the local fit through its neighbours' poses by more than
``--trajectory-limit K`` × the bone's median residual is flagged *off the trajectory* (default 2.5,
≥ 1), and so is a frame next to flagged ones that stands off by more than K × with them in its fit
and 0.7 K × without (*off the trajectory next to flagged frames*, ``flags_post.NEAR``): K scales both
rules; ``--trajectory-limit off`` or ``--no-trajectory-check`` turns both off
(``TrackingOptions.trajectory_limit=None``).
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

__all__ = ["CHECKS", "DEFAULT_SEARCH", "FINALS", "HELP", "METRICS", "RESTART_HELP", "SEARCHES", "STAGE_MOVES",
           "SUBTRACTS",
           "SUBTRACT_HELP", "TRAJECTORY_OFF", "add_check_arguments", "check_choices", "choices_of",
           "configure", "final_stage_problem", "options_from_choices", "parse_frames", "registration_terms",
           "resumed_frames", "run", "stage_move_note", "stopped_lines", "subtract_choice"]

HELP = "track bones of a study trial, saving each pose as it finishes"

#: ``--metric``: the gradient correlation of the gradient magnitudes (the default) or of the
#: gradient components (the ``gc`` term's ``components`` option).
METRICS = ("magnitudes", "components")
#: ``--final``: no final stage (the default) or the weighted least-squares refinement.
FINALS = ("none", "likelihood")
#: ``--search``: the Gauss–Newton engine (the default, :data:`core.tracking.options.DEFAULT_SEARCH`;
#: repeated here so that ``--help`` needs no numerical import, a test keeps them equal) or the
#: quadratic-model search.
SEARCHES = ("newton", "local")
DEFAULT_SEARCH = "newton"
#: ``--sequential-subtract``: choice -> ``TrackingOptions.sequential_subtract`` (``auto``, the
#: default: None, which :func:`core.tracking.from_study.track_study` turns on for flatfield-corrected
#: frames).
SUBTRACTS = {"auto": None, "on": True, "off": False}
SUBTRACT_HELP = ("sequential tracking: search each bone with its neighbours' DRRs subtracted (those "
                 "registered earlier in the frame at their poses, the others at their guesses). auto "
                 "(the default): on where the trial's frames are flatfield-corrected (as --mode auto "
                 "decides; it matters with --mode sequential), off on frames divided by the full scale, "
                 "whose intensities the DRRs do not match. On the synthetic 1024^2 acceptance trial (one "
                 "NVIDIA H100, 100 frames, three bones) it took the frames over 4x their Cramer-Rao bound "
                 "left unflagged (tibia/talus/calcaneus) from 9/7/0 to 0/0/0 on seed 0, 9/0/0 to 8/0/0 "
                 "and 4/1/0 to 2/0/0 on seeds 1 and 2, as joint tracking does (1/0/0, 7/0/0, 2/0/0)")
#: ``--joint-restart`` (``TrackingOptions.joint_restart``), shared by ``talus batch`` and the window.
RESTART_HELP = ("joint tracking: start each bone's rounds after the first from its prediction, not from "
                "its previous round's pose. On the synthetic 1024^2 acceptance trial (one NVIDIA H100, seed "
                "0) joint tracking's errors came to sequential's, no difference resolved (x the Cramer-Rao "
                "bound, mm/deg: tibia 1.73/1.85 -> 1.72/1.79, talus 1.80/1.57 -> 1.79/1.58, calcaneus "
                "1.31/1.52 -> 1.29/1.50) at 141 -> 182 evaluations a frame (three bones: 78.6 -> 64.7 "
                "frames/s). Off by default: one synthesis measured (on held-out seed 4 joint tracking as it "
                "is was the better about the tibia's long axis after the first frame)")
#: The failure checks' thresholds: ``TrackingOptions`` field -> (command-line option, default,
#: help). The defaults are :mod:`core.tracking.checks`' and :mod:`core.tracking.options`' constants
#: (a test keeps them equal; they are repeated here so that ``--help`` needs no numerical import).
#: The ``stage_move_*`` entries (:data:`STAGE_MOVES`) are the likelihood final stage's move check.
CHECKS = {
    "collapse_ratio": ("--collapse-ratio", 0.6,
                       "flag a frame whose score falls below R times the bone's recent median score "
                       "('score collapse', never cleared by a confirmed optimum); a ratio in [0, 1], "
                       "default 0.6"),
    "motion_limit": ("--motion-limit", 6.0,
                     "flag a pose farther from the constant-velocity prediction of the bone's last good "
                     "poses than K times the bone's recent median miss of that prediction ('unexpected "
                     "motion'); a factor >= 1, default 6"),
    "motion_floor": ("--motion-floor", (1.0, 2.0),
                     "the motion limit is never below MM millimetres and DEG degrees for consecutive "
                     "frames (grown with the frame gaps); each >= 0, default 1,2"),
    "sigma_limit": ("--sigma-limit", 3.0,
                    "flag a frame whose confidence sigma (mm or degrees) exceeds K times the bone's recent "
                    "median ('uncertain'); a factor >= 1, default 3"),
    "stage_move_limit": ("--stage-move-limit", 4.0,
                         "with --final likelihood only: flag a frame whose final stage moved the pose "
                         "(translation) more than K times the median move of the bone's last good frames "
                         "('uncertain'; such a frame keeps the similarity's pose); a factor >= 1, default 4"),
    "stage_move_sigmas": ("--stage-move-sigmas", 0.5,
                          "with --final likelihood only: never flag a final-stage move of S times the "
                          "frame's own translation sigma or less; a factor >= 0, default 0.5"),
    "stage_move_frames": ("--stage-move-frames", 5,
                          "with --final likelihood only: the move check applies once the bone has N good "
                          "frames with a final-stage move; an integer >= 1, default 5"),
    "stage_move_reject": ("--keep-stage-moves", True,
                          "with --final likelihood only: keep the final stage's pose in a frame whose move "
                          "the check flags (still flagged); default: such a frame keeps the similarity's "
                          "pose"),
    "trajectory_limit": ("--trajectory-limit", 2.5,
                         "once the run is complete, flag every frame whose pose stands off the local fit "
                         "through its neighbours' poses (+-4 frames) by more than K times the bone's median "
                         "residual ('off the trajectory'), and a frame next to flagged ones that stands off "
                         "by more than K times with them in its fit and 0.7 K times without ('off the "
                         "trajectory next to flagged frames'): K scales both rules, 'off' turns both off. "
                         "On the synthetic 1024^2 acceptance trial (three bones jointly, tracked on one "
                         "NVIDIA H100, the pass applied on a CPU) the frames over 4x their Cramer-Rao bound "
                         "left unflagged went from 5 to 1 (to 0 with the next-to-flagged rule, which flagged "
                         "3 more good bone-frames), and 14 of 295 good bone-frames were flagged; a factor "
                         ">= 1 or off, default 2.5"),
}
#: ``--trajectory-limit off`` (and ``--no-trajectory-check``): the trajectory check turned off.
TRAJECTORY_OFF = "off"

#: The :data:`CHECKS` entries of the likelihood final stage's move check (meaningful with ``--final
#: likelihood`` only).
STAGE_MOVES = ("stage_move_limit", "stage_move_sigmas", "stage_move_frames", "stage_move_reject")
_METAVARS = {"collapse_ratio": "R", "motion_limit": "K", "motion_floor": "MM,DEG", "sigma_limit": "K",
             "stage_move_limit": "K", "stage_move_sigmas": "S", "stage_move_frames": "N",
             "trajectory_limit": "K|off"}


def registration_terms(metric: str = "magnitudes") -> tuple:
    """The registration's cost terms for ``--metric`` (:func:`core.tracking.cost.metric_terms`):
    :data:`core.tracking.cost.DEFAULT_TERMS` for ``"magnitudes"`` (or ``"gc"``, its older name),
    with ``components=True`` on its ``gc`` terms for ``"components"``; any other name is one term
    of that :mod:`core.similarity` batched kind (e.g. ``"ncc"``), as before."""
    from core.tracking.cost import metric_terms

    return metric_terms(metric)


def options_from_choices(search: str = DEFAULT_SEARCH, scale: float = 1.0, mode: str = "auto",
                         guess: str = "velocity", confidence: bool = True, metric: str = "magnitudes",
                         final: str = "none", max_uncertainty: tuple[float, float] | None = None,
                         collapse_ratio: float = CHECKS["collapse_ratio"][1],
                         motion_limit: float = CHECKS["motion_limit"][1],
                         motion_floor: tuple[float, float] = CHECKS["motion_floor"][1],
                         sigma_limit: float = CHECKS["sigma_limit"][1],
                         stage_move_limit: float = CHECKS["stage_move_limit"][1],
                         stage_move_sigmas: float = CHECKS["stage_move_sigmas"][1],
                         stage_move_frames: int = CHECKS["stage_move_frames"][1],
                         stage_move_reject: bool = CHECKS["stage_move_reject"][1],
                         trajectory_limit: float | None = CHECKS["trajectory_limit"][1],
                         sequential_subtract: str = "auto", joint_restart: bool = False):
    """The :class:`core.tracking.trial.TrackingOptions` of ``talus track --search S --scale X --mode M
    --guess G --metric C --final F [--no-confidence] [--max-uncertainty MM,DEG] [--collapse-ratio R]
    [--motion-limit K] [--motion-floor MM,DEG] [--sigma-limit K] [--stage-move-limit K]
    [--stage-move-sigmas S] [--stage-move-frames N] [--keep-stage-moves] [--trajectory-limit K|off]``
    — the one mapping of these choices, shared by the command and the window's *Tracking options*
    dialog. ``final``: ``"none"`` or ``"likelihood"`` (``TrackingOptions.refine_likelihood``); the
    last nine are the failure checks' thresholds, the final stage's move check and the trajectory
    check (:data:`CHECKS`; ``trajectory_limit`` None: off), checked by ``TrackingOptions``;
    ``sequential_subtract``: ``"auto"``, ``"on"`` or ``"off"`` (:data:`SUBTRACTS`); ``joint_restart``:
    ``--joint-restart``."""
    from core.tracking.register import RegistrationOptions
    from core.tracking.trial import TrackingOptions

    if final not in FINALS:
        raise ValueError(f"final: expected one of {FINALS}, got {final!r}")
    if sequential_subtract not in SUBTRACTS:
        raise ValueError(f"sequential_subtract: expected one of {tuple(SUBTRACTS)}, "
                         f"got {sequential_subtract!r}")
    reg = RegistrationOptions(terms=registration_terms(metric), bounds=(5.0, 5.0), sigma=(1.0, 1.0),
                              search=search, final_scale=float(scale))
    return TrackingOptions(registration=reg, guess=guess, mode=mode, confidence=bool(confidence),
                           max_uncertainty=max_uncertainty, refine_likelihood=final == "likelihood",
                           collapse_ratio=collapse_ratio, motion_limit=motion_limit,
                           motion_floor=motion_floor, sigma_limit=sigma_limit,
                           stage_move_limit=stage_move_limit, stage_move_sigmas=stage_move_sigmas,
                           stage_move_frames=stage_move_frames, stage_move_reject=stage_move_reject,
                           trajectory_limit=trajectory_limit,
                           sequential_subtract=SUBTRACTS[sequential_subtract], joint_restart=joint_restart)


def subtract_choice(value) -> str:
    """The ``--sequential-subtract`` choice of ``TrackingOptions.sequential_subtract`` ``value``."""
    return next(k for k, v in SUBTRACTS.items() if v is value)


def _choice(field: str, v):
    """A threshold as :data:`CHECKS` holds it: (mm, deg) floats, an int, a bool, a float or None
    (the trajectory check off)."""
    if v is None and field == "trajectory_limit":
        return None
    if field == "motion_floor":
        return tuple(float(x) for x in v)
    if field == "stage_move_frames":
        return int(v)
    if field == "stage_move_reject":
        return bool(v)
    return float(v)


def check_choices(options) -> dict:
    """The failure checks' thresholds and the final stage's move check of ``options``
    (:data:`CHECKS`; None: the defaults)."""
    if options is None:
        return {k: v for k, (_, v, _) in CHECKS.items()}
    return {k: _choice(k, getattr(options, k)) for k in CHECKS}


def choices_of(options) -> dict:
    """The choices of :func:`options_from_choices` that give ``options`` (None: the defaults;
    ``max_uncertainty`` is left out)."""
    if options is None:
        return {"search": DEFAULT_SEARCH, "scale": 1.0, "mode": "auto", "guess": "velocity",
                "confidence": True, "metric": "magnitudes", "final": "none", "sequential_subtract": "auto",
                "joint_restart": False, **check_choices(None)}
    reg = options.registration
    components = any(t.kind == "gc" and t.options.get("components") for t in reg.terms)
    likelihood = bool(getattr(options, "refine_likelihood", False)) or reg.final == "likelihood"
    return {"search": reg.search, "scale": float(reg.final_scale), "mode": options.mode,
            "guess": options.guess, "confidence": bool(options.confidence),
            "metric": "components" if components else "magnitudes",
            "final": "likelihood" if likelihood else "none",
            "sequential_subtract": subtract_choice(getattr(options, "sequential_subtract", None)),
            "joint_restart": bool(getattr(options, "joint_restart", False)), **check_choices(options)}


def final_stage_problem(study, trial: str) -> str | None:
    """Why the likelihood final stage cannot run on ``trial`` of ``study`` (an open
    :class:`core.study.Study`), or None: :func:`core.tracking.from_study.final_stage_problem`, the
    test :func:`~core.tracking.from_study.track_study` makes, asked before any work starts."""
    from core.tracking.from_study import final_stage_problem as problem

    return problem(study, trial)


def parse_frames(text: str | None, n_frames: int) -> list[int]:
    """``"a:b"`` (b exclusive; either side may be empty), ``"a"`` or None (all) → frame list."""
    if text is None:
        return list(range(n_frames))
    try:
        if ":" in text:
            a, b = text.split(":", 1)
            lo = int(a) if a.strip() else 0
            hi = int(b) if b.strip() else n_frames
        else:
            lo = int(text)
            hi = lo + 1
    except ValueError:
        raise ValueError(f"--frames: expected START:STOP or a frame number, got {text!r}") from None
    if not 0 <= lo < hi <= n_frames:
        raise ValueError(f"--frames: {text!r} is not a non-empty range of the trial's {n_frames} frames "
                         f"(0:{n_frames}, STOP exclusive)")
    return list(range(lo, hi))


def parse_limits(text: str | None, option: str = "--max-uncertainty") -> tuple[float, float] | None:
    """``--max-uncertainty MM,DEG`` (or ``option``'s) → ``(mm, deg)``; the range is checked by the
    library."""
    if text is None:
        return None
    try:
        mm, deg = (float(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"{option}: expected MM,DEG (two numbers), got {text!r}") from None
    return mm, deg


def _limit_or_off(text: str):
    """``--trajectory-limit K|off``: a number, or :data:`TRAJECTORY_OFF` (the range is checked by the
    library)."""
    if text.strip().lower() in (TRAJECTORY_OFF, "none"):
        return TRAJECTORY_OFF
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a factor >= 1 or 'off', got {text!r}") from None


def add_check_arguments(p: argparse.ArgumentParser) -> None:
    """The failure checks' options (:data:`CHECKS`), shared by ``talus track`` and ``talus batch``."""
    g = p.add_argument_group("failure checks", "thresholds of the checks that flag frames for review (a "
                                               "lower limit or floor, or a higher ratio, flags more frames)")
    s = p.add_argument_group("final stage move check", "with --final likelihood only: a frame whose "
                                                       "likelihood refinement moved the pose far more than "
                                                       "on the bone's other frames is flagged")
    t = p.add_argument_group("trajectory check", "once the run is complete: frames whose pose stands off "
                                                 "their neighbours' trajectory are flagged")
    for field, (flag, _default, text) in CHECKS.items():
        group = s if field in STAGE_MOVES else t if field == "trajectory_limit" else g
        if field == "trajectory_limit":  # the two spellings refused together (argparse names both)
            one = group.add_mutually_exclusive_group()
            one.add_argument(flag, dest=field, default=None, metavar=_METAVARS[field], type=_limit_or_off,
                             help=text)
            one.add_argument("--no-trajectory-check", dest=field, action="store_const",
                             const=TRAJECTORY_OFF, help=f"no trajectory check (as {flag} off)")
        elif field == "stage_move_reject":
            group.add_argument(flag, dest=field, action="store_const", const=False, default=None, help=text)
        else:
            group.add_argument(flag, dest=field, default=None, metavar=_METAVARS[field],
                               type=None if field == "motion_floor" else float, help=text)


def check_choices_of_args(a: argparse.Namespace) -> dict:
    """The thresholds given on the command line (:func:`add_check_arguments`), as
    :func:`options_from_choices` keywords (``trajectory_limit`` None: turned off); the others keep
    their defaults."""
    out = {}
    for field, (flag, _default, _text) in CHECKS.items():
        v = getattr(a, field, None)
        if v is None:
            continue
        if field == "motion_floor":
            v = parse_limits(v, flag)
        elif field == "trajectory_limit" and v == TRAJECTORY_OFF:
            v = None
        elif field == "stage_move_frames" and v.is_integer():  # argparse gives a float
            v = int(v)  # a fraction stays one, refused by TrackingOptions naming the option
        out[field] = v
    return out


def stage_move_note(checks: dict, final: str) -> str | None:
    """The note for move-check options given without ``--final likelihood`` (they do nothing), or
    None."""
    given = [CHECKS[k][0] for k in STAGE_MOVES if k in checks]
    if not given or final == "likelihood":
        return None
    return f"{', '.join(given)}: no effect without --final likelihood (the move check is the final stage's)"


def check_error(exc: ValueError) -> CliError | None:
    """A :class:`CliError` naming the command-line option for a ``TrackingOptions`` error about one
    of the failure checks' thresholds (its message starts with the field name), else None."""
    text = str(exc)
    for field, (flag, _default, _text) in CHECKS.items():
        if text.startswith(field + ":"):
            return CliError(flag + text[len(field):])
    return None


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
    try:
        opts = options_from_choices(search=a.search, scale=a.scale, mode=a.mode, guess=a.guess,
                                    confidence=not a.no_confidence, metric=a.metric, final=a.final,
                                    max_uncertainty=limits, sequential_subtract=a.sequential_subtract,
                                    joint_restart=a.joint_restart, **checks)
    except ValueError as exc:
        raise (check_error(exc) or exc) from None
    note = stage_move_note(checks, a.final)
    if note:
        print(f"{PROG} track: {note}", file=sys.stderr)
    if a.joint_restart and a.mode == "sequential":
        print(f"{PROG} track: --joint-restart: no effect with --mode sequential", file=sys.stderr)
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
    # joint runs: the rounds' starts (--joint-restart), and the note of a resume with the other choice
    out.update((k, v) for k, v in (report.get("options") or {}).items() if k.startswith("joint_restart"))
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
    print_json(out)
    for line in stopped_lines(report.get("stopped"), tracked=result is not None or cancelled):
        print(f"{PROG} track: {line}", file=sys.stderr)
    if cancelled:
        print(f"{PROG} track: cancelled; the poses finished so far are saved "
              f"('{PROG} track ... --resume' carries on)", file=sys.stderr)
        return EXIT_CANCELLED
    return EXIT_NOTHING_DONE if result is None else EXIT_OK


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
