"""The final stage's move check of a tracked frame (:func:`stage_move_check`) and its confirmation
(:func:`confirmed`), as :func:`core.tracking.frame_step.track_frame` applies them (both importable from
there; its switches :data:`~core.tracking.frame_step.STAGE_MOVE_CONFIRM` and
:data:`~core.tracking.frame_step.CONFIRM_FLOOR_MM`).

With the final stage, a frame whose stage moved the pose (translation) more than
:data:`STAGE_MOVE_LIMIT` × the median move of the bone's last good frames, and more than half its
own translation σ, is flagged ``"uncertain"`` (:func:`stage_move_check`; recorded, not retried,
still used for the guesses; the thresholds are ``TrackingOptions.stage_move_limit``,
``stage_move_sigmas`` and ``stage_move_frames``): the similarity's optimum and the weighted
least-squares fit disagree far more than they do on that bone's other frames. Such a frame keeps
the similarity's pose — the stage's move is rejected (``stage_move_reject``, the default;
:func:`core.tracking.final_stage.rejected`; the flag says so, ``timing["likelihood_rejected"]``
is 1 and ``likelihood_taken`` 0) — and its confidence stays the stage's (its sandwich plus the
move, which spans both poses). Measured on one NVIDIA H200, same trial and stage (no robust
weights; ``resources/benchmarks/tracking_final_reject_h200.json``): the 17 flagged tibia frames
(72-76, 78-89) rejected, the tibia went from 4.34/1.69 to 2.39/1.80 × its bound (mm/degrees; the
tracker alone 2.21/2.01) and its frames over 4× the bound from 19 to 5 (2 silent, 55 and 91, as
before); the talus and calcaneus unchanged. With the stage's default robust weights
(:data:`core.tracking.final_stage.MODEL`) the check flagged nothing on that trial (tibia
2.16/1.46 ×, 2 frames over 4×, both silent; the tracker alone 7). On that trial the stage moved the tibia
0.08-0.24 mm in frames 72-89 (its good frames' median 0.01-0.02 mm) and its error there was the
move: 19 tibia frames were over 4× their bound with the stage, all unflagged (7 tibia and 1
calcaneus frame without it). The check, applied to that run's per-frame moves and σ, flags 17 of
the 19 and none of the 281 bone-frames within 4× their bound (limits 3-6 the same; 2 flags 15
talus frames); the two left (frames 55 and 91, 0.065 and 0.071 mm against 0.060 mm) moved no more
than usual. Rotation moves do not separate them (good frames' rotation moves reached 5.5× their
recent median), so only translation is checked.
"""

from __future__ import annotations

import statistics
from typing import TYPE_CHECKING

import numpy as np

from .cost import OutsideViewError
from .options import STAGE_MOVE_FRAMES, STAGE_MOVE_LIMIT, STAGE_MOVE_SIGMAS

if TYPE_CHECKING:
    from .attempt import Attempt
    from .frame_records import Work
    from .frame_state import _Run

__all__ = ["confirmed", "stage_move_check"]


def stage_move_check(timing: dict | None, confidence: dict | None, moves, *, n: int = 10,
                     limit: float = STAGE_MOVE_LIMIT, sigmas: float = STAGE_MOVE_SIGMAS,
                     min_frames: int = STAGE_MOVE_FRAMES) -> list[str]:
    """The ``"uncertain"`` flag of a frame whose final stage (``timing`` of its registration: the
    stage taken, its move) moved the pose more than ``limit`` × the median translation move of the
    bone's last ``n`` good frames (``moves``, mm, tracking order; at least ``min_frames`` of them)
    and more than ``sigmas`` × the frame's own translation σ (``confidence``; when it has one): the
    similarity's optimum and the weighted least-squares fit disagree far more than they do on this
    bone's frames. Module docs: what it caught on the acceptance trial."""
    t = timing or {}
    mm = t.get("likelihood_move_mm")
    if not t.get("likelihood_taken") or mm is None or not np.isfinite(mm):
        return []
    recent = [float(v) for v in list(moves or [])[-int(n):] if v is not None and np.isfinite(v)]
    if len(recent) < min_frames:
        return []
    med = statistics.median(recent)
    st = (confidence or {}).get("translation_mm")
    if mm <= limit * med or (st is not None and np.isfinite(st) and mm <= sigmas * st):
        return []
    return [f"uncertain (the final stage moved the pose {mm:.3f} mm from the similarity's optimum; over "
            f"{limit:g} x the bone's recent {med:.3f} mm)"]


def confirmed(run: _Run, frame, i: int, a: Attempt, others, w: Work, moved: list, *,
              floor_mm: float) -> list:
    """The move check's flag ``moved`` of bone ``i``'s attempt ``a``, or none where the stage run again
    from the far side of its pose confirms it (:func:`core.tracking.final_stage.confirm_move`; a note
    says so); the second run's work added to ``w``. Where it lands within ``floor_mm`` (and
    half the move) too: on noisy 128² views (CPU; every stage move sent to it) two of 22 moves, 0.016 and
    0.033 mm but 0.77° and 0.76°, landed 0.006 and 0.010 mm away and were rejected, 0.67-0.75° worse
    (the tracker's floor: :data:`core.tracking.frame_step.CONFIRM_FLOOR_MM`)."""
    from .final_stage import CONFIRM_FRACTION, confirm_move

    try:
        c = confirm_move(run.renderer, frame, a.result, bone=i, center=run.bones[i].centroid,
                         options=run.options.registration, views=tuple(range(frame.n_views)), others=others)
    except OutsideViewError:
        return moved
    if c is None:
        return moved
    w.evaluations += c["evaluations"]
    w.time_s += c["time_s"]
    t = a.result.timing or {}
    mm, deg = t.get("likelihood_move_mm", float("nan")), t.get("likelihood_move_deg", float("nan"))
    if not (c["confirmed"] or (c["mm"] <= min(floor_mm, 0.5 * mm)
                               and c["deg"] <= max(CONFIRM_FRACTION * deg, 0.05))):
        return moved
    a.notes = (*a.notes, f"final stage's move {mm:.3f} mm kept: run again from the far side it ended "
                         f"{c['mm']:.3f} mm, {c['deg']:.3f} deg from its pose")
    return []
