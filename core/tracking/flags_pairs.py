"""The trajectory check's pairs of frames off together (:mod:`core.tracking.flags_post`, the ``pair``
keyword of :func:`~core.tracking.flags_post.trajectory_review`, default :data:`PAIR`; None: off).

The check judges a frame against the fit through its good neighbours. Two consecutive frames off
together are each in the other's fit: the pair drags the fit, neither residual crosses the limit, and
the worst-first removal may take out the neighbours they pulled instead (seed 3's tibia at 6c8beab,
jointly: frames 69 and 70 0.39 and 0.46 deg off about the long axis, 4.0x and 4.7x the bone's bound,
stood 2.9x and 3.2x the bone's median residual off their fits; frame 67, 1.9x its bound, then
frames 72 and 71, 0.8x and 1.0x, were flagged first, and without them the pair fell under the
limit: frame 70 silent). After the check's own rules (the worst-first loop and *next to a flagged
frame*), each pair of consecutive tracked frames ``f``, ``f + 1`` is judged with both left out of the
fits:

* its frames' residuals so (normalised by ``sqrt(1 + leverage)`` as the check's own) are scaled by
  the median of such residuals over every pair of the bone's good frames, all frames in the fits (the
  pair residual is wider than a frame's own: 1.10x / 1.16x in mm / degrees on seed 3's tibia);
* the fits hold the frames in use and, within the window, the frames the other rules took out whose
  own residual with the pair left out is within the check's limit — those that stood off only
  through the pair's pull (seed 3's frames 71 and 72) — not those off by themselves (frame 67, or a
  single spike whose neighbours it pulled: their pair would stand off through it);
* a pair is judged when a frame of it is judged and in use (the other may be one the other rules
  flagged) and both frames' first residuals (all neighbours in the fit) exceed :data:`PAIR_GATE` ×
  ``limit`` × the bone's median; it is flagged when *both* residuals exceed ``pair`` × ``limit`` ×
  the pair median (and ``FLOOR``): a single frame off leaves its neighbour's residual without it
  small. The worst pair is flagged first and left out of the fits of the pairs near it, which are
  judged again. A frame flagged so reads ``"off the trajectory with frame 70 (... from the fit through
  its neighbours without both, frame 70 ...; limits ..., 2.5 x the bone's median ... of such
  residuals)"``; a frame the other rules flagged keeps their message.

The rule only adds flags: every flag of the check without it stays, and the frames it flags are left
out of the fits of the rule for frames whose neighbours are flagged (:mod:`core.tracking.flags_gaps`).

Measured (:mod:`core.studies.tracking.trajectory_pairs`,
``resources/benchmarks/tracking_trajectory_pairs_cpu.json``; the stored acceptance runs of seeds 0, 3
and 4, 1024², 100 frames, jointly and sequentially, with the final stage at 6c8beab and without it at
445a8ae / 782362a, tracked on one NVIDIA H100, their poses rebuilt from the kept errors and the seed's
truth — the check without the rule gives every run's stored flags — the check run on this 2-core
x86_64 machine, shared). The limits were chosen on seed 0 only: its runs have no frame over 4x left
silent, so on its good frames flagged (1189 bone-frames; 74 by the check without the rule) and on
pairs put into its 12 tracks, frames ``f`` and ``f + 1`` turned 4x and 4.4x the bone's RMS rotation
bound more about the error's z axis, every 3rd frame 4-94 in turn (372 pairs; the check without the
rule flagged both frames of 248, either of 293). Gate 0.7 and ``pair`` 1.0: 75 good frames flagged,
both frames of 288 pairs (either 324); gate 0.5: 81 and 292; 0.9: 75 and 266; ``pair`` 0.9 at gate
0.7: 84 and 290; 1.1: 75 and 278. Judging pairs with one frame flagged by the other rules (seed 4's
frames 7 and 8) took 279 to 288 of the pairs for one good frame more (a variant without it, not kept).
Held out for the limits (seed 3's pair shaped the rule's form): seed 3 with the stage, frames over
4x left silent 1 -> 0 of 2 (frame 70, flagged with 69), good frames flagged 83 -> 86 of 598; seed 4
with the stage 5 -> 4 of 15 (calcaneus frame 97 jointly), 41 -> 45 of 584; without the stage seed 3
17 -> 17 of 33, 74 -> 74 of 567, seed 4 79 -> 79 of 122 (long runs of frames off together, which no
local fit sees), 33 -> 39 of 478; seed 0 with the stage 39 -> 40 of 597, without 35 -> 35 of 592. On
the kept runs of seeds 0-2 at ea76c8b (:mod:`core.studies.tracking.silent_checks`) silent 17 -> 17 of
39, good frames flagged 100 -> 102 of 1761. On the tests' walking track (0.05 deg noise per axis)
two frames 0.25 and 0.275 deg off together were flagged both in 3 of 8 draws where the check without
the rule missed one or both; a single frame 0.5 deg off flags as before. The check took 24-26 ms per bone over
100 frames with the rule and 10-16 without on those runs (this machine loaded; the pair scale
batched, :func:`pair_scale`), 41 and 16 ms on the tests' track of 1000 frames, 31 and 25 ms for a
3-frame range with 997 neighbours.
"""

from __future__ import annotations

import numpy as np

from . import flags_fit
from .flags_fit import FLAG, _Table

__all__ = ["PAIR", "PAIR_GATE", "Pairs", "pair_residuals", "pair_scale"]

#: Two consecutive good frames are flagged together when, judged with both left out of the fits, each
#: stands off by more than this many times ``limit`` × the bone's median such residual (the ``pair``
#: keyword's default of :func:`core.tracking.flags_post.trajectory_review`; None: not judged so).
PAIR = 1.0
#: ... and each stands off its own fit (the other in it) by more than this many times ``limit`` × the
#: bone's median residual.
PAIR_GATE = 0.7


def _partner(t: _Table, use: np.ndarray, i: int) -> int | None:
    """The frame after ``i`` in ``use`` when it is the next tracked frame (one median spacing on)."""
    j = i + 1
    if j < len(use) and use[j] and t.fr[j] - t.fr[i] == t.step:
        return j
    return None


def _both_sides(t: _Table, use: np.ndarray, j: int) -> bool:
    """Whether frame ``j``'s fit through the frames in ``use`` has neighbours before and after it: an
    extrapolated fit (a trial's end without the pair) is too wide to say a frame stood off only through
    the pair's pull."""
    d = t.fr[t.neighbours(j, use)] - t.fr[j]
    return bool((d < 0).any() and (d > 0).any())


def pair_residuals(t: _Table, use: np.ndarray, i: int) -> np.ndarray | None:
    """``(2, 2)`` normalised residuals (mm, degrees) of frame ``i`` and the next tracked one, each
    against the fit through the frames in ``use`` with both left out (NaN without enough
    neighbours); None when the next tracked frame is not in ``use``."""
    j = _partner(t, use, i)
    if j is None or not use[i]:
        return None
    u = use.copy()
    u[i] = u[j] = False
    return np.array([t.residual(i, u), t.residual(j, u)])


def pair_scale(t: _Table, use: np.ndarray, which: np.ndarray) -> tuple[np.ndarray, int]:
    """The median (mm, degrees) of the pair residuals of every pair whose first frame is in
    ``which`` (both members' residuals pooled), and how many residuals it is of. Frames with every
    neighbour of an evenly spaced window in ``use`` (most) are fitted in one batch, the others one by
    one (:func:`pair_residuals`' values)."""
    n = len(use)
    if flags_fit.BATCHED:  # _partner of every candidate at once (the same frames)
        cand = np.flatnonzero(which & use)
        nxt = np.minimum(cand + 1, n - 1)
        first = cand[(cand + 1 < n) & use[nxt] & (t.fr[nxt] - t.fr[cand] == t.step)]
    else:
        first = np.array([i for i in np.flatnonzero(which & use) if _partner(t, use, int(i)) is not None],
                         dtype=int)
    if not len(first):
        return np.full(2, np.nan), 0
    j = np.arange(n)[:, None] + t.offsets
    jc = np.clip(j, 0, n - 1)
    full = use & (t.near & use[jc]).all(axis=1) & (t.fr[jc] - t.fr[:, None] == t.offsets * t.step).all(axis=1)
    vals = []
    for own, gone in ((first, 1), (first + 1, -1)):  # each member without the other
        keep = t.offsets != gone
        hit = t._weights((t.offsets[keep] * t.step).astype(float))
        batch = own[full[own]] if hit is not None else own[:0]
        if len(batch):
            row, k = hit
            r = np.einsum("m,nmk->nk", row, t.Y[batch][:, keep])
            vals.append(np.c_[np.linalg.norm(r[:, :3], axis=1) / k,
                              np.degrees(np.linalg.norm(r[:, 3:], axis=1)) / k])
        for i in own[~full[own]] if hit is not None else own:
            u = use.copy()
            u[i + gone] = False
            vals.append(np.array([t.residual(int(i), u)]))
    v = np.concatenate(vals)
    v = v[np.isfinite(v).all(axis=1)]
    if not len(v):
        return np.full(2, np.nan), 0
    return np.median(v, axis=0), len(v)


class Pairs:
    """Pairs of consecutive frames judged each with both left out of the fits (module docs of
    :mod:`core.tracking.flags_post`, *Two frames off together*): a pair's score is the smaller of its
    two residuals so (each over ``lim``, mm and degrees, its larger part); only pairs with a judged
    frame and both frames' own residuals ``R`` (the other in the fit) over ``gate`` are scored."""

    def __init__(self, t: _Table, use: np.ndarray, judge: np.ndarray, lim: np.ndarray, med: np.ndarray,
                 factor: float, R: np.ndarray, gate: np.ndarray, out: np.ndarray,
                 lim_one: np.ndarray) -> None:
        self.t, self.use, self.judge, self.lim, self.med, self.factor = t, use, judge, lim, med, factor
        self.R, self.gate, self.out, self.lim_one = R, gate, out, lim_one
        self.Z = np.zeros(len(use))
        self.got: dict[int, np.ndarray] = {}
        self.rescore(0, len(use) - 1)

    def rescore(self, lo: int, hi: int) -> None:
        """Score again the pairs starting at ``lo`` .. ``hi - 1``."""
        n, judge = len(self.use), self.judge
        a, b = max(0, lo), min(n - 1, hi)
        gated = None
        if flags_fit.BATCHED and b > a:  # the pairs scored, the whole range at once (the same booleans)
            both = self.use[a:b + 1] | self.out[a:b + 1]
            mine = self.use[a:b + 1] & judge[a:b + 1]
            over = (self.R[a:b + 1] / self.gate).max(axis=1) > 1.0
            gated = ((mine[:-1] | mine[1:]) & both[:-1] & both[1:] & over[:-1] & over[1:]).tolist()
        for i in range(a, b):
            if gated is not None:
                on = gated[i - a]
            else:
                both = self.use[i:i + 2] | self.out[i:i + 2]
                on = (bool((self.use[i:i + 2] & judge[i:i + 2]).any()) and bool(both.all())
                      and bool(((self.R[i:i + 2] / self.gate).max(axis=1) > 1.0).all()))
            r = None
            if on:
                u = self._fits(i)
                u[i] = u[i + 1] = True
                r = pair_residuals(self.t, u, i)
            if r is None or not np.all(np.isfinite(r)):
                self.Z[i] = 0.0
                self.got.pop(i, None)
            else:
                self.got[i] = r
                self.Z[i] = float(min((r[0] / self.lim).max(), (r[1] / self.lim).max()))

    def _fits(self, i: int) -> np.ndarray:
        """The frames in the fits of the pair starting at ``i``: those in ``use`` and the frames the
        other rules took out (``out``) near it whose residual without the pair is within ``lim_one``
        (off only through the pair's pull); the pair itself left in (:func:`pair_residuals` takes it
        out)."""
        u = self.use.copy()
        hw = len(self.t.offsets) // 2
        near = np.flatnonzero(self.out[max(0, i - hw):i + hw + 2]) + max(0, i - hw)
        if len(near):
            v = u.copy()
            v[i] = v[i + 1] = False
            for j in near:
                r = np.asarray(self.t.residual(int(j), v))
                if np.all(np.isfinite(r)) and (r <= self.lim_one).all() and (
                        not self.t.ends or _both_sides(self.t, v, int(j))):
                    u[j] = True
        return u

    def judge_all(self):
        """``(k, (k, k + 1))`` of each pair over the limit, the one that stands off most first, then the
        pairs near it scored again without it."""
        hw = len(self.t.offsets) // 2
        while True:
            k = int(np.argmax(self.Z))
            if not self.Z[k] > 1.0:
                return
            yield k, (k, k + 1)
            self.use[k] = self.use[k + 1] = False
            self.out[k] = self.out[k + 1] = False  # flagged: never put back in the fits
            self.rescore(k - hw - 1, k + hw + 2)

    def message(self, i: int, m: int) -> str:
        """The flag of the pair starting at ``i``'s member ``m`` (0: frame ``i``, 1: the next)."""
        r, fr = self.got[i], self.t.fr
        g, own, other = int(fr[i + 1 - m]), r[m], r[1 - m]
        lim, med = self.lim, self.med
        return (f"{FLAG} with frame {g} ({own[0]:.3f} mm, {own[1]:.3f} deg from the fit through its "
                f"neighbours without both, frame {g} {other[0]:.3f} mm, {other[1]:.3f} deg; limits "
                f"{lim[0]:.3f} mm, {lim[1]:.3f} deg, {self.factor:g} x the bone's median {med[0]:.3f} mm, "
                f"{med[1]:.3f} deg of such residuals)")
