"""The trajectory check's frames whose neighbours are all flagged (:mod:`core.tracking.flags_post`).

:data:`REACH` is the ``reach`` keyword's default of :func:`core.tracking.flags_post.trajectory_review`
(None: off). Once frames are flagged, a good frame with fewer than ``DEGREE + 2`` good neighbours
within ±``HALF_WINDOW`` (:mod:`core.tracking.flags_post`'s) has no fit, and the check before this
rule never judged it (seed 4's sequential tibia frame 0, 1.31° off, beside flagged frames 1-4). Such
a frame is judged against the straight line (:data:`GAP_DEGREE`) through its nearest *frames judged
good* — judged by their own fits and not flagged, so not other frames without a fit —
:data:`GAP_FRAMES` / 2 on each side within ``reach`` tracked frames. Its residual (normalised by
``sqrt(1 + leverage)`` as the check's own fits) is scaled by the median
residual of the bone's :data:`GAP_SCALE` frames nearest to it, each fitted alike (through the frames
judged good at the same frame offsets from it, or the mirrored ones): a local scale, which grows
with the gap and with the motion's acceleration there, where the bone's median does neither. Over
``limit`` × that scale (and ``FLOOR``) it is flagged (``"off the trajectory (... from the line
through its nearest frames judged good 14, 15, 25, 26, its neighbours flagged; ...)"``). A frame
with fewer than two such frames on a side — at a trial's ends, mostly — is not judged: it gets the
note :data:`~core.tracking.flags_fit.UNCHECKED` (not a flag), which
:func:`~core.tracking.flags_post.apply_trajectory_flags` puts in the frame's
``notes`` (journaled with the frame; the frames table shows it as the frame's reason, a batch's
trajectory pass names it) so a user sees that the check could not judge it. Lines extrapolated from one
side were tried (the nearest four frames judged good on either side): on the stored runs below they
flagged 5 of the 27 frames at a trial's end, 3 of them over 4× the bone's bound, but 4 of the 5 were
flagged with their true pose put in their place too — a line from frames 3-9 missed the walking
motion's first frame by 0.87-1.17 mm (normalised), where the frames' errors were 0.05-0.10 mm — and
only seed 4's sequential tibia frame 0 was caught by its error (1.10° against a limit of 1.03°).
Judged instead relative to another bone of the run (the pose in that bone's frame where both are
judged good: the foot's shared motion drops out, the line from frames 3-6 missing the tibia's true
first frame by 0.26 mm / 0.19° instead of 1.88 mm / 0.87°, not normalised), the same one-sided lines
left all 27 within the limit (0.26-0.97 of it; the 4 over 4× at 0.43-0.80): the other bone's errors
widen the scale as much (a prototype, not kept).

*One side only* (:data:`ONE_SIDED`, the ``one_sided`` keyword of
:func:`~core.tracking.flags_post.trajectory_review`; False: noted as before). A frame left without a fit
whose frames judged good lie on one side only — a trial's first or last frames beside flagged ones — is
flagged for review (``"off the trajectory not ruled out (trajectory unchecked: its neighbours flagged; the
nearest frames judged good, 4, 5, 6, 9, on one side only: ...)"``) instead of noted: the check cannot judge
it, and its neighbours' flags say the trial is in trouble there. Seed 4's tibia frame 0 at b797131, jointly
(0.65° off, 5.7x its bound; ``resources/benchmarks/tracking_acceptance_seed4_final_b797131_h100.json``) was
noted so and silent: its backward registration (:mod:`core.tracking.backward_check`) landed 0.084° from it,
0.83x the bone's median residual against a limit of 1.25x, which ``TrackingOptions`` does not let go under 1
(seed 3's good first tibia frame came back 1.00x). Flagging the one-sided frames costs what is noted: on the
stored runs of :mod:`core.studies.tracking.trajectory_silent` (its JSON) 10 frames at b797131 (6 good, under
2x their bound, of 1385; the one over 4x caught), and on the held-out sets 44 (the stage off at 445a8ae /
782362a, seeds 0-2 at ea76c8b, seeds 3-4 at 56350ae / a5fd412; 14 good of 2800, 7 over 4x), each frame noted
when judged without this rule and :mod:`core.tracking.flags_along`'s. Frames noted for other reasons (fewer
than two frames judged good on a side within ``reach``) stay noted. With ``one_sided`` (the default) the
flag replaces the note; the review panel shows it as a flag.

Measured (:mod:`core.studies.tracking.trajectory_gaps`,
``resources/benchmarks/tracking_trajectory_gaps_cpu.json``; the stored runs of seeds 0-4, 1024²,
100 frames, jointly and sequentially, tracked on one NVIDIA H100 — seeds 0-2 at ea76c8b, their poses
kept; seeds 3 and 4 at 56350ae and seed 4 with the bones kept apart at a5fd412, their poses rebuilt
from the kept errors and the seed's truth — the check run on this 2-core x86_64 CPU, shared): of 3600
bone-frames, 30 good ones were left without a fit, 4 of them over 4× the bone's bound (seed 4's tibia
frame 0 in its three runs, frame 1 jointly with the bones apart). 3 lie between frames judged good
(tibia frame 14: seed 1 jointly, seed 4 kept apart in both modes), all within 4× and none flagged;
27 at a trial's end (frames 0, 1, 98, 99) get the note, the 4 over 4× among them. No flag changed:
silent frames over 4× and good frames flagged are as before on every run. On the tests' walking track
(100 frames, noise 0.01 mm / 0.05° per axis, 200 draws) with frames 16-19 and 21-24 0.6° off by
turns about z, frame 20 among them was left without a fit in 176-190 draws of 200 and then flagged in
5 of 186 (2.7 %) when good, 43 of 184 (23 %) when 0.15° off, 170 of 190 (89 %) at 0.3°, 172 of 176 at
0.5°; the spikes next to it that lost their fit once the others were flagged are judged the same way
(the check before left one of them, 19 or 21, unflagged in the tests' draw). The rule's sizes (a line,
2 + 2 frames, 16 fitted alike, ±12) were chosen on these counts, seeds 3 and 4 included. That 2.7 %
(0.9-6.2 % at 95 %) is about 7× the false-flag rate of the check's own fits on the same draws
without spikes, 79 of 20000 good frames (0.40 %; ``synthetic['main']`` of the JSON): a wider gap
and a median of 16 frames make a noisier limit. Accepted because such frames are rare — 3 judged in
the stored runs' 3600 bone-frames, about 0.08 false flags expected there, where the check flagged
228 of their 3307 good bone-frames (6.9 %) — and a flag only asks for review. These counts were
measured at 9f7693d, before the pair rule (:mod:`core.tracking.flags_pairs`) became default; run again
with it at d904484 (the JSON; ``along`` and ``one_sided`` off, as the rule was measured), the frames
without a fit, their notes and the rule's flags are the same, the check flags 238 of the 3307 good
bone-frames (7.2 %; seed 2 24 -> 26, seed 4 interpenetrating 29 -> 31, kept apart 33 -> 39), and the
walking track's frame 20 is flagged in 1 of 186 draws when good (0.5 %, 0.01-3.0 % at 95 %), 43 of 184
at 0.15°, 171 of 190 at 0.3°, 172 of 176 at 0.5°.
"""

from __future__ import annotations

import math

import numpy as np

from .flags_fit import FLAG, UNCHECKED, _deltas, _Table

__all__ = ["GAP_DEGREE", "GAP_FRAMES", "GAP_SCALE", "ONE_SIDED", "ONE_SIDED_FLAG", "REACH"]

#: A good frame left without a fit (fewer than ``DEGREE + 2`` good neighbours within
#: ±:data:`HALF_WINDOW`) is judged from its nearest good frames within this many tracked frames on
#: either side (the ``reach`` keyword; None: left unjudged; module docs, *A frame whose neighbours
#: are flagged*).
REACH = 12
#: Such a frame is judged against the straight line (degree :data:`GAP_DEGREE`) through its this many
#: nearest good frames within :data:`REACH`, ...
GAP_FRAMES = 4
#: ... the degree of that fit ...
GAP_DEGREE = 1
#: ... scaled by the median residual of the bone's this many good frames nearest to it, each fitted
#: alike (through the good frames at the same offsets from it, or mirrored).
GAP_SCALE = 16
#: A frame left without a fit whose nearest frames judged good lie on one side only (a trial's end) is
#: flagged for review (:data:`ONE_SIDED_FLAG`) rather than noted :data:`~core.tracking.flags_fit.UNCHECKED`
#: (the ``one_sided`` keyword's default of :func:`core.tracking.flags_post.trajectory_review`; False:
#: noted; module docs, *One side only*).
ONE_SIDED = True
#: The message of such a frame starts with this (the check's flag, :data:`~core.tracking.flags_fit.FLAG`).
ONE_SIDED_FLAG = f"{FLAG} not ruled out"


def _gap_fit(t: _Table, use: np.ndarray, i: int, reach: int) -> tuple[np.ndarray, bool]:
    """Frame ``i``'s nearest good frames (in ``use``) within ``reach`` tracked frames, half of
    :data:`GAP_FRAMES` on each side, sorted, and whether both sides have them (else the nearest
    :data:`GAP_FRAMES` on whichever side, which may be fewer)."""
    fr, half = t.fr, GAP_FRAMES // 2
    d = fr - fr[i]
    near = use & (np.abs(d) <= reach * t.step)
    before = np.flatnonzero(near & (d < 0))[::-1][:half]
    after = np.flatnonzero(near & (d > 0))[:half]
    if len(before) == half and len(after) == half:
        return np.sort(np.r_[before, after]), True
    nb = np.flatnonzero(near & (d != 0))
    return np.sort(nb[np.argsort(np.abs(d[nb]), kind="stable")][:GAP_FRAMES]), False


def _gap_residuals(t: _Table, P: np.ndarray, c: np.ndarray, use: np.ndarray, i: int, nb: np.ndarray):
    """Frame ``i``'s normalised residual (mm, degrees) against the line (:data:`GAP_DEGREE`) through
    frames ``nb``, and ``(m, 2)`` those of the bone's :data:`GAP_SCALE` nearest other good frames
    (fewer where fewer can be) each fitted through the good frames at the same frame offsets from it,
    or the mirrored ones (the fit's weights are the same); None when singular."""
    fr = t.fr
    off = fr[nb] - fr[i]
    x = off.astype(float)
    A = np.vander(x, GAP_DEGREE + 1)
    AtA = A.T @ A
    if abs(np.linalg.det(AtA)) < 1e-12:
        return None
    row, k = np.linalg.solve(AtA, A.T)[-1], math.sqrt(1.0 + float(np.linalg.inv(AtA)[-1, -1]))

    def norm(r):
        return np.c_[np.linalg.norm(r[:, :3], axis=1) / k, np.degrees(np.linalg.norm(r[:, 3:], axis=1)) / k]

    own = norm((row @ _deltas(np.repeat(P[i:i + 1], len(nb), axis=0), P[nb], c))[None])[0]
    js = np.flatnonzero(use)
    js = js[js != i]
    rows, at = [], []
    for sign in (1, -1):
        want = fr[js, None] + sign * off
        idx = np.minimum(np.searchsorted(fr, want), len(fr) - 1)
        good = ((fr[idx] == want) & use[idx] & (idx != i)).all(axis=1)
        a, b = js[good], idx[good]
        if len(a):
            Y = _deltas(np.repeat(P[a], len(off), axis=0), P[b.ravel()], c).reshape(len(a), len(off), 6)
            rows.append(norm(np.einsum("m,nmk->nk", row, Y)))
            at.append(np.abs(fr[a] - fr[i]))
    if not rows:
        return own, np.zeros((0, 2))
    S = np.concatenate(rows)
    return own, S[np.argsort(np.concatenate(at), kind="stable")[:GAP_SCALE]]


def _judge_gaps(t: _Table, P, c, use, judge, R, limit: float, floor, reach: int, out: dict,
                one_sided: bool = False) -> dict[int, str]:
    """Judge the good frames left without a fit by the other flags (module docs, *A frame whose
    neighbours are flagged*), each through frames the fits judged good (``use``, a residual): flag
    (into ``out``) those whose residual against the line through their nearest such frames exceeds
    ``limit`` × the median of the nearest frames fitted alike; return the :data:`UNCHECKED` notes of
    those it cannot judge — but for those with such frames on one side only (a trial's end), flagged
    (:data:`ONE_SIDED_FLAG`) instead where ``one_sided``."""
    fr, floor = t.fr, np.asarray(floor, dtype=float)
    fitted = np.isfinite(R).all(axis=1)
    base = use & fitted  # judged by their own fits: neither flagged nor unfitted
    notes = {}
    for i in np.flatnonzero(use & judge & ~fitted):
        i = int(i)
        nb, both = _gap_fit(t, base, i, reach)
        if not both:
            why = (f"the nearest frames judged good, {', '.join(str(f) for f in fr[nb])}, on one side only: "
                   "a line extrapolated to it follows the motion's acceleration more than its error"
                   if len(nb) >= GAP_FRAMES else
                   f"fewer than {GAP_FRAMES // 2} frames judged good on a side within {reach} tracked frames")
            if one_sided and len(nb) >= GAP_FRAMES:
                out[int(fr[i])] = f"{ONE_SIDED_FLAG} ({UNCHECKED}: its neighbours flagged; {why})"
            else:
                notes[int(fr[i])] = f"{UNCHECKED} (its neighbours flagged; {why})"
            continue
        got = _gap_residuals(t, P, c, base, i, nb)
        if got is None:
            notes[int(fr[i])] = f"{UNCHECKED} (its neighbours flagged; the line through {fr[nb]} singular)"
            continue
        own, S = got
        if len(S) < GAP_SCALE:
            notes[int(fr[i])] = (f"{UNCHECKED} (the line through its nearest frames judged good "
                                 f"{', '.join(str(f) for f in fr[nb])}: {len(S)} of the bone's frames "
                                 f"fitted alike, fewer than {GAP_SCALE}, to scale it)")
            continue
        med = np.median(S, axis=0)
        lg = np.maximum(limit * med, floor)
        if (own > lg).any():
            tm, rd = own
            out[int(fr[i])] = (f"{FLAG} ({tm:.3f} mm, {rd:.3f} deg from the line through its nearest frames "
                               f"judged good {', '.join(str(f) for f in fr[nb])}, its neighbours flagged; "
                               f"limits {lg[0]:.3f} mm, {lg[1]:.3f} deg, {limit:g} x the median "
                               f"{med[0]:.3f} mm, {med[1]:.3f} deg of the {GAP_SCALE} nearest frames "
                               "fitted alike)")
    return notes
