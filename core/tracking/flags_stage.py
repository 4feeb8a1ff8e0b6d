"""The trajectory check's frames the final stage moved off the trajectory (:mod:`core.tracking.flags_post`,
the ``stage`` keyword of :func:`~core.tracking.flags_post.trajectory_review`, default :data:`STAGE`; None:
off).

The final stage (:mod:`core.tracking.final_stage`) refines the search's pose; on the acceptance trial it
moves a frame by hundredths of a millimetre. Seed 4's calcaneus, frame 53, is the frame over
4x its bound that the check left silent at b941103 in both modes (0.176 / 0.171 mm off in x, 4.27x /
4.13x the bone's RMS bound): the search's pose was 0.079 / 0.083 mm off in x, the stage moved it 0.098 /
0.087 mm further along x — the largest move of its neighbours — and the frame then stood 2.38x / 2.21x
the bone's median residual off its fit (the limit 2.5x) where the search's pose stood within 0.9x. No other
signal a run keeps set it apart (:mod:`core.studies.tracking.stage_silent`, the share of the unflagged
good frames as high: its score against its neighbours' 21-22 %, evaluations 17-96 %, the stage's steps
25-100 %, the stage's move 4-8 % in mm, 13-17 % in degrees, the move over its σ 48-51 %, its confidence
σ over the bone's 50-52 %; its residual alone, 2.5-2.7x the median without the flagged frames, 1.0-2.4 %;
the stage's pose's residual 2.9-3.4x the search's pose's: 0.7-1.4 %; 1.7-1.9 larger: 0.15-0.5 %; both
together, the rule, below).

So, after the check's other rules, each good frame whose search's pose is known (``searched``: the
:class:`~core.tracking.results.FrameResult`'s ``search_pose``, where the stage's move was taken) is
judged once more, all on the same fits (a frame it flags does not make others judged again): it is
flagged (``"off the trajectory where the final stage moved it (...)"``) when its
residual against the fit through its good neighbours exceeds ``stage`` × ``limit`` × the bone's median
(and ``FLOOR``), in translation or rotation, and the search's pose, against the same fit, stands off by
less than :data:`STAGE_RATIO` × as much (each over the bone's median, the larger of mm and degrees): the
stage, not the image's evidence the search followed, put the frame off its neighbours' path. Frames
flagged so are left out of the fits of the rules after it (:mod:`core.tracking.flags_gaps`).

The search's pose is not journaled: a pass over a journal (``talus batch``'s, :mod:`core.tracking.
batch_pass`) cannot judge this rule. A frame the rule flagged whose search's pose is not known is judged
as a good frame up to the rule (in the fits, as in the run that flagged it) and there keeps its flag
and message, when it is still a good frame then (:func:`core.tracking.flags_post.apply_trajectory_flags`;
the same flags as that run's when nothing else changed).

Measured (:mod:`core.studies.tracking.stage_silent`, ``resources/benchmarks/tracking_stage_silent_cpu.json``;
the stored acceptance runs, 1024², 100 frames, jointly and sequentially, tracked on one NVIDIA H100, their
poses and search's poses rebuilt from the kept errors and the seed's truth; the check run on this 2-core
x86_64 machine, shared). *Good*: under 2x the bone's bound in translation and rotation; *mid*: between
2x and 4x. The rule's form and both limits were made on frame 53 (its four runs: b941103 and d262386,
both modes); no held-out run keeps a search's pose of a silent frame, so what it catches elsewhere is
measured on frames put in (last item):

* b941103 (seeds 0, 3, 4): frames over 4x left silent 2 -> 0 of 17; good frames flagged 83 -> 88 of
  1387 (0.38 % of the 1304 left unflagged), mid 121 -> 127;
* d262386 (seeds 0, 3, 4, an older tracker): silent 3 -> 1 of 21 (frame 53 in both modes caught; the
  sequential calcaneus's frame 30 left: its search's pose stood 0.58x as far off), good 53 -> 60 of
  1373, mid 115 -> 121;
* the older sets (no search's pose kept): unchanged, as they must be;
* held out, frames like frame 53 put into b941103's seeds 0 and 3 (each of every 3rd good frame 4-94 in
  turn moved along x until its translation error is 4.3x the bone's bound, its search's pose the frame's
  own before): the check flagged 288 of 299 before the rule, 295 with it (tibia 83 -> 88 of 91, talus
  100 -> 102 of 103, calcaneus 105 of 105); at 5x 297 -> 299.

The limits (silent of 5 / good frames flagged more than the check's 136 / mid more than 236, both sets):
``stage`` 0.9 with ratio 0.4 gives 1 / 1 / 4 — but b941103's sequential frame 53 stood 0.098 mm off
against a limit of 0.098 mm, caught by a hair (0.95: 3 silent); 0.85 / 0.5 (the defaults) 1 / 12 / 12;
0.8 / 0.5 1 / 18 / 13; ratio 0.3 catches only 1 at any ``stage``; 0.6 catches frame 30 too, 0 / 18 / 14
at 0.85. The margins of the defaults on frame 53: its residual 2.52-2.69x the bone's median against
2.125x, its search's pose 0.30-0.34 of it against 0.5. On the tests' walking track (0.01 mm / 0.05 deg
noise) with search's poses a noise draw of their own (as large as the poses'), the rule flags about 0.5 %
of the frames (6 of 1200 over 20 draws). The check's time grows by the residuals of the frames with a
search's pose (one batch) and the candidates' search's residuals: about 1 ms a bone on the b941103 runs
(this machine, loaded).
"""

from __future__ import annotations

import numpy as np

from .flags_fit import FLAG, _deltas, _Table

__all__ = ["STAGE", "STAGE_FLAG", "STAGE_RATIO", "judge_stage", "searched_residual"]

#: A good frame whose search's pose is known is flagged when its residual exceeds this many times
#: ``limit`` × the bone's median (the ``stage`` keyword's default of
#: :func:`core.tracking.flags_post.trajectory_review`; None: not judged so) ...
STAGE = 0.85
#: ... and its search's pose's residual against the same fit is under this fraction of it.
STAGE_RATIO = 0.5
#: The flag's message starts so.
STAGE_FLAG = f"{FLAG} where the final stage moved it"


def searched_residual(t: _Table, i: int, use: np.ndarray, pose: np.ndarray) -> np.ndarray | None:
    """``(2,)`` the normalised residual (mm, degrees) of ``pose`` in frame ``i``'s place against the fit
    through ``i``'s neighbours in ``use`` (:meth:`~core.tracking.flags_fit._Table.residual`'s); None
    without a fit."""
    hit = t._fit(i, use)
    if hit is None:
        return None
    row, k, _ = hit
    nb = t.neighbours(i, use)
    r = row @ _deltas(np.repeat(np.asarray(pose, float)[None], len(nb), axis=0), t.P[nb], t.c) / k
    return np.array([np.linalg.norm(r[:3]), np.degrees(np.linalg.norm(r[3:]))])


def judge_stage(t: _Table, S: np.ndarray | None, use: np.ndarray, judge: np.ndarray, med: np.ndarray,
                limit: float, floor, stage: float, ratio: float, out: dict, kept=None) -> None:
    """The rule of the module docs: flags into ``out`` (frame number -> message) the frames in ``use``
    and ``judge`` with a search's pose (``S``, ``(n, 4, 4)``, NaN where none; None: no frame has one)
    whose residual exceeds ``stage`` × ``limit`` × ``med`` (and ``floor``) and whose search's pose stands
    off by less than ``ratio`` × as much, judged on the same fits, and those of ``kept`` (index -> the
    message of the run that flagged it: a journal's frame without its search's pose) still in ``use``
    and ``judge``, with their message; takes them out of ``use``."""
    for i, msg in (kept or {}).items():
        if use[i] and judge[i]:
            out[int(t.fr[i])] = msg
    gone = [i for i in (kept or {}) if use[i] and judge[i]]
    if S is None:
        use[gone] = False
        return
    have = use & judge & np.isfinite(S.reshape(len(S), -1)).all(axis=1)
    have[gone] = False
    if not have.any():
        use[gone] = False
        return
    lim = np.maximum(float(stage) * float(limit) * med, np.asarray(floor, dtype=float))
    R = t.residuals(use)
    scale = np.maximum(med, 1e-12)
    z = np.where(have[:, None] & np.isfinite(R), R / lim, 0.0).max(axis=1)
    got = []
    for i in np.flatnonzero(z > 1.0):
        i = int(i)
        rs = searched_residual(t, i, use, S[i])
        if rs is None or not np.all(np.isfinite(rs)):
            continue
        own, was = float((R[i] / scale).max()), float((rs / scale).max())
        if was < float(ratio) * own:
            got.append((float(z[i]), i, rs))
    use[gone] = False
    for _, i, rs in sorted(got, reverse=True):
        use[i] = False
        tm, rd = R[i]
        out[int(t.fr[i])] = (f"{STAGE_FLAG} ({tm:.3f} mm, {rd:.3f} deg from the fit through its neighbours, "
                             f"the search's pose {rs[0]:.3f} mm, {rs[1]:.3f} deg; limits {lim[0]:.3f} mm, "
                             f"{lim[1]:.3f} deg, {float(stage):g} x {float(limit):g} x the bone's median "
                             f"{med[0]:.3f} mm, {med[1]:.3f} deg)")
