"""The records a :func:`core.tracking.trial.track` run keeps between frames — a bone's good
history and scores (:class:`_BoneState`), the run's fixed inputs (:class:`_Run`), the sticky cancel
token — and the initial guess of a frame from that history (:func:`predict_pose`, also exported by
:mod:`core.tracking.trial`, whose module docs describe the guesses) with the constant-velocity
prediction the frame's motion check judges the registrations against (:func:`motion_prediction`).
Shared by :mod:`core.tracking.trial` and :mod:`core.tracking.frame_step`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..geometry.transforms import pose_from_params
from .bones import BoneModel
from .checks import _predict, pose_delta
from .flags_post import BACKWARD_FLAG
from .flags_post import FLAG as TRAJECTORY_FLAG
from .options import TrackingOptions
from .results import FrameResult

__all__ = ["motion_prediction", "predict_pose"]


def motion_prediction(history: Sequence[tuple[int, np.ndarray]], frame: int, center) -> np.ndarray | None:
    """The constant-velocity prediction of ``frame`` from the bone's last two good poses
    (``history``, tracking order), or None with fewer than two: the velocity guess of
    :func:`predict_pose` and the pose :func:`core.tracking.checks.motion_check` judges the frame's
    registrations against. The frame step computes it once per bone and frame and hands it to both
    (``prediction``)."""
    if len(history) < 2:
        return None
    (f0, T0), (f1, T1) = history[-2], history[-1]
    return _predict(f0, T0, f1, T1, frame, np.asarray(center, dtype=float))


def predict_pose(history: Sequence[tuple[int, np.ndarray]], frame: int, center, *,
                 guess: str = "velocity",
                 keyframes: Mapping[int, np.ndarray] | None = None, prediction=None) -> np.ndarray:
    """Initial guess for ``frame`` from the bone's good ``(frame, pose)`` history (in tracking
    order, last = most recent) and its ``keyframes`` (see the module docs). ``prediction``: the
    frame's :func:`motion_prediction` when the caller has it (the velocity guess is then a copy
    of it); None computes it."""
    c = np.asarray(center, dtype=float)
    kf = dict(keyframes or {})
    if guess == "spline" and len(kf) >= 2:
        ks = sorted(kf)
        if ks[0] <= frame <= ks[-1]:
            from scipy.interpolate import CubicSpline

            base = np.asarray(kf[ks[0]], float)
            P = np.array([pose_delta(base, np.asarray(kf[k], float), c) for k in ks])
            bc = "not-a-knot" if len(ks) > 2 else "clamped"
            return pose_from_params(CubicSpline(ks, P, axis=0, bc_type=bc)(frame), center=c, base=base)
    if not history:
        if not kf:
            raise ValueError(f"keyframes: no pose to start frame {frame} from")
        near = min(kf, key=lambda k: (abs(k - frame), k))
        return np.asarray(kf[near], dtype=float)
    f1, T1 = history[-1]
    if guess == "previous" or len(history) < 2 or f1 == frame:
        return np.asarray(T1, dtype=float)
    f0, T0 = history[-2]
    if f0 == f1:
        return np.asarray(T1, dtype=float)
    # the constant-velocity step (motion_prediction: the frame step hands the same one to the motion
    # check of this frame); a copy, the caller's own
    if prediction is None:
        prediction = _predict(f0, T0, f1, T1, frame, c)
    return np.array(prediction, dtype=float)


class _Cancel:
    """A cancel token that stays fired once it has fired (a poll that said "stop" is never lost)."""

    def __init__(self, fn: Callable[[], bool] | None) -> None:
        self.fn, self.fired = fn, False

    def __call__(self) -> bool:
        if not self.fired and self.fn is not None and self.fn():
            self.fired = True
        return self.fired


@dataclass
class _BoneState:
    """What a bone's next frames are registered from: its good ``(frame, pose)`` history (for
    the guesses), its good scores (the score-drop check) and its first good score."""

    history: list = field(default_factory=list)
    scores: list = field(default_factory=list)
    start_score: float | None = None
    sigmas: list = field(default_factory=list)
    reference: float | None = None
    #: the good frames' final-stage moves (mm; :func:`core.tracking.frame_step.stage_move_check`)
    moves: list = field(default_factory=list)

    def add_good(self, frame: int, pose, score: float | None, confidence: dict | None = None) -> None:
        self.history.append((frame, np.asarray(pose, float)))
        if score is not None:
            self.scores.append(score)
            if self.start_score is None:
                self.start_score = score
        t, r = (confidence or {}).get("translation_mm"), (confidence or {}).get("rotation_deg")
        if t is not None and r is not None:
            self.sigmas.append((t, r))

    def add(self, frame: int, fr: FrameResult) -> None:
        """A frame's result: a good one, or one flagged only ``"uncertain"`` (poorly determined,
        not wrong: it still feeds the guesses and the score history, not the σ history or the final
        stage's moves), or a flagged one (:meth:`add_flagged`)."""
        if fr.pose is None:
            return
        # the trajectory post-pass's and the backward check's flags (core.tracking.flags_post,
        # backward_check) came after the run that made the frame: a restored frame feeds the guesses
        # as that run's did
        flags = tuple(x for x in fr.flags if not x.startswith((TRAJECTORY_FLAG, BACKWARD_FLAG)))
        if not flags:
            self.add_good(frame, fr.pose, fr.score, fr.confidence)
            t = fr.timing or {}
            # one stage taken: a frame's timing holds its kept registration's outcome; results
            # written before it did (resumed) summed the stage's moves over a frame's
            # registrations (joint rounds, retries), a taken count above 1, and are left out
            if t.get("likelihood_taken") == 1 and t.get("likelihood_move_mm") is not None:
                self.moves.append(float(t["likelihood_move_mm"]))
        elif all(x.startswith("uncertain") for x in flags):
            self.add_good(frame, fr.pose, fr.score)
        else:
            self.add_flagged(fr.score)

    def add_flagged(self, score: float) -> None:
        """A flagged frame with a pose: while the bone has no good score, the first one's score is
        the reference later frames are compared with (:func:`core.tracking.checks.failures`)."""
        if self.start_score is None and self.reference is None and np.isfinite(score):
            self.reference = float(score)


@dataclass
class _Run:
    """The fixed inputs of a :func:`track` run (``contacts``: the bones'
    :class:`~core.tracking.contact.ContactModel` when joint tracking keeps them apart)."""

    renderer: object
    bones: Sequence[BoneModel]
    names: tuple
    keyframes: Mapping
    options: TrackingOptions
    cancel: _Cancel
    contacts: list | None = None
