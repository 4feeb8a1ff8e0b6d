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

*Next to a flagged frame* (:data:`NEAR`, the ``near`` keyword; None: off): leaving the flagged
frames out clears the neighbours they had pulled off their fits — rightly for a frame off only
through that pull, wrongly for one that also stands off by itself. So a frame whose fit changed
when frames near it were flagged is flagged too (``"off the trajectory next to flagged frames"``,
both residuals in the message) when its residual with them in the fit (the first judgement)
exceeds the limit and its residual without them exceeds ``NEAR`` × the limit. The acceptance
trial's tibia frame 81 (jointly, 4.45× its bound in rotation) stood 2.7× the bone's median off the
fit with frame 79 (flagged, 4.26× in translation) in it and 2.0× without (0.257° and 0.196° against
the median 0.096°; ``tracking_silent_checks_per_frame_h100.json``): the only silent frame of that
run, now flagged. A frame far off with quiet neighbours still flags only itself (tests); one with a
neighbour that is itself off by 0.7× the limit flags both, and neighbours near the limit by noise
alone may be flagged with it (a 0.5° spike in the tests' track with every 2nd frame tracked flags
three more, 1.7-2.5× the median residual without the spike).

*Two frames off together* (:data:`PAIR`, the ``pair`` keyword; None: off, the check before it): each
pair of consecutive good frames is judged with both left out of the fits, the frames the other rules
took out only through the pair's pull put back in them, and flagged when both stand off by more than
``pair`` × ``limit`` × the bone's median such residual (:mod:`core.tracking.flags_pairs`, whose docs
say how and what it caught: seed 3's tibia frames 69 and 70 at 6c8beab). It only adds flags.

*Next to a flagged frame, off the same way* (:data:`ALONG`, the ``along`` keyword; None: off): after
those rules, a good frame next to a frame the check flagged is flagged too when its residual without that
frame exceeds the ``near`` limit and points the same way as the flagged frame's (cosine over ``along``):
the flagged frame's pull on its fit had hidden it (:mod:`core.tracking.flags_along`, whose docs say how
and what it caught: seed 4's tibia frame 7 at b797131).

*A frame whose neighbours are flagged* (:data:`REACH`, the ``reach`` keyword; None: off): a good frame
left without a fit once its neighbours are flagged is judged against the line through its nearest
frames judged good further away, or noted :data:`UNCHECKED` where it cannot be
(:mod:`core.tracking.flags_gaps`, whose docs say how and what it caught) — but one whose frames judged
good lie on one side only (a trial's end) is flagged for review instead (:data:`ONE_SIDED`, the
``one_sided`` keyword; False: noted; seed 4's tibia frame 0 at b797131).

*A trial's ends* (:data:`ENDS`, the ``ends`` keyword; False: the check before; :data:`CROWD`, the ``crowd``
keyword, None: off): a frame within ``half_window`` of the first or last frame with a pose is fitted
through the frames of the window shifted inside the trial, not the window cut at the end, so a bad end
frame stands off its fit more than its good neighbours do theirs and is flagged in their place; the
bone's median leaves those frames out (when enough others have residuals); a good end frame with
``crowd`` or more flagged frames near it and no fit through its nearest ones is flagged for review
(:mod:`core.tracking.flags_ends`, whose docs say why and what it changed).

*Moved off by the final stage* (:data:`STAGE`, the ``stage`` keyword; None: off): after those rules, a good
frame whose search's pose before the final stage is known (``searched``; :func:`apply_trajectory_flags`
takes each frame's ``search_pose``) is flagged when it stands off its fit by more than ``stage`` × the
limit and the search's pose, against the same fit, by less than :data:`STAGE_RATIO` × as much: the stage
moved it off (:mod:`core.tracking.flags_stage`, whose docs say how and what it caught: seed 4's calcaneus
frame 53 at b941103, in both modes).

Frames already flagged are neither judged nor used as neighbours. A bone with fewer than
:data:`MIN_FRAMES` frames that have a residual is not judged.

A run over a frame range (``--frames``, a batch task's range, a re-track between keyframes in the
window) is judged with the journal's good poses outside the range as *neighbours*
(:func:`journal_neighbours`: each frame's latest record, when it has a pose and no review flag —
frames tracked before, hand-set poses): they enter the fits like the run's own frames, so the
frames at the range's ends get two-sided fits, and a range of fewer than :data:`MIN_FRAMES` frames
is judged, the neighbours' residuals then giving the bone's scale too (a longer range is scaled by
its own frames: poses that are not the tracker's — an imported, filtered trajectory, poses set by
hand — are smooth, and in the median they took the limit down to :data:`FLOOR`, flagging 8 of 10
good frames of a range in the tests), but they are never flagged by a run that did not track them
(a neighbour over the limit is only left out of the others' fits) and keep the flags (or none) their
own run gave them, as do all frames when the check is turned off. :func:`core.tracking.trial.track`
runs the pass at the end of a complete run (``TrackingOptions.trajectory_limit``, default
:data:`LIMIT`; None: off) and hands the frames whose flag changed to ``record_result`` again, so
the journal and the review panel carry the flag. ``talus batch`` judges a trial's ranges once more
when all of them are done, in one pass over all of their frames
(:func:`core.tracking.batch.trajectory_pass`): each range task saw only the ranges done before it,
so a keyframe tracked by two ranges would otherwise end flagged or not by the order the tasks ran.
The pass took 2-7 ms per bone over 100 frames on this 2-core x86_64 machine (shared, loaded), and
18-25 ms for a 20-frame range with 980 neighbours.

What it caught (:mod:`core.studies.tracking.silent_failures` dumps, judged by
:mod:`core.studies.tracking.silent_checks`; the acceptance trial and two more syntheses of it, scene
seeds 0-2, 1024², 100 frames, grid-corrected, the tracker's defaults jointly and sequentially with
the neighbours subtracted, tracked on one NVIDIA H100 at commit ea76c8b, the pass applied to the
returned poses on this 2-core CPU; ``resources/benchmarks/tracking_silent_checks_h100.json``).
These are runs over the whole trial, which have no neighbours outside them (a resumed run's hand
fixes inside it, ``track``'s ``skip`` poses, are neighbours too): the pass judges them
as it did before ranges took the journal's poses (on 200 synthetic tracks of 5-120 frames, with
frames shifted, flagged and missing, the same flags as the pass before that change). The per-frame
checks flagged none of the 1800 bone-frames. Frames over 4× the Cramér–Rao bound (all of them
tibia frames but two talus frames of seed 1), left silent by the pass without ``near`` → with it:

* seed 0 (the acceptance study's trial): jointly 5 over 4×, silent 1 → 0 (frame 81);
  sequentially 3, 0 → 0;
* seed 1: jointly 12, silent 7 → 7; sequentially 13, 8 → 8;
* seed 2: jointly 3, silent 2 → 1 (frame 11 caught, 25 left); sequentially the same.

Of 39 bone-frames over 4×, 19 were flagged without ``near`` and 22 with it; of 1761 good ones 89
(5.1 %) and 100 (5.7 %; the 11 more 2.0-3.8× their bound). What it does not catch are frames off
with their neighbours — the tibia's error about its long axis is mostly smooth over several frames
(seed 1, frames 6-7 and 37-39 up to 0.46° off; frame 23 4.4× the bound in translation beside
frames 2.8-3.1×): that smooth part fits the neighbours; and single frames off by less than the
limit (in translation seed 1 frame 34, 2.35× the median residual, seed 2 frame 25, 1.9×).
Candidates measured on the same bone-frames (:mod:`core.studies.tracking.silent_checks`; rank AUC of
the 20 silent frames against the 1672 unflagged good ones; silent frames caught when flagging 1 % /
5 % of those good ones): the fit with its 1 or 2 nearest neighbours on each side left out (runs of
frames off) 0.87 / 0.86, 2-3 / 8-9 of 20; ±8 frames, cubic 0.85, 0 / 5; per-axis and Mahalanobis
residuals 0.64-0.81, 2-3 / 7-8; the confidence σ against the bone's median 0.70, 0 / 3; the score
0.74, 0 / 4; σ against the frame's own Cramér–Rao bound (computed at the true pose) 0.44, 0 / 1; the
frame's own bound against the bone's 0.53, 0 / 0; joint against sequential poses 0.51, 0 / 4. None
catches frame 81 flagging 3 % (the residual with every neighbour in the fit over the unflagged
frames' median does at 5 %).

Earlier runs (the tracker before the sequential search subtracted the neighbours,
``resources/benchmarks/tracking_silent_failures_h100.json``):
alternatives measured on joint seed 0 (caught of 5, good frames flagged): ±3
frames, limit 2.5: 4, 12; ±4 frames, limit 3: 4, 7; limit 2.25: 4, 29; each frame judged once with
every neighbour in its fit (no removal of the worst first), ±4, 2.5: 5, 17 — the fifth (frame 81)
flagged only through its neighbour's pull (frame 79, 4.26× in translation), the same pull that
flagged both neighbours of a frame 12× the noise off in the tests; so judged, a straight line
(degree 1) through ±2 frames at 2.5: 5, 45.
"""

from __future__ import annotations

import threading
from dataclasses import replace

import numpy as np

from . import flags_ends
from .flags_along import ALONG, judge_along
from .flags_ends import CROWD, judge_crowded_ends
from .flags_fit import ENDS, FLAG, UNCHECKED, _deltas, _Table  # noqa: F401 (_deltas: the studies')
from .flags_gaps import GAP_DEGREE, GAP_FRAMES, GAP_SCALE, ONE_SIDED, REACH, _judge_gaps
from .flags_pairs import PAIR, PAIR_GATE, Pairs, pair_scale
from .flags_stage import STAGE, STAGE_FLAG, STAGE_RATIO, judge_stage

__all__ = ["ALONG", "BACKWARD_FLAG", "CROWD", "DEGREE", "ENDS", "FLAG", "FLOOR", "GAP_DEGREE", "GAP_FRAMES",
           "GAP_SCALE", "HALF_WINDOW", "LIMIT", "MIN_FRAMES", "NEAR", "ONE_SIDED", "PAIR", "PAIR_GATE",
           "REACH", "STAGE", "STAGE_FLAG", "STAGE_RATIO", "UNCHECKED", "apply_trajectory_flags",
           "journal_neighbours", "release_tables", "trajectory_flags", "trajectory_residuals",
           "trajectory_review"]

#: The flag of :mod:`core.tracking.backward_check` (a first frame whose registration backward from the
#: frames after it lands elsewhere), a review flag run after the tracking as this module's: named here,
#: where :mod:`core.tracking.frame_state` reads both.
BACKWARD_FLAG = "first frame off its backward registration"
#: Neighbours on each side of a frame used for its fit (tracked frames: frame numbers within this
#: many times the frames' median spacing, so that every k-th frame tracked is judged alike). With
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
#: A frame next to flagged ones is flagged too when it stands off the fit through all its good
#: neighbours (the flagged ones in it) by more than the limit and off the fit without them by more
#: than this fraction of the limit (module docs, *Next to a flagged frame*; None: not judged so).
#: Over the six runs of the module docs: 0.7 caught 3 of the 20 silent frames and flagged 11 more
#: of 1761 good bone-frames, 0.6 3 and 16, 0.5 3 and 17, 0.8 1 and 9. On 200 tracks of 100 frames
#: with Gaussian noise alone (the tests' walking motion, 0.01 mm / 0.05° per axis) the check flags
#: 0.38 % of the frames without it and 0.40 % with it.
NEAR = 0.7
#: Residuals below this (mm, degrees) are never flagged: noise-free or exactly smooth tracks.
FLOOR = (0.005, 0.02)
#: Good frames a bone needs before its trajectory is judged.
MIN_FRAMES = 8


#: :func:`trajectory_review` takes the table of local fits (and the first residuals) that
#: :func:`trajectory_residuals` made last for the same frames, poses and options, instead of making it
#: again: the backward check (:mod:`core.tracking.backward_check`) scales its limits by
#: ``trajectory_residuals`` of the run's good frames, the same frames and poses the post-pass then judges
#: when it flags none (exact: the same table, made from the same numbers; False: made anew).
SHARE_TABLE = True
_TABLES: dict = {}  # trajectory_residuals' (thread, inputs' key) -> (table, residuals), taken once


def release_tables() -> None:
    """Let go of the tables :func:`trajectory_residuals` kept for a review that did not come
    (:data:`SHARE_TABLE`; the post-pass off, or the backward check's frame flagged): the tracker calls it
    at a run's end, so a long run's tables are not held after it (another run's taken from under it is
    made again: the same values). Only the calling thread's: a run's backward check and post-pass run in
    its thread (trial._track_frames), and another thread's run keeps its own."""
    tid = threading.get_ident()
    for k in list(_TABLES):  # (a copy of the keys in one call: another thread may add or take one meanwhile)
        if k[0] == tid:
            _TABLES.pop(k, None)


def _key(fr, P, ok, c, half_window, degree, ends) -> tuple:
    return (threading.get_ident(), fr.tobytes(), P.tobytes(), ok.tobytes(), c.tobytes(), int(half_window),
            int(degree), bool(ends))


def _inputs(frames, poses, center):
    """Frame numbers, poses (sorted by frame), which have a pose, the centre, and the sorting order."""
    fr = np.asarray(frames, dtype=int)
    P = np.asarray(poses, dtype=float).reshape(len(fr), 4, 4)
    order = np.argsort(fr, kind="stable")
    fr, P = fr[order], P[order]
    ok = np.all(np.isfinite(P.reshape(len(P), -1)), axis=1)
    return fr, P, ok, np.asarray(center, dtype=float), order


def trajectory_residuals(frames, poses, center, *, half_window: int = HALF_WINDOW,
                         degree: int = DEGREE, ends: bool = ENDS) -> np.ndarray:
    """``(n, 2)`` normalised residuals (mm, degrees) of each pose against the local fit of the others
    (module docs); NaN where a frame has too few neighbours (``degree + 2`` at least) or no pose.
    ``frames``: the frame numbers of ``poses`` (``(n, 4, 4)``, NaN where none; distinct)."""
    fr, P, ok, c, order = _inputs(frames, poses, center)
    t = _Table(fr, P, ok, c, half_window, degree, ends)
    R = t.residuals(ok)
    if SHARE_TABLE:  # (for the post-pass over the same frames; the last few kept)
        key = _key(fr, P, ok, c, half_window, degree, ends)
        mine = [k for k in list(_TABLES) if k[0] == key[0]]  # (list: one call, safe while others add)
        if len(mine) >= 4:  # this thread's oldest let go
            _TABLES.pop(mine[0], None)
        elif len(_TABLES) >= 16:  # (threads gone without release_tables: the oldest of all let go)
            _TABLES.pop(next(iter(list(_TABLES)), None), None)
        _TABLES[key] = (t, R.copy())
    out = np.full((len(P), 2), np.nan)
    out[order] = R
    return out


def trajectory_flags(frames, poses, center, **kw) -> dict[int, str]:
    """Frame number -> the ``"off the trajectory"`` message: the flags of :func:`trajectory_review`
    (the same arguments), without the frames it could not judge."""
    return trajectory_review(frames, poses, center, **kw)[0]


def trajectory_review(frames, poses, center, *, limit: float = LIMIT, half_window: int = HALF_WINDOW,
                      degree: int = DEGREE, floor=FLOOR, min_frames: int = MIN_FRAMES,
                      judged=None, near: float | None = NEAR, reach: int | None = REACH,
                      pair: float | None = PAIR, pair_gate: float = PAIR_GATE,
                      along: float | None = ALONG, one_sided: bool = ONE_SIDED,
                      ends: bool = ENDS, crowd: int | None = CROWD, searched=None,
                      stage: float | None = STAGE, stage_ratio: float = STAGE_RATIO,
                      stage_kept=None) -> tuple[dict[int, str], dict[int, str]]:
    """``(flags, unchecked)``: frame number -> the ``"off the trajectory"`` message, for the good frames
    of one bone (``poses`` ``(n, 4, 4)`` at ``frames``; NaN rows are not good) whose residual exceeds
    ``limit`` × the bone's median (module docs), and frame number -> the :data:`UNCHECKED` note for the
    good frames it could not judge. The worst frame over the limit is flagged first and left out
    of its neighbours' fits before they are judged again, one frame at a time: a frame far off
    would otherwise pull its neighbours' fits and flag them too. ``judged`` (``(n,)`` bool, default
    all): the frames that may be flagged; the others are neighbours only — in the fits (left out
    when over the limit) and, when fewer than ``min_frames`` judged frames have a residual, in the
    median; never flagged. ``near`` (None: off): then each frame whose fit changed because frames
    near it were flagged is flagged too when its residual with them in the fit (the first one)
    exceeds the limit and its residual without them exceeds ``near`` × the limit (module docs).
    ``reach`` (None: off, such frames left unjudged and not noted): a frame left without a fit is
    judged from its nearest good frames within ``reach`` tracked frames, against the bone's frames
    fitted alike (module docs, *A frame whose neighbours are flagged*). ``pair`` (None: off): pairs of
    consecutive frames judged with both left out of the fits, those whose frames both exceed ``pair`` ×
    ``limit`` × the bone's median such residual flagged (and both first residuals over ``pair_gate`` ×
    ``limit`` × the bone's median; module docs, *Two frames off together*). ``along`` (None: off; needs
    ``near``): a good frame next to a flagged one, off the same way, flagged (module docs, *Next to a
    flagged frame, off the same way*). ``one_sided`` (False: noted): a frame left without a fit whose
    frames judged good lie on one side only flagged for review, not noted. ``ends`` (False: the window
    cut at a trial's ends) and ``crowd`` (None: off; needs ``one_sided``): module docs, *A trial's ends*.
    ``searched`` (``(n, 4, 4)``, NaN where none; None: no frame has one) the search's poses before the
    final stage, and ``stage`` (None: off) with ``stage_ratio``: module docs, *Moved off by the final
    stage*; ``stage_kept``: frame number -> the rule's flag of a frame whose search's pose is not known,
    kept where the frame is still good at the rule (:mod:`core.tracking.flags_stage`)."""
    fr, P, ok, c, order = _inputs(frames, poses, center)
    judge = np.ones(len(fr), dtype=bool) if judged is None else np.asarray(judged, dtype=bool)[order]
    if not (judge & ok).any():
        return {}, {}
    hit = _TABLES.pop(_key(fr, P, ok, c, half_window, degree, ends), None) if SHARE_TABLE else None
    if hit is not None:  # trajectory_residuals' table of these frames (SHARE_TABLE), now this review's own
        t, R = hit
    else:
        t = _Table(fr, P, ok, c, half_window, degree, ends)
        R = t.residuals(ok)
    have = np.all(np.isfinite(R), axis=1)
    if have.sum() < min_frames:
        return {}, {}
    # the scale from the judged frames when they are enough (module docs: smooth neighbours)
    own = have & judge
    pick = own if own.sum() >= min_frames else have
    if t.ext and not flags_ends.SCALE_WITHOUT_ENDS:  # the scale as before flags_ends: the windows cut
        Rc = t.cut_residuals(ok)
        hc = np.all(np.isfinite(Rc), axis=1)
        med = np.median(Rc[hc & judge if (hc & judge).sum() >= min_frames else hc], axis=0)
    else:
        if (pick & ~t.end).sum() >= min_frames:  # not a trial's end frames, extrapolated (flags_ends)
            pick = pick & ~t.end
        med = np.median(R[pick], axis=0)
    if t.ext and flags_ends.CALIBRATE:  # a trial's end frames calibrated to that scale (flags_ends)
        t.calibrate(med)
        for i in t.ext:
            R[i] = t.residual(i, ok)
    lim = np.maximum(float(limit) * med, np.asarray(floor, dtype=float))
    use = ok.copy()
    out = {}
    first = R.copy()
    while True:
        z = np.where(use[:, None] & np.isfinite(R), R / lim, 0.0).max(axis=1)
        i = int(np.argmax(z))
        if not z[i] > 1.0:
            break
        tm, rd = R[i]
        if judge[i]:  # a neighbour of the run over the limit: only left out of the fits
            out[int(fr[i])] = (f"{FLAG} ({tm:.3f} mm, {rd:.3f} deg from the fit through its neighbours; "
                               f"limits {lim[0]:.3f} mm, {lim[1]:.3f} deg, {float(limit):g} x the bone's "
                               f"median {med[0]:.3f} mm, {med[1]:.3f} deg)")
        use[i] = False
        for j in range(max(0, i - t.span), min(len(fr), i + t.span + 1)):
            if use[j] and (abs(j - i) <= half_window or t.end[j]):  # its neighbours judged again without it
                R[j] = t.residual(j, use)
    if near is not None:
        # next to flagged frames: off with them in its fit, and still near the limit without them
        lim_near = np.maximum(float(near) * float(limit) * med, np.asarray(floor, dtype=float))
        ok_all = np.isfinite(first).all(axis=1) & np.isfinite(R).all(axis=1)
        hit = use & judge & ok_all
        hit[hit] = ((first[hit] / lim).max(axis=1) > 1.0) & ((R[hit] / lim_near).max(axis=1) > 1.0)
        for i in np.flatnonzero(hit):
            (t0, r0), (tm, rd) = first[i], R[i]
            out[int(fr[i])] = (f"{FLAG} next to flagged frames ({t0:.3f} mm, {r0:.3f} deg from the fit "
                               f"through its neighbours with them, {tm:.3f} mm, {rd:.3f} deg without; limits "
                               f"{lim[0]:.3f} mm, {lim[1]:.3f} deg, {float(limit):g} x the bone's median "
                               f"{med[0]:.3f} mm, {med[1]:.3f} deg, and {float(near):g} x them)")
            use[i] = False
    if pair is not None:
        gate = np.maximum(float(pair_gate) * float(limit) * med, np.asarray(floor, dtype=float))
        _pairs(t, ok, use, judge, float(pair) * float(limit), floor, min_frames, first, gate, lim, out)
    if along is not None and near is not None:
        lim_near = np.maximum(float(near) * float(limit) * med, np.asarray(floor, dtype=float))
        judge_along(t, ok, use, judge, lim_near, float(near) * float(limit), float(along), out)
    if stage is not None and (searched is not None or stage_kept):
        S = None if searched is None else np.asarray(searched, dtype=float).reshape(len(fr), 4, 4)[order]
        at = {int(f): m for m, f in enumerate(fr)}
        kept = {at[int(f)]: msg for f, msg in (stage_kept or {}).items() if int(f) in at}
        judge_stage(t, S, use, judge, med, float(limit), floor, float(stage), float(stage_ratio), out, kept)
    if reach is None:
        return out, {}
    unchecked = _judge_gaps(t, P, c, use, judge, R, float(limit), floor, int(reach), out, bool(one_sided))
    if t.ends and one_sided and crowd is not None:
        judge_crowded_ends(t, ok, use & ~np.isin(fr, list(out)), judge, half_window, out, int(crowd))
    return out, unchecked


def _pairs(t, ok, use, judge, factor: float, floor, min_frames: int, first, gate, lim_one, out: dict) -> None:
    """The pair rule (module docs, *Two frames off together*; :mod:`core.tracking.flags_pairs`): scaled
    by every pair of consecutive good frames (those starting at a judged frame when they are enough),
    judged with all good frames but the pairs it flagged in the fits; flags into ``out`` and takes
    the frames flagged out of ``use``."""
    med, m = pair_scale(t, ok, ok & judge)
    if not m >= min_frames:
        med, m = pair_scale(t, ok, ok)
    if not m >= min_frames:
        return
    pairs = Pairs(t, use, judge, np.maximum(factor * med, np.asarray(floor, dtype=float)), med, factor,
                  first, gate, ok & ~use, lim_one)
    for k, frames in pairs.judge_all():
        for m_, j in enumerate(frames):
            if judge[j] and int(t.fr[j]) not in out:
                out[int(t.fr[j])] = pairs.message(k, m_)


def journal_neighbours(states, frames=()) -> dict[str, dict[int, np.ndarray]]:
    """Bone name -> {frame: pose}: the good poses of each bone's journal (``states``: bone name ->
    :class:`core.study.JournalState`) at frames not in ``frames`` (a run's range) — each frame's
    latest record when it has a pose and no review flag (a tracking result not flagged, a hand-set
    or legacy pose). The neighbours :func:`apply_trajectory_flags` fits through and never flags."""
    rng = {int(f) for f in frames}
    return {b: {int(f): np.asarray(r.pose, dtype=float) for f, r in sorted(st.records.items())
                if int(f) not in rng and r.pose is not None and not (r.tracking or {}).get("flags")}
            for b, st in states.items()}


def apply_trajectory_flags(result, centers, *, limit: float = LIMIT, neighbours=None, **kw):
    """A :class:`~core.tracking.results.TrackingResult` with :func:`trajectory_review`'s flags added to
    its frames' ``flags`` and its :data:`UNCHECKED` notes to their ``notes`` (``centers``: bone name ->
    rotation centre, its centroid), and the results whose flags or notes changed, ``(result,
    changed)``. Frames that carry a flag or note of an earlier post-pass are judged afresh (those
    taken off first), so running it again changes nothing. The registration's own outcome
    (``converged``) stays as it was: the frame passed its checks; the flag asks for review.
    ``neighbours``: bone name -> {frame: pose}, good poses of frames the result does not hold
    (:func:`journal_neighbours`), in the fits and the bone's scale, never judged (module docs)."""
    from .results import TrackingResult

    results = dict(result.results)
    changed = []
    order = sorted(result.frames)
    for b in result.bones:
        near = {int(f): p for f, p in ((neighbours or {}).get(b) or {}).items()
                if (b, int(f)) not in results and p is not None and np.all(np.isfinite(p))}
        base, kept = {}, {}
        for f in order:
            fr = results.get((b, f))
            if fr is None:
                continue
            own = tuple(s for s in fr.flags if not s.startswith(FLAG))
            if fr.search_pose is None:  # the stage rule's flag without the search's pose: kept (flags_stage)
                kept.update((f, s) for s in fr.flags if s.startswith(STAGE_FLAG))
            notes = tuple(s for s in fr.notes if not s.startswith(UNCHECKED))
            if own != fr.flags or notes != fr.notes:
                fr = replace(fr, flags=own, notes=notes)
            base[f] = fr
        fs = [f for f in order if f in base and base[f].pose is not None and not base[f].flags]
        P = np.array([base[f].pose for f in fs] + list(near.values())).reshape(-1, 4, 4)
        judged = np.arange(len(P)) < len(fs)
        more = {"stage_kept": {f: s for f, s in kept.items() if f in fs}}
        if any(base[f].search_pose is not None for f in fs):
            S = np.full_like(P, np.nan)
            for m, f in enumerate(fs):
                if base[f].search_pose is not None:
                    S[m] = base[f].search_pose
            more["searched"] = S
        got, unchecked = (trajectory_review(fs + list(near), P, centers[b], limit=limit, judged=judged,
                                            **{**more, **kw}) if fs else ({}, {}))
        for f, fr in base.items():
            new = replace(fr, flags=(*fr.flags, got[f])) if f in got else fr
            old = results[(b, f)]
            if f in unchecked:  # the same note where it was (a note added after it stays after it)
                same = unchecked[f] in old.notes and tuple(
                    s for s in old.notes if not s.startswith(UNCHECKED)) == new.notes
                new = replace(new, notes=old.notes if same else (*new.notes, unchecked[f]))
            if new.flags != old.flags or new.notes != old.notes:
                changed.append(new)
            results[(b, f)] = new
    return TrackingResult(result.bones, result.frames, results, result.status, result.time_s), changed
