"""Review flags from a bone's whole trajectory, after tracking (:func:`trajectory_flags`).

The checks of :mod:`core.tracking.checks` judge a frame as it is registered — a lost bone, a jump,
a score drop, a flat cost — and see nothing wrong in a frame whose estimate sits a few
Cramér–Rao bound-widths off the truth: the optimiser converged, the score is as usual, the step
from the prediction is as usual. Bone motion is smooth at fluoroscopy frame rates, so such a frame
shows in the trajectory: its pose stands off the curve through its neighbours. This post-pass runs
once the trial is tracked (users review flags after tracking) and flags ``"off the trajectory"``
(:data:`FLAG`) every frame whose pose is far off its neighbours' local fit, measured against the
bone's own scatter:

* each of the bone's good frames ``f`` (a pose, no flag) is compared with the fit of a polynomial
  of degree :data:`DEGREE` through the poses of its good neighbours within ±:data:`HALF_WINDOW`
  frames (``f`` itself left out), in the 6 parameters (mm, rotation vector) of those poses about
  ``f``'s own pose and the bone's centroid — the fit's value at ``f`` is the residual;
* the residual (translation in mm, rotation in degrees) is divided by ``sqrt(1 + leverage)`` of the
  fit at ``f`` (a frame at a trial's end, extrapolated, has a wider residual for the same noise);
* the scale is the median of those normalised residuals over the bone's good frames, translation
  and rotation apart (the bone's own frame-to-frame scatter: its noise, whatever its bound); a
  frame whose residual exceeds :data:`LIMIT` × the scale (and :data:`FLOOR`) in either is flagged.

The worst frame over the limit is flagged first and left out of its neighbours' fits, which are
then judged again (a frame far off pulls its neighbours' fits). The message gives the residual and
the scale, so the review panel says how far off the frame is.
Frames already flagged are neither judged nor used as neighbours. A bone with fewer than
:data:`MIN_FRAMES` good frames is not judged. :func:`core.tracking.trial.track` runs it at the end of
a complete run (``TrackingOptions.trajectory_limit``, default :data:`LIMIT`; None: off) and hands the
frames it flagged to ``record_result`` again, so the journal and the review panel carry the flag.

What it caught (:mod:`core.studies.tracking.silent_failures`; the acceptance trial, 1024², 100
frames, grid-corrected, Gauss–Newton search, tracked on one NVIDIA H100, the pass applied to the
returned poses on this 2-core CPU; ``resources/benchmarks/tracking_silent_failures_h100.json``).
Frames over 4× the Cramér–Rao bound, tibia / talus / calcaneus, silent before → after, and the
bone-frames within 4× that it flagged:

* three bones jointly (the default tracker), scene seed 0 (the acceptance study's trial): 5/0/0 →
  1/0/0 (tibia frame 81, 4.45× in rotation, left), 14 of 295 good bone-frames flagged (4.7 %; their
  errors 1.45-3.95× the bound, none under 1.4×);
* jointly, seed 1: 11/1/0 → 7/0/0, 19 of 288 (1.1-3.9×);
* each bone alone (sequential), seed 0: 11/9/1 → 9/7/0, 16 of 279; seed 1: 14/2/1 → 9/0/0, 19 of
  283.

Of 55 bone-frames over 4×, 22 were flagged; 68 of 1145 good ones were (5.9 %). No per-frame quantity
told the failures apart (rank AUC over the same frames, 0.5 = chance): the confidence σ against the
bone's median 0.43-0.44, the score against its neighbours 0.52, the two views' score gap 0.42,
evaluations 0.43, the fit's roughness 0.43, the last round's move 0.54-0.59, the miss of the motion
prediction 0.43-0.45; the trajectory residual 0.76. What it does not catch are runs of frames off
about the tibia's long axis (seed 1, frames 1-8 and 37-40: up to 0.43° off for several frames, then
back within one frame; sequentially, seed 0, the tibia mostly 0.2-0.6° off over frames 52-78):
smooth within the run, they fit their neighbours.

Alternatives measured on the same frames (joint seed 0 caught of 5, good frames flagged): ±3
frames, limit 2.5: 4, 12; ±4 frames, limit 3: 4, 7; limit 2.25: 4, 29; each frame judged once with
every neighbour in its fit (no removal of the worst first), ±4, 2.5: 5, 17 — the fifth (frame 81)
flagged only through its neighbour's pull (frame 79, 4.26× in translation), the same pull that
flagged both neighbours of a frame 12× the noise off in the tests; so judged, a straight line
(degree 1) through ±2 frames at 2.5: 5, 45.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from .checks import pose_delta

__all__ = ["DEGREE", "FLAG", "FLOOR", "HALF_WINDOW", "LIMIT", "MIN_FRAMES", "apply_trajectory_flags",
           "trajectory_flags", "trajectory_residuals"]

#: The flag's name (the message starts with it).
FLAG = "off the trajectory"
#: Neighbours on each side of a frame used for its fit (frames, by frame number). With
#: :data:`DEGREE` 2 and :data:`LIMIT` 2.5, over the four runs of the module docs: ±3 frames caught
#: 15 of the 55 failures and flagged 56 good bone-frames, ±4 22 and 68, ±5 24 and 107.
HALF_WINDOW = 4
#: Degree of the local polynomial through the neighbours' poses: a bone's acceleration over a few
#: frames at 278 Hz is larger than its registration noise (each frame judged once, a straight line
#: through ±2 frames flagged 45 of 295 good bone-frames where the parabola through ±4 flagged 17).
DEGREE = 2
#: A frame whose normalised residual exceeds this many times the bone's median is flagged (the
#: default of ``TrackingOptions.trajectory_limit``). Over the four runs of the module docs: 2.25
#: caught 26 of the 55 failures and flagged 128 good bone-frames, 2.5 22 and 68, 2.75 18 and 40,
#: 3 14 and 25.
LIMIT = 2.5
#: Residuals below this (mm, degrees) are never flagged: noise-free or exactly smooth tracks.
FLOOR = (0.005, 0.02)
#: Good frames a bone needs before its trajectory is judged.
MIN_FRAMES = 8


def _residual(fr: np.ndarray, P: np.ndarray, use: np.ndarray, i: int, c: np.ndarray, half_window: int,
              degree: int) -> tuple[float, float]:
    """Frame ``i``'s normalised residual (mm, degrees) against the fit through the frames ``use``
    within ``half_window`` of it (NaN with fewer than ``degree + 2``)."""
    near = [j for j in np.flatnonzero(use) if j != i and abs(fr[j] - fr[i]) <= half_window]
    if len(near) < degree + 2:
        return math.nan, math.nan
    A = np.vander((fr[near] - fr[i]).astype(float), degree + 1)
    Y = np.array([pose_delta(P[i], P[j], c) for j in near])
    coef, *_ = np.linalg.lstsq(A, Y, rcond=None)
    r = coef[-1]  # the fit at f, about f's own pose: the residual (sign aside)
    a0 = np.zeros(degree + 1)
    a0[-1] = 1.0
    try:
        lev = float(a0 @ np.linalg.solve(A.T @ A, a0))
    except np.linalg.LinAlgError:
        return math.nan, math.nan
    k = math.sqrt(1.0 + lev)
    return math.sqrt(float(r[:3] @ r[:3])) / k, math.degrees(math.sqrt(float(r[3:] @ r[3:]))) / k


def _inputs(frames, poses, center):
    fr = np.asarray(frames, dtype=int)
    P = np.asarray(poses, dtype=float).reshape(len(fr), 4, 4)
    ok = np.all(np.isfinite(P.reshape(len(P), -1)), axis=1)
    return fr, P, ok, np.asarray(center, dtype=float)


def trajectory_residuals(frames, poses, center, *, half_window: int = HALF_WINDOW,
                         degree: int = DEGREE) -> np.ndarray:
    """``(n, 2)`` normalised residuals (mm, degrees) of each pose against the local fit of the others
    (module docs); NaN where a frame has too few neighbours (``degree + 2`` at least) or no pose.
    ``frames``: the frame numbers of ``poses`` (``(n, 4, 4)``, NaN where none)."""
    fr, P, ok, c = _inputs(frames, poses, center)
    out = np.full((len(P), 2), np.nan)
    for i in np.flatnonzero(ok):
        out[i] = _residual(fr, P, ok, i, c, half_window, degree)
    return out


def trajectory_flags(frames, poses, center, *, limit: float = LIMIT, half_window: int = HALF_WINDOW,
                     degree: int = DEGREE, floor=FLOOR, min_frames: int = MIN_FRAMES) -> dict[int, str]:
    """Frame number -> the ``"off the trajectory"`` message, for the good frames of one bone
    (``poses`` ``(n, 4, 4)`` at ``frames``; NaN rows are not good) whose residual exceeds ``limit`` ×
    the bone's median (module docs). The worst frame over the limit is flagged first and left out
    of its neighbours' fits before they are judged again, one frame at a time: a frame far off
    would otherwise pull its neighbours' fits and flag them too."""
    fr, P, ok, c = _inputs(frames, poses, center)
    R = np.full((len(P), 2), np.nan)
    for i in np.flatnonzero(ok):
        R[i] = _residual(fr, P, ok, i, c, half_window, degree)
    have = np.all(np.isfinite(R), axis=1)
    if have.sum() < min_frames:
        return {}
    med = np.median(R[have], axis=0)
    lim = np.maximum(float(limit) * med, np.asarray(floor, dtype=float))
    use = ok.copy()
    out = {}
    while True:
        z = np.where(use[:, None] & np.isfinite(R), R / lim, 0.0).max(axis=1)
        i = int(np.argmax(z))
        if not z[i] > 1.0:
            return out
        t, r = R[i]
        out[int(fr[i])] = (f"{FLAG} ({t:.3f} mm, {r:.3f} deg from the fit through its neighbours; "
                           f"limits {lim[0]:.3f} mm, {lim[1]:.3f} deg, {float(limit):g} x the bone's "
                           f"median {med[0]:.3f} mm, {med[1]:.3f} deg)")
        use[i] = False
        for j in np.flatnonzero(use):  # its neighbours judged again without it
            if abs(fr[j] - fr[i]) <= half_window:
                R[j] = _residual(fr, P, use, j, c, half_window, degree)


def apply_trajectory_flags(result, centers, *, limit: float = LIMIT, **kw):
    """A :class:`~core.tracking.results.TrackingResult` with :func:`trajectory_flags` added to its
    frames (``centers``: bone name -> rotation centre, its centroid) and the results whose flags
    changed, ``(result, changed)``. Frames that carry a flag of an earlier post-pass are judged
    afresh (the flag taken off first), so running it again changes nothing. The registration's
    own outcome (``converged``) stays as it was: the frame passed its checks; the flag asks for
    review."""
    from .results import TrackingResult

    results = dict(result.results)
    changed = []
    order = sorted(result.frames)
    for b in result.bones:
        base = {}
        for f in order:
            fr = results.get((b, f))
            if fr is None:
                continue
            own = tuple(s for s in fr.flags if not s.startswith(FLAG))
            if own != fr.flags:
                fr = replace(fr, flags=own)
            base[f] = fr
        fs = [f for f in order if f in base and base[f].pose is not None and not base[f].flags]
        P = np.array([base[f].pose for f in fs]) if fs else np.zeros((0, 4, 4))
        got = trajectory_flags(fs, P, centers[b], limit=limit, **kw) if fs else {}
        for f, fr in base.items():
            new = replace(fr, flags=(*fr.flags, got[f])) if f in got else fr
            if new.flags != results[(b, f)].flags:
                changed.append(new)
            results[(b, f)] = new
    return TrackingResult(result.bones, result.frames, results, result.status, result.time_s), changed
