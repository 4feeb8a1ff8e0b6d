"""The final stage's σ with its move measured from the similarity's optimum, where the σ checks would
flag a frame (:func:`remeasured`, called by :func:`core.tracking.attempt.register_checked`).

With the likelihood stage a frame's confidence is the stage's sandwich covariance plus the outer product
of its move from the similarity's pose (``final_confidence="sandwich+move"``, 257631c: the two costs'
disagreement, a systematic part neither sees). Since 9d0b690 / 16bf448 the similarity's search stops at a
looser tolerance before the stage (:data:`core.tracking.register_options.STAGE_SEARCH_TOL`, 0.5 mm and
degrees): the move is then measured from where the search stopped, and it holds the search's shortfall
too — along the talus's weakest axis, about x, up to about half a degree. The stage's pose does not
depend on it (it lands where it lands from the converged similarity too), but the σ checks do (the
``"uncertain"`` flag of :func:`core.tracking.checks.sigma_check`: 3× the bone's recent σ; a frame flagged
is not converged).

Seed 0's talus at d262386 (one NVIDIA H100, 1024², ``tracking_acceptance_seed0_final_d262386_h100.json``):
frames 6 and 69, jointly, were its only frames not converged, both flagged so (σ 0.71° and 0.63° in
rotation, over 3× the bone's recent 0.18° and 0.19°; σ about x 0.61° and 0.58°; errors about x 0.16° and
0.43°), both with a stage move of about 0.6° about x from the searched pose (sequentially the same moves:
frame 6 flagged, 69 not). On this 2-core x86_64 machine's CPU at 1024² (:mod:`core.studies.tracking.
stage_sigma_frames`, ``tracking_stage_sigma_frames_cpu.json``: the H100 run's searched pose rebuilt from
its stored error, the neighbours at their predictions): the stage moves −0.46° / +0.62° about x and σ is
0.51° / 0.65° in rotation against the check's 0.53° / 0.56° (frame 69 flagged; frame 6 just under, the
CPU's stage moving less than the H100's); the similarity searched on from the searched pose to its own
tolerance (two steps) lies 0.37° / 0.46° about x from where the search had stopped; with the move from
there σ is 0.22° / 0.23°, neither flagged; and the stage from that optimum lands within 0.015° / 0.019°
about x of the same pose. So where the σ checks flag a frame whose stage took its move, the similarity's
search goes on from the searched pose to its own tolerance (the tracker's ``"newton"`` search without a
stage; its work counted), the move is measured from that optimum and the checks judge that σ, which is
the frame's confidence (a note says so). The stage's move in the timing is then the move from that
optimum, and the fit's similarity that optimum: the stage-move check (:func:`core.tracking.stage_move.
stage_move_check`, after the frame's registrations) reads both, and a move it rejects leaves the
similarity's optimum, not the stopped search's pose; otherwise the pose is the stage's, as it was.
The frames the checks do not flag keep the move from the searched pose (converging every search is what
the looser tolerance saves; on the three seeds' d262386 runs these three bone-frames were the only ones
the σ checks flagged). Not applied to a confidence left to :func:`~core.tracking.attempt.settle` (a first
frame's round before the last with ``contact``). Frame 69's error about x, 0.43° (0.47° here), is the
stage's own at that frame, the same from every start: from the truth at 512² the stage ends 0.64° off on
the run's noise draw, 0.24° noise-free, 0.14° with the other bones taken out of the image or with the
imaging chain left out (0.13° of it the soft tissue's). Within 4× the bound; no longer inside 2σ about x.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..geometry.transforms import params_from_pose
from .cost import OutsideViewError

__all__ = ["REMEASURE", "remeasurable", "remeasured"]

#: Re-measure a flagged frame's σ from the similarity's optimum (module docs); off: as before.
REMEASURE = True


def remeasurable(res, options) -> bool:
    """Whether :func:`remeasured` applies to ``res`` (a registration of ``options``): the switch on, the
    stage's move taken, its fit the stage's with the similarity's result, the σ ``"sandwich+move"``."""
    fit = getattr(res, "fit", None)
    staged = bool((res.timing or {}).get("likelihood_taken"))
    kept = getattr(fit, "similarity", None) is not None and getattr(fit, "covariance", None) is not None
    return bool(REMEASURE and options.final_confidence == "sandwich+move" and staged and kept)


def _move(pose, base, center) -> np.ndarray:
    """``pose`` relative to ``base`` as the stage's parameters (mm, degrees about ``center``)."""
    p = params_from_pose(np.asarray(pose, dtype=float), center=np.asarray(center, dtype=float),
                         base=np.asarray(base, dtype=float))
    return np.r_[p[:3], np.degrees(p[3:])]


def remeasured(renderer, frame, res, *, bone: int, center, options, others=None, outline=None, cancel=None,
               profile: bool = False):
    """``(res with its fit's σ re-measured, the similarity's optimum)`` (module docs): the similarity
    searched on from ``res.fit.similarity``'s pose with ``options`` (the tracker's registration options)
    without a stage, and the covariance's move part taken from there; the fit's ``similarity`` that optimum
    (a rejected move keeps it) and the stage's move in the timing from it (the move check reads it, against
    this σ); None where it does not apply, the search leaves the views or is cancelled."""
    from .likelihood_model import LikelihoodFit
    from .register import register

    if not remeasurable(res, options):
        return None
    fit = res.fit
    sim = fit.similarity
    try:
        conv = register(renderer, frame, bone=bone, initial_pose=sim.pose, center=center,
                        options=replace(options, final=None), others=others, cancel=cancel, profile=profile,
                        outline=outline)
    except OutsideViewError:
        return None
    if any(getattr(st, "reason", None) == "cancelled" for st in getattr(conv, "stages", ())):
        return None  # (cut short: no optimum)
    d0, d1 = _move(res.pose, sim.pose, center), _move(res.pose, conv.pose, center)
    cov = np.asarray(fit.covariance, dtype=float) - np.outer(d0, d0) + np.outer(d1, d1)
    if not np.all(np.isfinite(cov)):
        return None
    try:
        new = LikelihoodFit.of(cov, x=fit.x, chi2=fit.chi2, covariance_independent=fit.covariance_independent,
                               similarity=conv)
    except np.linalg.LinAlgError:
        return None
    timing = {**res.timing, "likelihood_move_mm": float(np.linalg.norm(d1[:3])),
              "likelihood_move_deg": float(np.linalg.norm(d1[3:]))}
    return replace(res, fit=new, timing=timing), conv
