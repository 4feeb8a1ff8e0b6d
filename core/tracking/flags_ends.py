"""The trajectory check at a trial's first and last frames (:mod:`core.tracking.flags_post`, the ``ends``
and ``crowd`` keywords of :func:`~core.tracking.flags_post.trajectory_review`, defaults :data:`ENDS` and
:data:`CROWD`; ``ends=False``: the check before).

The check judges a frame against the fit through its good neighbours within ±``HALF_WINDOW`` tracked
frames. At a trial's end that window was cut: the last frame's fit was the parabola through the four
frames before it, extrapolated, its residual divided by ``sqrt(1 + leverage)`` = 2.96, while the frame
before it had the last frame in its own fit with a weight of 0.46 (``sqrt(1 + leverage)`` 1.20). So a
bad last frame pulled its neighbour's residual above its own, the worst-first loop flagged the good
neighbour first, then the next, and the bad frame, left with three neighbours, had no fit: noted
unchecked, or flagged "not ruled out" (:data:`~core.tracking.flags_gaps.ONE_SIDED`) — as was a good end
frame whenever one frame within three of it was flagged. The first frame has the backward registration
(:mod:`core.tracking.backward_check`); the last had nothing else.

*The window shifted inside the trial* (``ends``). A frame within ``HALF_WINDOW`` tracked frames of the
first or last frame with a pose (of the frames given: a run's and its journal neighbours) is fitted through
the good frames of the ``2 * HALF_WINDOW``-wide window shifted to lie inside the trial: the last frame
through the eight before it (``sqrt(1 + leverage)`` 1.72), the frame before it through seven before and
the last (whose weight is then 0.3). The frame off now stands off its fit more than its neighbours do
theirs and is flagged first (:class:`~core.tracking.flags_fit._Table`), and a good end frame keeps a fit
when a frame near it is flagged. The pair rule (:mod:`core.tracking.flags_pairs`) no longer puts a frame back
in a pair's fits when its own fit without the pair is extrapolated (the bad last frame had been put back
by its wide residual, and the pair before it flagged through its pull).

*The motion's model error* (:data:`CALIBRATE`). A parabola through the 8 frames on one side follows an
accelerating start less well than one through 4 frames on either side: on the true poses of the tests'
walking talus scene (0.1-2.6 mm a frame early on) it missed frame 0 by 1.2 mm where the cut window's missed
it by 0.05 mm, and flagged good frames 0-3 of a 12-frame trial. So an end frame's residual is divided by
how much wider than the bone's median the residuals of the bone's frames fitted alike are — each frame
with frames at the same offsets (or the mirrored ones), the fit's value extrapolated to it — the larger of
mm and degrees, and not below 1 (:meth:`~core.tracking.flags_fit._Table._factor`; 1 on the tests' smooth
walking track, where it changes nothing). That scene's 12 frames then flag none. On a short trial the
frames fitted alike are few and include the end frame itself, so a bad end frame widens its own
calibration: the tests' walking track of 12 frames, the last frame 0.5° off, caught in 0 of 6 draws (6
without the calibration; 2°: caught in 6, 2-4 good frames flagged a draw against 0-1), 16 frames 3 of 6,
20 frames and more as without it. Leaving out the fits that touch the end frame keeps the short trial's
bad frame but flags the scene's good first frames again (too few fits left to calibrate): not done, a
trade-off on trials under 20 frames.

*The scale* (:data:`SCALE_WITHOUT_ENDS`). The bone's median residual, which sets the limit, is taken over
the frames fitted on both sides, the end frames (extrapolated) left out when enough others have a residual;
before, every frame's residual entered it, the end frames' with the window cut. This moves the limit of
the whole trial, not only of its ends: on d262386 most of the change in good frames flagged is this, in the
trials' middle (below).

*Crowded ends* (``crowd``, :func:`judge_crowded_ends`). A good frame within ``HALF_WINDOW`` of a trial's
end whose cut window (its nearest ``HALF_WINDOW`` tracked frames on each side) holds :data:`CROWD` or more
frames the check flagged and too few good ones for a fit through it — the frames the check before
flagged "not ruled out", when a crowd is flagged about them — is flagged for review (``"off the
trajectory not ruled out (frames 0, 2, 3 near it flagged at the trial's end: ...)"``): its shifted fit
reaches past them to frames further in, which a run of frames off together at a trial's start follows as
well as the frame (seed 4's tibia at 445a8ae and a5fd412, frames 0-8 4.4-10.5x its bound: jointly frame
1, sequentially frame 0 silent without the rule). One or two flagged frames near it no longer send it
to review.

Measured (:mod:`core.studies.tracking.trajectory_ends`, ``resources/benchmarks/tracking_trajectory_ends_
cpu.json``; the check run on this 2-core x86_64 machine, shared). The tests' walking track (60 frames,
0.01 mm / 0.05° noise per axis, 6 draws; one good frame flagged in them without a frame turned), one frame
turned more about z, caught / good frames flagged over the draws, before -> now: the last frame 0.3° 1/6
(+2) -> 3/6 (+1), 0.5° 3/6 (+3) -> 6/6 (+2), 1° 6/6 (+15) -> 6/6 (+1), 2° and 5° 6/6 (+24) -> 6/6 (+1);
the first frame 0.3° 0/6 -> 4/6, 1-5° (+14 to +24) -> (+0 to +1); frames 1-3 and 56-58 caught as before,
good frames flagged 6-12 a cell -> 0-8 (a 5° spike flags neighbours by the near rule as in the trial's
middle). The stored acceptance runs (1024², 100 frames, both modes, tracked on one NVIDIA H100, rebuilt
from the kept errors), frames over 4x their bound left silent and good frames (under 2x) flagged, before ->
the shifted windows with the median as before -> with the median without the end frames (the default):
d262386 (seeds 0, 3, 4) 5 -> 4 -> 3 of 21 and 70 -> 64 -> 53 of 1373; at its end frames (within 4 of a
trial's end) silent 1 -> 0 (seed 4's sequential tibia frame 0 caught) and good flagged 18 -> 18 of 117
with the default, so the 17 fewer good frames flagged (net) and the joint calcaneus frame 30 caught
(4.1x) are frames in the middle whose limit moved with the scale; b797131 2 -> 2 -> 2 of 17, 87 -> 88 ->
85 of 1385; held out (nostage, ea76c8b, 56350ae, a5fd412) 266 -> 269 -> 270 of 455 (seed 4's tibia at
its start, frames off together, 4 more silent with the calibration), 126 -> 128 -> 130 of 2800.
``crowd`` 2 / 3 / 4 / off: d262386 good flagged 57 / 53 / 49 / 47, silent 3 at each; held out silent 268
/ 270 / 272 / 272, good flagged 140 / 130 / 126 / 126. Left: with frames missing just before a trial's end
(the walking track's 52-55 without a pose), the shifted window [51, 59] holds 51 and 56-58 only, and once a
bad last frame is flagged frames 56-58 are flagged "not ruled out" (as the check before flagged them with no
bad frame at all): the window does not reach past frames without a pose.
"""

from __future__ import annotations

import numpy as np

from .flags_fit import ENDS, _Table
from .flags_gaps import ONE_SIDED_FLAG

__all__ = ["CALIBRATE", "CROWD", "ENDS", "SCALE_WITHOUT_ENDS", "judge_crowded_ends"]

#: The bone's median (the check's scale) leaves out the frames fitted through the shifted window when enough
#: others have a residual (module docs, *The scale*; False: the median of every frame's residual with the
#: window cut at the trial's ends, as before — a switch for the study, not a keyword).
SCALE_WITHOUT_ENDS = True
#: A trial's end frames' residuals are divided by how much wider the bone's frames fitted alike (the same
#: one-sided offsets) stand off than its median (module docs, *The motion's model error*).
CALIBRATE = True
#: A good frame at a trial's end (within ``half_window`` of it) is flagged for review when this many frames
#: or more within ``half_window`` tracked frames of it are flagged by the check.
CROWD = 3


def judge_crowded_ends(t: _Table, ok: np.ndarray, use: np.ndarray, judge: np.ndarray, half_window: int,
                       out: dict, crowd: int = CROWD) -> None:
    """Flag into ``out`` the good frames (``use`` and ``judge``) of ``t``'s trial ends whose cut window
    (±``half_window`` tracked frames) holds ``crowd`` or more frames taken out of the fits (``ok`` and not
    ``use``) and fewer than ``degree + 2`` frames in use (no fit through it: the check before gave these
    frames the one-sided flag, :data:`~core.tracking.flags_gaps.ONE_SIDED`); those frames are left in
    ``use`` (a review flag, not an error found)."""
    fr, w = t.fr, half_window * t.step
    gone = ok & ~use
    for i in np.flatnonzero(t.end & use & judge):
        i = int(i)
        lo, hi = max(0, i - half_window), min(len(fr), i + half_window + 1)
        win = [j for j in range(lo, hi) if j != i and ok[j] and abs(int(fr[j]) - int(fr[i])) <= w]
        near = [j for j in win if gone[j]]
        if len(near) >= crowd and len(win) - len(near) < t.degree + 2:
            out[int(fr[i])] = (f"{ONE_SIDED_FLAG} (frames {', '.join(str(int(fr[j])) for j in near)} near it "
                               "flagged at the trial's end: its fit reaches past them to frames further in, "
                               "which a run of frames off together follows as well)")
