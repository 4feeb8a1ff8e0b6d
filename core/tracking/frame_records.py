"""A bone's record of one frame: the work spent on it over the frame's rounds (:class:`Work`), its
:class:`~core.tracking.results.FrameResult` (:func:`frame_result`), and the flags of a frame a view has no
image for (:func:`missing_flags`). Used by :func:`core.tracking.frame_step.track_frame` (and importable
from there)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from .attempt import Attempt
from .feed import MissingView
from .results import FrameResult

__all__ = ["MISSING_FLAG", "STAGE_KEYS", "UNREADABLE_FLAG", "Work", "frame_result", "missing_flags"]

#: The flag of a frame a view has no image for, its source giving no reason (:func:`missing_flags`).
MISSING_FLAG = "frame missing in view"
#: The flag of a frame a view's image could not be read for, with the source's reason.
UNREADABLE_FLAG = "frame cannot be read"


@dataclass
class Work:
    """Work spent on one bone in one frame, every round and registration added up."""

    evaluations: int = 0
    time_s: float = 0.0
    timing: dict = field(default_factory=dict)

    def add(self, a: Attempt) -> None:
        self.evaluations += a.evaluations
        self.time_s += a.time_s
        for k, v in (a.timing or {}).items():
            self.timing[k] = self.timing.get(k, 0) + v


#: The final stage's outcome in a registration's timing (:mod:`core.tracking.final_stage`): of the
#: registration kept, not summed over a frame's registrations like the times.
STAGE_KEYS = ("likelihood_taken", "likelihood_move_mm", "likelihood_move_deg", "likelihood_rejected")


def frame_result(name: str, f: int, a: Attempt, w: Work) -> FrameResult:
    """The :class:`FrameResult` of a bone's final attempt in frame ``f`` with all its work (the
    times summed; the final stage's outcome, ``STAGE_KEYS``, that of the registration kept; the
    search's pose before its final stage, ``search_pose``, where it has the stage's fit)."""
    res = a.result
    if res is None:
        return FrameResult(name, f, None, np.nan, w.evaluations, w.time_s, False, tuple(a.flags), a.retried,
                           None, w.timing or None)
    timing = w.timing
    if any(k in timing for k in STAGE_KEYS):
        timing = {k: v for k, v in timing.items() if k not in STAGE_KEYS}
        timing.update((k, res.timing[k]) for k in STAGE_KEYS if k in (res.timing or {}))
    prior = getattr(getattr(res, "fit", None), "similarity", None)  # (the search's, before a final stage)
    return FrameResult(name, f, res.pose, res.score, w.evaluations, w.time_s, not a.flags, tuple(a.flags),
                       a.retried, a.confidence, timing or None, a.notes,
                       None if prior is None else np.asarray(prior.pose, dtype=float))


def missing_flags(imgs: Sequence) -> tuple[str, ...]:
    """The flags of a frame some view of which has no image: ``imgs[v]`` None, or a
    :class:`~core.tracking.feed.MissingView` carrying the reason its frame source gave (a file and
    the reader's error; :class:`core.tracking.feed.FrameFeed`). Views with a reason are said in one
    :data:`UNREADABLE_FLAG` flag, counted from 1 as the reasons of
    :func:`core.tracking.from_study.frame_reader` always were (``"frame cannot be read: view 2:
    <file>: <error>"``; one reason shared by every view of a frame of several views is said once,
    without them); views without one in :data:`MISSING_FLAG`'s, counted from 1 too, as the window
    and every other message count views (``"frame missing in view 1, 2"``; it counted from 0 before).
    Empty when every view has its image."""
    said, absent = {}, []
    for v, im in enumerate(imgs):
        if isinstance(im, MissingView) and im.reason:
            said[v] = im.reason
        elif im is None or isinstance(im, MissingView):
            absent.append(v + 1)
    out = []
    if said:
        reasons: dict[str, list[int]] = {}
        for v, r in said.items():
            reasons.setdefault(r, []).append(v + 1)
        if len(imgs) > 1 and len(said) == len(imgs) and len(reasons) == 1:  # the whole frame, one reason
            out.append(f"{UNREADABLE_FLAG}: {next(iter(reasons))}")
        else:
            out.append(f"{UNREADABLE_FLAG}: " + "; ".join(f"view {', '.join(map(str, vs))}: {r}"
                                                          for r, vs in reasons.items()))
    if absent:
        out.append(f"{MISSING_FLAG} {', '.join(map(str, absent))}")
    return tuple(out)
