"""Is a registration on the right optimum? Restart consistency of a bone's starting pose.

A similarity cost has false optima a few millimetres or degrees from the true pose (a view where
the bone's outline half-overlaps a neighbour's, a rotation that trades one edge for another). A
registration that starts from a hand-placed pose can converge into one of them with every
convergence rule satisfied; tracking then follows the false optimum frame after frame, and the
relative checks of :mod:`core.tracking.trial` (score drop against recent frames, pose jump)
never fire because every frame is consistently wrong.

:func:`verify_start` checks a result by **restarts**: ``n`` local registrations
(:func:`core.tracking.register.register`, ``search="local"``) from the result displaced by
``spread`` (mm, degrees) in random directions, each in one batched quadratic-model search. On
the true optimum the restarts come back to it (or fail to converge); from a false optimum, some
restart usually falls into a deeper basin and scores higher. The outcome:

* ``improved`` — a restart scored higher than the result by more than ``score_tol`` (absolute
  similarity): the result was a false optimum, and the best restart is returned;
* ``ambiguous`` — a converged restart ended farther than ``pose_tol`` (mm, degrees) from the
  best pose with a score within ``score_tol`` of it: two optima the data cannot tell apart
  (flag for review);
* otherwise the result is confirmed.

The tracker runs this on every bone's first frame and after a failed frame's wider retry; its
cost is ``n`` short local searches (a few dozen launches), once per bone and start.

With the Gauss–Newton searches (``options.search`` ``"newton"`` or ``"global_newton"``, a cost
the engine scores) the restarts are Gauss–Newton searches of :mod:`core.tracking.engine` — half
resolution, then full resolution (the levels of the ``"newton"`` search's second attempt: a
displacement of ``spread`` is beyond the full-resolution steps' reach) — each started at its
displacement ``x0`` inside one search box about the checked pose and all side by side
(:func:`core.tracking.joint.restarts_together`: the fluoroscope regions prepared once per level,
the restarts' steps in flight together; a restart whose half-resolution search comes back within
half of ``pose_tol`` of the checked pose is scored there at full resolution instead of taking
full-resolution steps back to the checked optimum: it can be neither better by ``score_tol`` nor
a distinct optimum); the
quadratic-model restarts built a cost of their own
per restart and level (the first frame of three bones at 1024² spent 1.0 of its 1.3 s in them
on one H100).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from ..geometry.transforms import pose_from_params
from .checks import _distance

__all__ = ["StartCheck", "verify_start"]


@dataclass(frozen=True, eq=False)
class StartCheck:
    """Outcome of :func:`verify_start`.

    Attributes
    ----------
    result : RegistrationResult
        The best registration (the checked one unless ``improved``).
    improved : bool
        A restart found a better optimum than the checked result.
    ambiguous : bool
        A converged restart found a distinct optimum scoring within ``score_tol`` of the best.
    scores : tuple of float
        Scores of the restarts.
    distances : tuple of (float, float)
        Distance (mm, degrees) of each restart's pose from the best pose.
    evaluations : int
        Poses rendered by the restarts.
    """

    result: object
    improved: bool
    ambiguous: bool
    scores: tuple[float, ...]
    distances: tuple[tuple[float, float], ...]
    evaluations: int

    def to_dict(self) -> dict:
        return {"improved": self.improved, "ambiguous": self.ambiguous, "best_score": self.result.score,
                "scores": list(self.scores), "distances": [list(d) for d in self.distances],
                "evaluations": self.evaluations}


def _engine_supports(terms) -> bool:
    from .engine import supports

    return supports(terms)


def verify_start(renderer, frame, *, bone: int, result, center, options=None, n: int = 4,
                 spread: tuple[float, float] = (3.0, 3.0), score_tol: float = 0.01,
                 pose_tol: tuple[float, float] = (1.0, 2.0), seed: int = 0,
                 views: Sequence[int] | None = None, others=None, outline=None,
                 cancel: Callable[[], bool] | None = None) -> StartCheck:
    """Check ``result`` (a :class:`~core.tracking.register.RegistrationResult` of bone ``bone``
    in ``frame``) by ``n`` local restarts from it displaced by exactly ``spread`` (mm, degrees)
    in random directions (see the module docs).

    ``options`` (a :class:`~core.tracking.register.RegistrationOptions`; default the tracker's
    local options) is used with ``search="local"`` (``"newton"`` for the Gauss–Newton searches,
    module docs) and bounds of at least twice ``spread``.
    """
    from .register import RegistrationOptions, register

    if isinstance(n, bool) or int(n) != n or n < 1:
        raise ValueError(f"n: expected a positive number of restarts, got {n!r}")
    if len(spread) != 2 or min(spread) < 0 or len(pose_tol) != 2 or min(pose_tol) <= 0:
        raise ValueError(f"spread, pose_tol: expected (mm, degrees) pairs, got {spread!r}, {pose_tol!r}")
    if not score_tol >= 0:
        raise ValueError(f"score_tol: expected a non-negative score difference, got {score_tol!r}")
    c = np.asarray(center, dtype=float)
    o = options or RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0))
    newton = (o.search in ("newton", "global_newton") and o.levels is None and o.refine is None
              and _engine_supports(o.terms))
    o = replace(o, search="newton" if newton else "local", levels=None,
                bounds=(max(o.bounds[0], 2 * spread[0]), max(o.bounds[1], 2 * spread[1])))
    levels = None
    if newton:  # half resolution first: a restart is beyond the full-resolution steps' reach
        from .register import _newton_fallback, mm_per_pixel

        vw = tuple(range(frame.n_views)) if views is None else tuple(views)
        fs = o.final_scale
        levels = tuple(replace(lv, scale=lv.scale * fs) for lv in _newton_fallback(
            mm_per_pixel(renderer, np.asarray(result.pose, float), c, vw) * fs))
    g = np.random.default_rng(seed)
    runs, evals = [], 0
    if newton:  # one search box about the checked pose, the restarts side by side from their displacements
        from .joint import restarts_together

        x0s = []
        for _ in range(int(n)):
            t, a = g.normal(size=3), g.normal(size=3)
            x0s.append(np.r_[t / np.linalg.norm(t) * spread[0], a / np.linalg.norm(a) * spread[1]])
        if not (cancel is not None and cancel()):
            runs = restarts_together(renderer, frame, bone=bone, base=result.pose, center=c, x0s=x0s,
                                     options=replace(o, levels=levels), views=views, others=others,
                                     outline=outline, cancel=cancel,
                                     settle=(pose_tol[0] / 2, pose_tol[1] / 2))
        evals = sum(r.evaluations for r in runs)
    for k in range(0 if newton else int(n)):
        if cancel is not None and cancel():
            break
        t, a = g.normal(size=3), g.normal(size=3)
        p = np.r_[t / np.linalg.norm(t) * spread[0], a / np.linalg.norm(a) * np.radians(spread[1])]
        start = pose_from_params(p, center=c, base=result.pose)
        r = register(renderer, frame, bone=bone, initial_pose=start, center=c,
                     options=replace(o, seed=o.seed + 31 * (k + 1)), views=views, others=others,
                     cancel=cancel, outline=outline)
        evals += r.evaluations
        runs.append(r)
    best = result
    for r in runs:
        if r.score > best.score + score_tol and (r.converged or r.score > result.score + 3 * score_tol):
            best = r
    improved = best is not result
    scores = tuple(float(r.score) for r in runs)
    dist = tuple(_distance(best.pose, r.pose, c) for r in runs)
    ambiguous = any(r.converged and abs(r.score - best.score) <= score_tol
                    and (d[0] > pose_tol[0] or d[1] > pose_tol[1]) for r, d in zip(runs, dist, strict=True))
    return StartCheck(best, improved, ambiguous, scores, dist, evals)
