"""The options of ``talus track`` (and ``talus batch``, the window's *Tracking options*): their
choices, help texts and defaults, and the one mapping of them to
:class:`core.tracking.trial.TrackingOptions` (:func:`options_from_choices`) and back
(:func:`choices_of`); parsing of ``--frames``, ``--max-uncertainty`` and the failure checks'
options (:func:`add_check_arguments`). :mod:`app.commands.track` runs the command and re-exports
these names; what each option does is told there.

Nothing here imports ``core`` at module level, so ``talus --help`` needs no numerical import.
"""

from __future__ import annotations

import argparse

from ._shared import CliError

__all__ = ["CHECKS", "DEFAULT_SEARCH", "FINALS", "METRICS", "OFF_CHECKS", "RESTART_FIGURES", "RESTART_HELP",
           "ROUNDS_HELP", "SEARCHES", "STAGE_MOVES", "SUBTRACTS", "SUBTRACT_HELP", "TRAJECTORY_OFF",
           "add_check_arguments",
           "check_choices", "check_choices_of_args", "check_error", "choices_of", "joint_rounds_of_args",
           "options_from_choices", "parse_frames", "parse_limits", "registration_terms", "stage_move_note",
           "subtract_choice"]

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
#: ``--joint-rounds N`` (``TrackingOptions.joint_rounds``), shared by ``talus batch``; the window's
#: *Joint rounds* box.
ROUNDS_HELP = ("joint tracking: rounds per frame, an integer >= 1 (default 1; 2 with --joint-restart). "
               "Round 0 searches every bone from its prediction with its neighbours' DRRs subtracted at "
               "theirs; each further round searches every bone again with its neighbours at the previous "
               "round's poses. On three syntheses of the 1024^2 acceptance trial (one NVIDIA H100) one "
               "round matched sequential tracking on seeds 0 and 3, fell short on seed 4 only where two "
               "rounds fall short too, and was never worse than two where the difference was resolved, at "
               "about 60 percent of the evaluations (121.8 against 202.3 a frame on seed 0). A second round "
               "is for a bone whose neighbours' predictions are poor, as in the first frame")
#: What ``--joint-restart`` did where it was measured (its help's second part; the window's tooltip).
RESTART_FIGURES = ("On the synthetic 1024^2 acceptance trial (one NVIDIA H100, seed 0, two rounds) joint "
                   "tracking's errors came to sequential's, no difference resolved (x the Cramer-Rao bound, "
                   "mm/deg: tibia 1.73/1.85 -> 1.72/1.79, talus 1.80/1.57 -> 1.79/1.58, calcaneus 1.31/1.52 "
                   "-> 1.29/1.50) at 141 -> 182 evaluations a frame (three bones: 78.6 -> 64.7 frames/s). "
                   "Off by default: on held-out seed 3 it left the tibia's rotation worse than sequential's "
                   "(+0.0143 deg), where one round matched sequential")
#: ``--joint-restart`` (``TrackingOptions.joint_restart``), shared by ``talus batch`` and the window.
RESTART_HELP = ("joint tracking: start each bone's rounds after the first from its prediction, not from "
                "its previous round's pose. One round has none: --joint-restart alone implies --joint-rounds "
                "2, and --joint-rounds 1 --joint-restart is refused. " + RESTART_FIGURES)
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
                         "('uncertain'; such a frame keeps the similarity's pose, unless the stage run "
                         "again from the far side of its pose lands on the same pose: then the move is "
                         "kept, unflagged, with a note); a factor >= 1, default 4"),
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
    "backward_limit": ("--backward-limit", 1.25,
                       "once the run is complete, register its first frame again as any later frame, from "
                       "the frames after it, and flag it where the two registrations disagree by more than K "
                       "times the bone's median trajectory residual ('first frame off its backward "
                       "registration'; the pose is kept, the frame sent for review), else note the distance; "
                       "'off' skips that registration. On the synthetic 1024^2 acceptance trial at 8536510 "
                       "(seeds 0, 3 and 4, both modes, tracked on one NVIDIA H100) the 16 good first frames "
                       "came back at most 1.00 times the median away, seed 4's tibia (0.72 deg off) 1.46 and "
                       "1.72 times: 1.25 flags it and no good one (chosen on those runs, none held out); a "
                       "factor >= 1 or off, default 1.25"),
}
#: ``--trajectory-limit off`` (``--no-trajectory-check``), ``--backward-limit off``
#: (``--no-backward-check``): that check turned off.
TRAJECTORY_OFF = "off"
#: The :data:`CHECKS` entries that ``off`` turns off (the choice None), with their second spelling.
OFF_CHECKS = {"trajectory_limit": "--no-trajectory-check", "backward_limit": "--no-backward-check"}

#: The :data:`CHECKS` entries of the likelihood final stage's move check (meaningful with ``--final
#: likelihood`` only).
STAGE_MOVES = ("stage_move_limit", "stage_move_sigmas", "stage_move_frames", "stage_move_reject")
_METAVARS = {"collapse_ratio": "R", "motion_limit": "K", "motion_floor": "MM,DEG", "sigma_limit": "K",
             "stage_move_limit": "K", "stage_move_sigmas": "S", "stage_move_frames": "N",
             "trajectory_limit": "K|off", "backward_limit": "K|off"}


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
                         backward_limit: float | None = CHECKS["backward_limit"][1],
                         sequential_subtract: str = "auto", joint_restart: bool = False,
                         joint_rounds: int | None = None):
    """The :class:`core.tracking.trial.TrackingOptions` of ``talus track --search S --scale X --mode M
    --guess G --metric C --final F [--no-confidence] [--max-uncertainty MM,DEG] [--collapse-ratio R]
    [--motion-limit K] [--motion-floor MM,DEG] [--sigma-limit K] [--stage-move-limit K]
    [--stage-move-sigmas S] [--stage-move-frames N] [--keep-stage-moves] [--trajectory-limit K|off]
    [--backward-limit K|off]`` — the one mapping of these choices, shared by the command and the
    window's *Tracking options* dialog. ``final``: ``"none"`` or ``"likelihood"``
    (``TrackingOptions.refine_likelihood``); the last ten are the failure checks' thresholds, the final
    stage's move check, the trajectory check and the first frame's backward check (:data:`CHECKS`;
    ``trajectory_limit`` or ``backward_limit`` None: that check off), checked by ``TrackingOptions``;
    ``sequential_subtract``: ``"auto"``, ``"on"`` or ``"off"`` (:data:`SUBTRACTS`); ``joint_restart``:
    ``--joint-restart``; ``joint_rounds``: ``--joint-rounds`` (None, not given: 2 with the restart, else
    1, as the command; a number is used as given, ``TrackingOptions`` refusing 1 with the restart)."""
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
                           trajectory_limit=trajectory_limit, backward_limit=backward_limit,
                           sequential_subtract=SUBTRACTS[sequential_subtract], joint_restart=joint_restart,
                           joint_rounds=(2 if joint_restart is True else 1) if joint_rounds is None
                           else joint_rounds)


def subtract_choice(value) -> str:
    """The ``--sequential-subtract`` choice of ``TrackingOptions.sequential_subtract`` ``value``."""
    return next(k for k, v in SUBTRACTS.items() if v is value)


def _choice(field: str, v):
    """A threshold as :data:`CHECKS` holds it: (mm, deg) floats, an int, a bool, a float or None
    (an :data:`OFF_CHECKS` check off)."""
    if v is None and field in OFF_CHECKS:
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
                "joint_restart": False, "joint_rounds": 1, **check_choices(None)}
    reg = options.registration
    components = any(t.kind == "gc" and t.options.get("components") for t in reg.terms)
    likelihood = bool(getattr(options, "refine_likelihood", False)) or reg.final == "likelihood"
    return {"search": reg.search, "scale": float(reg.final_scale), "mode": options.mode,
            "guess": options.guess, "confidence": bool(options.confidence),
            "metric": "components" if components else "magnitudes",
            "final": "likelihood" if likelihood else "none",
            "sequential_subtract": subtract_choice(getattr(options, "sequential_subtract", None)),
            "joint_restart": bool(getattr(options, "joint_restart", False)),
            "joint_rounds": int(getattr(options, "joint_rounds", 1)), **check_choices(options)}


def joint_rounds_of_args(a: argparse.Namespace) -> int | None:
    """``--joint-rounds`` of ``talus track`` / ``talus batch`` (None where not given: 1, or 2 with
    ``--joint-restart``), checked: an integer >= 1, and not 1 with ``--joint-restart`` (which acts on
    the rounds after the first), each refused naming the options."""
    n = getattr(a, "joint_rounds", None)
    if n is None:
        return None
    if n < 1:
        raise CliError(f"--joint-rounds: expected an integer >= 1 (rounds per frame), got {n}")
    if n == 1 and getattr(a, "joint_restart", False):
        raise CliError("--joint-rounds 1 --joint-restart: the restart acts on the rounds after the first, "
                       "and one round has none (give --joint-rounds 2 or more, or leave --joint-rounds out: "
                       "--joint-restart alone implies 2)")
    return n


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
    """``--trajectory-limit K|off`` (``--backward-limit K|off``): a number, or :data:`TRAJECTORY_OFF`
    (the range is checked by the library)."""
    if text.strip().lower() in (TRAJECTORY_OFF, "none"):
        return TRAJECTORY_OFF
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a factor or 'off', got {text!r}") from None


def add_check_arguments(p: argparse.ArgumentParser) -> None:
    """The failure checks' options (:data:`CHECKS`), shared by ``talus track`` and ``talus batch``."""
    g = p.add_argument_group("failure checks", "thresholds of the checks that flag frames for review (a "
                                               "lower limit or floor, or a higher ratio, flags more frames)")
    s = p.add_argument_group("final stage move check", "with --final likelihood only: a frame whose "
                                                       "likelihood refinement moved the pose far more than "
                                                       "on the bone's other frames is flagged")
    t = p.add_argument_group("trajectory check", "once the run is complete: frames whose pose stands off "
                                                 "their neighbours' trajectory are flagged")
    b = p.add_argument_group("backward check", "once the run is complete: its first frame, registered from "
                                               "a keyframe, is registered again from the frames after it")
    for field, (flag, _default, text) in CHECKS.items():
        group = s if field in STAGE_MOVES else {"trajectory_limit": t, "backward_limit": b}.get(field, g)
        if field in OFF_CHECKS:  # the two spellings refused together (argparse names both)
            one = group.add_mutually_exclusive_group()
            one.add_argument(flag, dest=field, default=None, metavar=_METAVARS[field], type=_limit_or_off,
                             help=text)
            what = "trajectory check" if field == "trajectory_limit" else "backward check of the first frame"
            one.add_argument(OFF_CHECKS[field], dest=field, action="store_const",
                             const=TRAJECTORY_OFF, help=f"no {what} (as {flag} off)")
        elif field == "stage_move_reject":
            group.add_argument(flag, dest=field, action="store_const", const=False, default=None, help=text)
        else:
            group.add_argument(flag, dest=field, default=None, metavar=_METAVARS[field],
                               type=None if field == "motion_floor" else float, help=text)


def check_choices_of_args(a: argparse.Namespace) -> dict:
    """The thresholds given on the command line (:func:`add_check_arguments`), as
    :func:`options_from_choices` keywords (``trajectory_limit`` or ``backward_limit`` None: turned
    off); the others keep their defaults."""
    out = {}
    for field, (flag, _default, _text) in CHECKS.items():
        v = getattr(a, field, None)
        if v is None:
            continue
        if field == "motion_floor":
            v = parse_limits(v, flag)
        elif field in OFF_CHECKS and v == TRAJECTORY_OFF:
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
