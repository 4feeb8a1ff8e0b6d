"""The trajectory check's frames next to a flagged one and off the same way (:mod:`core.tracking.flags_post`,
the ``along`` keyword of :func:`~core.tracking.flags_post.trajectory_review`, default :data:`ALONG`; None:
off).

*Next to a flagged frame* (the ``near`` rule) flags a frame whose residual is over the limit with its
flagged neighbours in its fit and still over ``near`` × the limit without them: a frame the flagged ones
pulled *away* from its fit and that stands off by itself too. A frame off *the same way* as its flagged
neighbour is the opposite case: the neighbour pulls the fit *towards* it, its first residual is small, and
only without the neighbour does it stand off. Seed 4's tibia at b797131, jointly: frames 7 and 8 were
−0.47° and −0.66° off about the long axis (4.3× and 6.0× the bone's RMS bound); frame 8 was flagged, and
frame 7 stood 1.11× the bone's median residual off its fit with frame 8 in it (the ``near`` rule's first
condition, the limit 2.5×, failed) and 2.11× / 1.90× (mm / degrees) without it, its residual about the
long axis the same way as frame 8's
(``resources/benchmarks/tracking_acceptance_seed4_final_b797131_h100.json``).

So, after the check's other rules (the worst-first loop, ``near`` and ``pair``), each good frame next to a
frame the check flagged (the previous or next tracked frame; not a neighbour the run does not judge, such
as a hand fix) whose fit has neighbours on both sides is judged on its residual without it: it is
flagged (``"off the trajectory next to flagged frame 8, the same way (...)"``) when, in translation or
rotation, that residual exceeds ``near`` × ``limit`` × the bone's median residual (the
``near`` rule's second limit, and ``FLOOR``) and points the same way as the flagged frame's own residual
(with both left out of the fits): the cosine of the two vectors (mm, or rotation vectors) over ``along``
(:data:`ALONG` 0.5: within 60°). It judges once, on the frames flagged before it (a frame it flags does not
make its own neighbours judged), and only adds flags; the frames it flags are left out of the fits of
the rule for frames whose neighbours are flagged (:mod:`core.tracking.flags_gaps`).

Measured (:mod:`core.studies.tracking.trajectory_silent`, ``resources/benchmarks/tracking_trajectory_silent_
cpu.json``; the stored acceptance runs, 1024², 100 frames, jointly and sequentially, tracked on one NVIDIA
H100, their poses rebuilt from the kept errors and the seed's truth; the check run on this 2-core x86_64
machine, shared). *Good* frames are those under 2x their bound in translation and rotation. The rule's
form was made on seed 4's frame 7 at b797131; its limit is the ``near`` rule's (0.7 x 2.5, not tuned) and
its cosine 0.5 was set before measuring (0, 0.5 and 0.8 measured after: within 3 good frames flagged
on every set, 0.8 leaving 3 more held-out frames over 4x silent). With :mod:`core.tracking.flags_gaps`'
``one_sided`` (the two rules together; each set's good frames flagged without them -> with them):

* b797131 (seeds 0, 3, 4 with the stage): frames over 4x left silent 4 -> 2 of 17 (the tibia's frames 7 by
  this rule and 0 by ``one_sided``; the calcaneus's frame 53 in both modes left), good frames flagged
  65 -> 87 of 1385 (4.7 -> 6.3 %; this rule alone, ``one_sided`` on: 71 -> 87);
* held out: without the stage (seeds 0, 3, 4 at 445a8ae / 782362a) 96 -> 90 of 163, good 35 -> 51 of 936;
  seeds 0-2 at ea76c8b 17 -> 17 of 39, 16 -> 28 of 1074; seed 3 and seed 4 interpenetrating at 56350ae
  90 -> 86 of 131, 28 -> 38 of 586; seed 4 at a5fd412 79 -> 73 of 122, 4 -> 9 of 204;
* pairs like seed 4's put into seed 0's 6 tracks at b797131 (frames ``f`` and ``f + 1`` turned 4.3x and
  6.0x the bone's RMS rotation bound more about z, the same way, every 3rd frame in turn, 186 pairs):
  frame ``f`` flagged in 161 -> 165.

On the tests' walking track (0.05° noise per axis, 20 draws) a frame 0.2° off next to one 0.5° off the same
way is flagged in 16 draws where the check before flagged it in 8; next to a single 0.5° spike, the good
neighbours are flagged by the rule in 2 of 40.
"""

from __future__ import annotations

import numpy as np

from .flags_fit import FLAG, _Table

__all__ = ["ALONG", "judge_along"]

#: A good frame next to a flagged one whose residual without it is over the ``near`` limit is flagged
#: when its residual and the flagged frame's point within this cosine of each other (the ``along``
#: keyword's default of :func:`core.tracking.flags_post.trajectory_review`; None: not judged so).
ALONG = 0.5


def _cos(a: np.ndarray, b: np.ndarray) -> float:
    na, nb = float(np.linalg.norm(a)), float(np.linalg.norm(b))
    return float(a @ b) / (na * nb) if na > 0.0 and nb > 0.0 else -1.0


def _both_sides(t: _Table, use: np.ndarray, i: int) -> bool:
    """Whether frame ``i``'s fit has neighbours in ``use`` before and after it (not extrapolated)."""
    j = i + t.offsets
    sel = t.near[i] & use[np.clip(j, 0, len(use) - 1)]
    return bool(sel[t.offsets < 0].any() and sel[t.offsets > 0].any())


def judge_along(t: _Table, ok: np.ndarray, use: np.ndarray, judge: np.ndarray, lim_near: np.ndarray,
                factor: float, along: float, out: dict) -> None:
    """The rule of the module docs: flags into ``out`` (frame number -> message) the good frames in
    ``use`` and ``judge`` next to a frame the check flagged (``ok``, ``judge`` and not in ``use``) whose
    residual without it exceeds ``lim_near`` (mm, degrees; ``factor`` × the bone's median, for the
    message) in a part where the two residuals' cosine exceeds ``along``; takes them out of ``use``."""
    fr, n = t.fr, len(use)
    gone = ok & ~use & judge  # flagged by the check (a neighbour it may not judge, a hand fix, never counts)
    got = []
    for i in np.flatnonzero(use & judge):
        i = int(i)
        js = [j for j in (i - 1, i + 1) if 0 <= j < n and gone[j] and abs(int(fr[j]) - int(fr[i])) == t.step]
        if not js:
            continue
        if not _both_sides(t, use, i):
            continue
        v = t.residual_vector(i, use)
        if v is None:
            continue
        own = np.array([np.linalg.norm(v[:3]), np.degrees(np.linalg.norm(v[3:]))])
        over = own > lim_near
        if not over.any():
            continue
        for j in js:
            u = use.copy()
            u[i] = False
            w = t.residual_vector(j, u)
            if w is None:
                continue
            cs = [_cos(v[:3], w[:3]), _cos(v[3:], w[3:])]
            hit = [p for p in (0, 1) if over[p] and cs[p] > along]
            if hit:
                other = np.array([np.linalg.norm(w[:3]), np.degrees(np.linalg.norm(w[3:]))])
                got.append((i, j, own, other, cs))
                break
    for i, j, own, other, cs in got:
        use[i] = False
        out[int(fr[i])] = (f"{FLAG} next to flagged frame {int(fr[j])}, the same way ({own[0]:.3f} mm, "
                           f"{own[1]:.3f} deg from the fit through its neighbours without it, frame "
                           f"{int(fr[j])} {other[0]:.3f} mm, {other[1]:.3f} deg, cosines {cs[0]:.2f}, "
                           f"{cs[1]:.2f}; limits {lim_near[0]:.3f} mm, {lim_near[1]:.3f} deg, {factor:g} x "
                           "the bone's median)")
