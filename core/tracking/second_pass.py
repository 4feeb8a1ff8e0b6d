"""Sequential tracking's first-frame second pass with the final stage alone
(:data:`core.tracking.frame_step.SECOND_PASS_STAGE_ONLY`).

A first frame of sequential tracking gets a second pass (:data:`core.tracking.frame_step.
SEQUENTIAL_SECOND_PASS`): every bone again with the others at their first pass's poses. Without
``sequential_subtract`` the similarity's search subtracts nothing, so the second pass's search has the
inputs of the first (the same start, the same image) and only the final stage differs: in the first pass
(no stage: it runs in the last pass only) there was none, in the second it subtracts the neighbours at
their first pass's poses. :func:`stage_pass` runs only that: the stage from the first pass's pose (the
one its checks and restart check left), then :func:`core.tracking.attempt.register_checked`'s checks of
the second pass on its result (``pre``: in place of the registration), without the restart check, whose
verdict is the first pass's (its pose, its notes: an ambiguous optimum leaves the pass flagged, and a
flagged first pass is registered again as before). With ``sequential_subtract`` the second pass's search
differs (the neighbours subtracted at other poses) and is run again whole.

Measured on the ideal 128² scenes of :func:`core.studies.tracking.first_frame_keyframes.scene` (CPU, this
2-core x86_64 machine, shared; Gauss–Newton search, the likelihood stage at a 2 px high-pass, keyframes
5 mm / 5° off; :mod:`core.studies.tracking.second_pass_stage`,
``resources/benchmarks/second_pass_stage_cpu.json``): every bone's first-frame pose equal to the bit to
that of the whole pass again, the same flags, the same notes. Talus-calcaneus, 3 draws: with the tracker's
4 restarts the frame's evaluations 2361-2470 → 1200-1248 (talus) and 2204-2278 → 1128-1165 (calcaneus),
without restarts 1893-2015 → 966-1027 and 1749-1823 → 894-931 (×0.505-0.512); the frame took 9.5-17.3 s
against 19.8-28.3 s with restarts, 8.1-11.6 s against 15.3-21.0 s without. Tibia-talus-calcaneus, 2 draws,
4 restarts: the talus 2443-2626 → 1176-1261, the calcaneus 1591-2503 → 802-1271; the tibia, 3.06° off
about its long axis and flagged ambiguous by the first pass's restarts, registered whole again as before
(3089-3115 evaluations, the same pose, flag and note either way).
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from .attempt import Attempt

__all__ = ["stage_pass"]


def stage_pass(checked, kept: Attempt | None, renderer, frame, bone, index: int, start, guess, opts, o,
               good_scores, others, cancel, history, *, verify: bool = False, **kw) -> Attempt | None:
    """The second pass of bone ``index`` (a :class:`~core.tracking.bones.BoneModel` ``bone``) as the final
    stage alone from ``kept`` (its first pass's :class:`~core.tracking.attempt.Attempt`), checked by
    ``checked`` (:func:`~core.tracking.attempt.register_checked`, whose arguments the rest are: those of
    the second pass's registration) with the stage's result in place of the registration, the restart
    check left out (the first pass's verdict stands; its notes are kept). None where the pass must be
    registered again whole: ``kept`` flagged, without a pose, or run with a stage already; where the stage's
    result failed the checks (``retried``: the retry's searches ran without the restart check that follows
    them) the caller registers the pass whole too, counting this attempt's work."""
    from .final_stage import final_stage

    res = getattr(kept, "result", None)
    if res is None or kept.flags or "likelihood_s" in (res.timing or {}) or opts.final is None:
        return None
    t0 = time.perf_counter()
    # the stage's work alone (the first pass's is counted with it already)
    base = replace(res, evaluations=0, time_s=0.0, timing={k: 0.0 for k in res.timing if k != "total_s"})
    staged = final_stage(renderer, frame, base, bone=index, initial_pose=start, center=bone.centroid,
                         options=opts, views=tuple(range(frame.n_views)), others=others)
    spent = time.perf_counter() - t0
    plain = replace(o, verify_restarts=0) if verify and o.verify_restarts else o
    a = checked(renderer, frame, bone, index, start, guess, opts, plain, good_scores, others, cancel, history,
                verify=verify, pre=(staged, spent), **kw)
    if a is not None:
        a.notes = (*kept.notes, *a.notes)
    return a
