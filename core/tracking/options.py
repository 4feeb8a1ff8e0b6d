"""The options of :func:`core.tracking.trial.track` (:class:`TrackingOptions`; their meaning is
in :mod:`core.tracking.trial`'s module docs). Importable from :mod:`core.tracking.trial` as well."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .checks import COLLAPSE_RATIO, MOTION_FLOOR, MOTION_LIMIT, SIGMA_LIMIT
from .flags_post import LIMIT as TRAJECTORY_LIMIT
from .register import RegistrationOptions

__all__ = ["BACKWARD_LIMIT", "CHECK_FIELDS", "DEFAULT_SEARCH", "STAGE_MOVE_FIELDS", "STAGE_MOVE_FRAMES",
           "STAGE_MOVE_LIMIT", "STAGE_MOVE_SIGMAS", "TrackingOptions"]

#: With the final stage: a stage that moves a bone's pose (translation) more than this multiple of
#: the median move of the bone's last good frames flags the frame ``"uncertain"``
#: (:func:`core.tracking.frame_step.stage_move_check`; ``TrackingOptions.stage_move_limit``).
STAGE_MOVE_LIMIT = 4.0
#: Stage moves of this fraction of the frame's own translation σ or less are never flagged.
STAGE_MOVE_SIGMAS = 0.5
#: The bone's good frames with a stage move needed before the check applies.
STAGE_MOVE_FRAMES = 5

#: Once a run is complete its first frame is registered again backward from the frames after it
#: (:mod:`core.tracking.backward_check`); a first frame whose two registrations disagree by more than
#: this many times the bone's median trajectory residual is flagged (the default of
#: ``TrackingOptions.backward_limit``; chosen in that module's docs, *Measured*).
BACKWARD_LIMIT = 1.25

#: The thresholds of the tracker's failure checks (:mod:`core.tracking.checks`) that are options:
#: field name -> (what it is, its unit). Their defaults are the module constants of that name.
CHECK_FIELDS = {
    "collapse_ratio": ("a score below this fraction of the bone's recent median score always flags "
                       "(\"score collapse\")", "ratio"),
    "motion_limit": ("a pose farther from the motion prediction than this many times the bone's recent "
                     "median miss flags (\"unexpected motion\")", "times the median miss"),
    "motion_floor": ("the motion limit is never below this for consecutive frames", "mm, degrees"),
    "sigma_limit": ("a confidence sigma longer than this many times the bone's recent median flags "
                    "(\"uncertain\")", "times the median sigma"),
}

#: The final stage's move check (with ``refine_likelihood`` only): field name -> (what it is, its
#: unit), as :data:`CHECK_FIELDS`.
STAGE_MOVE_FIELDS = {
    "stage_move_limit": ("a final-stage move (translation) over this many times the median move of the "
                         "bone's last good frames flags (\"uncertain\")", "times the median move"),
    "stage_move_sigmas": ("moves of this fraction of the frame's translation sigma or less never flag",
                          "times the sigma"),
    "stage_move_frames": ("the bone's good frames with a stage move needed before the check applies",
                          "frames"),
    "stage_move_reject": ("a flagged frame keeps the similarity's pose", "True or False"),
}

#: The registration search of a tracked frame by default (``TrackingOptions().registration.search``):
#: the Gauss–Newton engine. ``"local"`` (the quadratic-model search, the default before) stays
#: selectable (``talus track --search local``, the window's Tracking options). Chosen on
#: ``resources/benchmarks/tracking_search_default_h200.json`` (README, "Which search tracks by default").
DEFAULT_SEARCH = "newton"

_GUESSES = ("previous", "velocity", "spline")
_MODES = ("sequential", "joint", "auto")


@dataclass(frozen=True)
class TrackingOptions:
    """Options of :func:`core.tracking.trial.track` (see that module's docs; ``valid_range`` and
    ``erode_px`` mark the usable fluoroscope pixels, :func:`core.tracking.cost.prepare_frame`).

    ``registration`` searches a tracked frame with the Gauss–Newton engine by default
    (``search="newton"``; first frames and retries: CMA-ES, then Gauss–Newton steps,
    :meth:`~core.tracking.register.RegistrationOptions.widened`); ``search="local"`` keeps the
    quadratic-model search (:data:`DEFAULT_SEARCH`).

    ``refine_likelihood``: every registration (``registration`` and ``first``) ends with the
    weighted least-squares refinement on the device (``final="likelihood"`` of
    :class:`~core.tracking.register.RegistrationOptions`, :mod:`core.tracking.final_stage`): the
    frame's pose and its confidence are the refinement's. Opt-in (it adds a few milliseconds per
    bone and frame on a GPU).

    The failure checks' thresholds (:mod:`core.tracking.checks`, :data:`CHECK_FIELDS`; defaults the
    module constants of the same name): ``collapse_ratio`` (in [0, 1]; a score below it × the
    bone's recent median score is a ``"score collapse"``, always flagged), ``motion_limit`` (≥ 1;
    the ``"unexpected motion"`` limit in multiples of the bone's recent median miss of the motion
    prediction), ``motion_floor`` (mm, degrees, ≥ 0; the least that limit is for consecutive
    frames) and ``sigma_limit`` (≥ 1; the relative ``"uncertain"`` limit in multiples of the
    bone's recent median confidence σ). A lower limit or floor, or a higher ratio, flags more
    frames for review.

    The final stage's move check (:func:`core.tracking.frame_step.stage_move_check`; with
    ``refine_likelihood`` only; defaults the module constants :data:`STAGE_MOVE_LIMIT`,
    :data:`STAGE_MOVE_SIGMAS`, :data:`STAGE_MOVE_FRAMES`): a frame whose stage moved the pose
    (translation) more than ``stage_move_limit`` (≥ 1) × the median move of the bone's last good
    frames and more than ``stage_move_sigmas`` (≥ 0) × its own translation σ is flagged
    ``"uncertain"``, once the bone has ``stage_move_frames`` (an integer ≥ 1) good frames with a
    move; with ``stage_move_reject`` (the default) such a frame keeps the similarity's pose.

    ``sequential_subtract``: in sequential mode each bone's search subtracts the other bones' DRRs
    (those registered earlier in the frame at their registered poses, the others at their keyframe
    of the frame where they have one, else at their guesses), as joint tracking's rounds do; off,
    each bone is searched against the whole image (:mod:`core.tracking.frame_step`). For
    flatfield-corrected frames only (DRR intensities matched). None (the default, "auto"):
    :func:`core.tracking.from_study.track_study` turns it on for sequential tracking of frames it
    finds flatfield-corrected (the test mode ``"auto"`` makes) and off otherwise — on resume, the
    choice the run being resumed recorded (off where it recorded none);
    :func:`~core.tracking.trial.track` alone cannot tell and keeps it off. True or False is used as
    given. One bone tracked has nothing to subtract (the report says false). Joint tracking is the
    same whatever it holds.

    ``joint_rounds`` (an integer ≥ 1, default 1): joint tracking's rounds per frame. Round 0 searches
    every bone from its prediction with its neighbours subtracted at theirs; each further round
    searches every bone again with its neighbours at the previous round's poses. One round by default:
    on three syntheses of the 1024² acceptance trial (one NVIDIA H100;
    ``resources/benchmarks/tracking_joint_one_round_acceptance_seed0_h100.json``, ``…seed4…``,
    ``tracking_joint_restart_acceptance_seed3_h100.json``) one round matched sequential tracking on
    seeds 0 and 3, fell short on seed 4 only where two rounds fall short too, and was never worse
    than two rounds where the difference was resolved (better in 5 of 18 bone-units), at about 60 %
    of the evaluations (121.8 against 202.3 a frame on seed 0). A second round is for a bone whose
    neighbours' predictions are poor, as in the first frame (seed 4, the tibia's rotation at frame
    0: 1.57° with one round, 1.21° with two, 0.25° sequentially). Sequential tracking has one round
    whatever it holds.

    ``joint_restart``: joint tracking's rounds after the first start each bone (one with a history:
    not a first frame) from its prediction, as round 0 does, its neighbours subtracted at their
    previous round's poses; off (the default), from its previous round's pose
    (:mod:`core.tracking.frame_step`, :mod:`core.studies.tracking.joint_gap`). It acts on rounds
    after the first only: with ``joint_rounds=1`` it would do nothing, and is refused (give
    ``joint_rounds=2``; ``talus track --joint-restart`` alone implies two rounds). On the synthetic
    1024² acceptance trial (one NVIDIA H100, seed 0, two rounds) joint tracking's errors came to
    sequential's, no difference resolved (× the Cramér–Rao bound, mm/°: tibia 1.73/1.85 →
    1.72/1.79), at 141 → 182 evaluations a frame (78.6 → 64.7 frames/s, three bones); off by
    default (on held-out seed 3 it left the tibia's rotation worse than sequential's). Sequential
    tracking ignores it.

    ``trajectory_limit`` (≥ 1, or None: off): once a run is complete, frames whose pose stands off
    the local fit through their neighbours by more than this many times the bone's median are
    flagged ``"off the trajectory"`` (:mod:`core.tracking.flags_post`, default its ``LIMIT``), and
    frames next to flagged ones that stand off it by more than this with them in the fit and by more
    than ``flags_post.NEAR`` × this without them.

    ``backward_limit`` (≥ 1, or None: off): once a run is complete, its first frame is registered
    again from the frames after it, as any later frame, and flagged ``"first frame off its backward
    registration"`` where the two registrations disagree by more than this many times the bone's
    median trajectory residual (:mod:`core.tracking.backward_check`, default :data:`BACKWARD_LIMIT`);
    None skips that registration. Below 1 it would flag a first frame whose two registrations
    disagree by less than the bone's typical frame-to-fit residual (the good first frames measured
    came back up to 1.00× it), so it is refused, as ``trajectory_limit`` below 1 is."""

    registration: RegistrationOptions = field(
        default_factory=lambda: RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0),
                                                    search=DEFAULT_SEARCH))
    first: RegistrationOptions | None = None
    guess: str = "velocity"
    mode: str = "sequential"
    joint_rounds: int = 1  # one round since the 1024² syntheses (see above)
    min_score_ratio: float = 0.85
    min_start_ratio: float = 0.7
    max_jump: tuple[float, float] = (4.0, 6.0)
    history: int = 10
    retry_factor: float = 2.0
    verify_restarts: int = 4
    verify_spread: tuple[float, float] = (3.0, 3.0)
    confidence: bool = True
    confidence_step: tuple[float, float] = (0.25, 0.25)
    max_uncertainty: tuple[float, float] | None = None
    valid_range: tuple[float, float] | None = (0.02, 0.999)
    erode_px: int = 3
    profile: bool = False
    contact: bool = False
    contact_weight: float = 0.05
    contact_margin_mm: float = 0.0
    confidence_scale: float = 1.0
    lockstep: bool = True
    joint_restart: bool = False
    sequential_subtract: bool | None = None  # None: auto (track_study decides, track() alone: off)
    refine_likelihood: bool = False
    collapse_ratio: float = COLLAPSE_RATIO
    motion_limit: float = MOTION_LIMIT
    motion_floor: tuple[float, float] = MOTION_FLOOR
    sigma_limit: float = SIGMA_LIMIT
    stage_move_limit: float = STAGE_MOVE_LIMIT
    stage_move_sigmas: float = STAGE_MOVE_SIGMAS
    stage_move_frames: int = STAGE_MOVE_FRAMES
    stage_move_reject: bool = True
    trajectory_limit: float | None = TRAJECTORY_LIMIT
    backward_limit: float | None = BACKWARD_LIMIT

    def __post_init__(self) -> None:
        if not isinstance(self.refine_likelihood, bool):
            raise ValueError(f"refine_likelihood: expected True or False, got {self.refine_likelihood!r}")
        if self.refine_likelihood:  # the registrations' own option
            object.__setattr__(self, "registration", replace(self.registration, final="likelihood"))
            if self.first is not None:
                object.__setattr__(self, "first", replace(self.first, final="likelihood"))
        if not isinstance(self.joint_restart, bool):
            raise ValueError(f"joint_restart: expected True or False, got {self.joint_restart!r}")
        n = self.joint_rounds
        if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
            raise ValueError(f"joint_rounds: expected an integer >= 1 (rounds per frame), got {n!r}")
        object.__setattr__(self, "joint_rounds", int(n))
        if self.joint_restart and n < 2:
            raise ValueError(f"joint_restart: acts on the joint rounds after the first, and joint_rounds={n} "
                             f"has none (give joint_rounds=2 or more, or leave joint_restart off)")
        if self.sequential_subtract is not None and not isinstance(self.sequential_subtract, bool):
            raise ValueError(f"sequential_subtract: expected True, False or None (auto), "
                             f"got {self.sequential_subtract!r}")
        if self.guess not in _GUESSES:
            raise ValueError(f"guess: expected one of {_GUESSES}, got {self.guess!r}")
        if self.mode not in _MODES:
            raise ValueError(f"mode: expected one of {_MODES}, got {self.mode!r}")
        if not 0 <= self.min_score_ratio <= 1:
            raise ValueError(f"min_score_ratio: expected a ratio in [0, 1], got {self.min_score_ratio!r}")
        if not 0 <= self.min_start_ratio <= 1:
            raise ValueError(f"min_start_ratio: expected a ratio in [0, 1], got {self.min_start_ratio!r}")
        if self.retry_factor < 1:
            raise ValueError(f"retry_factor: expected >= 1, got {self.retry_factor!r}")
        if isinstance(self.verify_restarts, bool) or int(self.verify_restarts) != self.verify_restarts \
                or self.verify_restarts < 0:
            raise ValueError(f"verify_restarts: expected an integer >= 0, got {self.verify_restarts!r}")
        if self.max_uncertainty is not None:
            mu = tuple(float(v) for v in self.max_uncertainty)
            if len(mu) != 2 or not all(np.isfinite(v) and v > 0 for v in mu):
                raise ValueError(f"max_uncertainty: expected positive (mm, degrees) or None, "
                                 f"got {self.max_uncertainty!r}")
            if not self.confidence:
                raise ValueError("max_uncertainty: needs confidence=True (the limits apply to it)")
        if not (np.isfinite(self.confidence_scale) and self.confidence_scale > 0):
            raise ValueError(f"confidence_scale: expected a positive factor, got {self.confidence_scale!r}")
        if not (np.isfinite(self.contact_weight) and self.contact_weight >= 0):
            raise ValueError(f"contact_weight: expected a weight >= 0 (per mm²), got {self.contact_weight!r}")
        if not np.isfinite(self.contact_margin_mm):
            raise ValueError(f"contact_margin_mm: expected a finite distance, got {self.contact_margin_mm!r}")
        self._check_thresholds()

    def _check_thresholds(self) -> None:
        """The failure checks' thresholds (:data:`CHECK_FIELDS`): numbers in their ranges."""
        def number(name, v) -> float:
            if isinstance(v, bool) or not isinstance(v, int | float | np.integer | np.floating) \
                    or not np.isfinite(v):
                raise ValueError(f"{name}: expected a finite number, got {v!r}")
            return float(v)

        if not 0 <= number("collapse_ratio", self.collapse_ratio) <= 1:
            raise ValueError(f"collapse_ratio: expected a ratio in [0, 1] (of the bone's recent median "
                             f"score), got {self.collapse_ratio!r}")
        for name, what in (("motion_limit", "median miss of the motion prediction"),
                           ("sigma_limit", "median confidence sigma")):
            v = getattr(self, name)
            if number(name, v) < 1:
                raise ValueError(f"{name}: expected a factor >= 1 (times the bone's recent {what}), "
                                 f"got {v!r}")
        try:
            floor = tuple(self.motion_floor)
        except TypeError:
            floor = ()
        if len(floor) != 2 or not all(number("motion_floor", v) >= 0 for v in floor):
            raise ValueError(f"motion_floor: expected (mm, degrees), each a number >= 0, "
                             f"got {self.motion_floor!r}")
        object.__setattr__(self, "motion_floor", tuple(float(v) for v in floor))
        if number("stage_move_limit", self.stage_move_limit) < 1:
            raise ValueError(f"stage_move_limit: expected a factor >= 1 (times the bone's recent median "
                             f"final-stage move), got {self.stage_move_limit!r}")
        if number("stage_move_sigmas", self.stage_move_sigmas) < 0:
            raise ValueError(f"stage_move_sigmas: expected a factor >= 0 (of the frame's translation "
                             f"sigma), got {self.stage_move_sigmas!r}")
        n = self.stage_move_frames
        if number("stage_move_frames", n) != int(n) or n < 1:
            raise ValueError(f"stage_move_frames: expected an integer >= 1 (good frames), got {n!r}")
        object.__setattr__(self, "stage_move_frames", int(n))  # 5.0 is kept (and reported) as 5
        if not isinstance(self.stage_move_reject, bool):
            raise ValueError(f"stage_move_reject: expected True or False, got {self.stage_move_reject!r}")
        if self.trajectory_limit is not None and number("trajectory_limit", self.trajectory_limit) < 1:
            raise ValueError(f"trajectory_limit: expected a factor >= 1 (times the bone's median residual) "
                             f"or None, got {self.trajectory_limit!r}")
        if self.backward_limit is not None and number("backward_limit", self.backward_limit) < 1:
            raise ValueError(f"backward_limit: expected a factor >= 1 (times the bone's median trajectory "
                             f"residual) or None (off), got {self.backward_limit!r}")

    @property
    def first_options(self) -> RegistrationOptions:
        return self.first or self.registration.widened(2.0)
