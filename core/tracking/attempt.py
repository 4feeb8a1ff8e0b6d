"""One bone's registration in one frame with the tracker's checks (:func:`register_checked`).

The registration of :func:`core.tracking.register.register`, its failure checks
(:mod:`core.tracking.checks`), one wider retry, the restart check of
:func:`core.tracking.verify.verify_start` on first frames and retries (a false optimum corrected,
an ambiguous one flagged, a score drop of the image confirmed rather than flagged) and the
per-frame confidence; see the module docs of :mod:`core.tracking.trial`.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import nullcontext
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from .bones import BoneModel
from .checks import MOTION_FLOOR, MOTION_LIMIT
from .checks import confirmable as _confirmable
from .checks import failures as _failures
from .checks import motion_limits as _motion_limits
from .checks import same_optimum as _same_optimum
from .checks import sigma_check as _sigma_check
from .checks import uncertain as _uncertain
from .confidence import confidence_from_fit, curvature_confidence
from .cost import OutsideViewError, RegistrationCost, search_roi
from .first_restarts import during_stage
from .register import RegistrationOptions, register
from .stage_sigma import remeasurable, remeasured
from .verify import verify_start

if TYPE_CHECKING:
    from .options import TrackingOptions

__all__ = ["Attempt", "confidence_of", "limits_ahead", "register_checked", "settle"]

#: timings that are parts of another timing of the same registration (not added to the sum)
_PARTS = frozenset({"likelihood_setup_s"})


@dataclass
class Attempt:
    """One bone's registration in one frame with its checks (:func:`register_checked`)."""

    result: object  # RegistrationResult | None (outside a view)
    flags: list
    retried: bool
    evaluations: int
    time_s: float
    confidence: dict | None
    timing: dict | None
    notes: tuple = ()
    #: the confidence and its checks left to :func:`settle` (``(fit, options, good sigmas)``)
    pending: tuple | None = None


def settle(a: Attempt) -> Attempt:
    """Compute the confidence that :func:`register_checked` left pending (``defer_confidence``) and
    add its flags, as it would have: the same values and flags, in the same order."""
    if a.pending is not None:
        fit, o, good_sigmas = a.pending
        a.pending = None
        a.confidence = confidence_of(fit, o)
        a.flags = a.flags + _conf_flags(a.confidence, a.flags, o, good_sigmas)
    return a


def _conf_flags(conf, flags, o: TrackingOptions, good_sigmas) -> list:
    """The flags of a confidence (the user's limits, the bone's own σ)."""
    out = []
    if o.max_uncertainty is not None:
        out += _uncertain(conf, o.max_uncertainty)
    if good_sigmas is not None and not any(f.startswith("uncertain") for f in (*flags, *out)):
        out += _sigma_check(conf, good_sigmas, n=o.history, limit=o.sigma_limit)
    return out


def _lengths(conf: dict) -> str:
    """A confidence's σ lengths as a note says them."""
    t, r = conf.get("translation_mm"), conf.get("rotation_deg")
    return "not determined" if t is None or r is None else f"{t:.3f} mm, {r:.3f} deg"


def confidence_of(fit, o: TrackingOptions) -> dict:
    """The confidence of a quadratic fit about the optimum, σ scaled by ``confidence_scale``."""
    c = confidence_from_fit(fit)
    if o.confidence_scale != 1.0:
        k = float(o.confidence_scale)
        c = replace(c, sigma=c.sigma * k, covariance=c.covariance * k * k)
    return c.to_dict()


def limits_ahead(checks: list, o: TrackingOptions, frame_number: int) -> Callable[[], None] | None:
    """Host work for a registration's waits (``idle`` of :func:`core.tracking.joint.register_together`):
    at each call the motion check's limits of the next of ``checks`` (per bone ``(history, centre,
    prediction)``, as :func:`register_checked` passes them to the checks) computed and kept, as
    :func:`register_checked`'s own idle does for one bone, so that the checks after the registration
    find them (the same values). None where no bone has a history."""
    todo = [c for c in checks if c[0]]
    if not todo:
        return None

    def idle() -> None:
        if todo:
            history, c, prediction = todo.pop(0)
            _motion_limits(history, frame_number, c, n=o.history,
                           limit=getattr(o, "motion_limit", MOTION_LIMIT),
                           floor=getattr(o, "motion_floor", MOTION_FLOOR), prediction=prediction)

    return idle


def _final_stage_of(renderer, frame, res, index: int, base, center, opts: RegistrationOptions, others):
    """``res`` (a registration without its final stage: the restart check's, whose ``x`` is relative to
    ``base``, the checked pose) through the final stage of ``opts``, as :func:`~core.tracking.register.
    register` ends a registration with one."""
    from .final_stage import final_stage

    return final_stage(renderer, frame, res, bone=index, initial_pose=base, center=center, options=opts,
                       views=tuple(range(frame.n_views)), others=others)


def register_checked(renderer, frame, bone: BoneModel, index: int, start, guess, opts: RegistrationOptions,
                     o: TrackingOptions, good_scores, others, cancel, history, *, verify: bool = False,
                     start_score: float | None = None, seed: int = 0, pre=None,
                     frame_number: int | None = None, good_sigmas=None, reference: float | None = None,
                     host_only: bool = False, defer_confidence: bool = False, prediction=None):
    """Register with failure checks, one wider retry and (first frames, retries) the restart
    check of :func:`core.tracking.verify.verify_start`. ``pre``: ``(registration or the
    OutsideViewError it raised, seconds spent)`` already run with these inputs
    (:func:`core.tracking.joint.register_together`), in place of the first registration.
    ``history`` (the bone's good ``(frame, pose)``) and ``frame_number`` give the motion check
    (:func:`core.tracking.checks.motion_check`), ``good_sigmas`` (the good frames' confidence
    lengths, mm and degrees) the relative ``"uncertain"`` check
    (:func:`core.tracking.checks.sigma_check`), ``reference`` the score of a flagged first frame
    that later frames are compared with while the bone has no good score, ``prediction`` the
    frame's constant-velocity prediction from ``history`` for the motion check
    (:func:`core.tracking.frame_state.motion_prediction`; None: the check computes it).

    Returns an :class:`Attempt`; with ``host_only``, None where the checks would use the device
    (a retry, the restart check, a confidence of a cost of its own: the caller runs them later).
    ``defer_confidence``: a confidence from the search's own fit is left to :func:`settle` (joint
    tracking's rounds before the last: their results are mostly replaced by the next round's)."""
    t0 = time.perf_counter()
    c = bone.centroid
    cancelled = cancel if cancel is not None else (lambda: False)
    try:
        if pre is None:
            idle = None
            if frame_number is not None and history:  # the motion check's limits while the device works
                def idle() -> None:
                    _motion_limits(history, frame_number, c, n=o.history,
                                   limit=getattr(o, "motion_limit", MOTION_LIMIT),
                                   floor=getattr(o, "motion_floor", MOTION_FLOOR), prediction=prediction)
            ahead = nullcontext()
            if verify and o.verify_restarts:  # the restart check's first regions made during the stage
                ahead = during_stage(renderer, frame, bone=index, center=c, options=o.registration,
                                     spread=o.verify_spread, outline=bone.outline)
            with ahead:
                res = register(renderer, frame, bone=index, initial_pose=start, center=c, options=opts,
                               others=others, cancel=cancel, profile=o.profile, outline=bone.outline,
                               idle=idle)
        else:
            res, spent = pre
            t0 -= spent
            if isinstance(res, OutsideViewError):
                raise res
    except OutsideViewError as exc:
        return Attempt(None, [f"outside the field of view: {exc}"], False, 0, time.perf_counter() - t0, None,
                       None)
    evals = res.evaluations
    first = res.pose
    timing = {k: v for k, v in res.timing.items() if k != "total_s"}

    def add(r) -> None:
        nonlocal evals
        evals += r.evaluations
        for k in timing:
            timing[k] += r.timing.get(k, 0.0)

    jump = o.retry_factor if verify else 1.0
    more = {"history": history, "frame": frame_number, "reference": reference, "prediction": prediction} \
        if frame_number is not None else {"reference": reference}
    flags = _failures(res, guess, c, good_scores, o, start_score=start_score, jump_factor=jump, **more)
    if host_only and ((flags and not cancelled()) or verify or (o.confidence and res.fit is None)):
        return None
    retried = False
    if flags and not cancelled():
        retried = True
        wide = opts.widened(o.retry_factor)  # (only for a retry: a new options object each call)
        starts = [guess] + ([history[-1][1]] if history else [])
        for s in starts:
            try:
                r2 = register(renderer, frame, bone=index, initial_pose=s, center=c, options=wide,
                              others=others, cancel=cancel, profile=o.profile, outline=bone.outline)
            except OutsideViewError:
                continue
            add(r2)
            f2 = _failures(r2, guess, c, good_scores, o, start_score=start_score,
                           jump_factor=o.retry_factor * jump, **more)
            if (len(f2), -r2.score) < (len(flags), -res.score):
                res, flags = r2, f2
            if not flags:
                break
    notes = []
    chk = None
    if (verify or retried) and o.verify_restarts and not cancelled():
        checked = res
        try:
            chk = verify_start(renderer, frame, bone=index, result=res, center=c, options=o.registration,
                               n=o.verify_restarts, spread=o.verify_spread, seed=seed, others=others,
                               outline=bone.outline, cancel=cancel)
        except OutsideViewError:
            chk = None
        if chk is not None:
            evals += chk.evaluations
            if chk.improved:  # the first optimum was false: search wider from the better one
                best = chk.result
                try:
                    r2 = register(renderer, frame, bone=index, initial_pose=best.pose, center=c,
                                  options=opts.widened(o.retry_factor), others=others, cancel=cancel,
                                  profile=o.profile, outline=bone.outline)
                    add(r2)
                    if r2.score > best.score:
                        best = r2
                except OutsideViewError:
                    pass
                if best is chk.result and opts.final is not None and "likelihood_taken" not in best.timing:
                    # the restarts are searches only: the kept one through the final stage, as every
                    # registration of opts ends (else the frame keeps a pose no stage refined)
                    best = _final_stage_of(renderer, frame, best, index, checked.pose, c, opts, others)
                    evals += best.evaluations - chk.result.evaluations
                    for k in ("likelihood_s", "likelihood_setup_s", "likelihood_steps", "likelihood_renders"):
                        if k in best.timing:
                            timing[k] = timing.get(k, 0) + best.timing[k]
                res = best
                flags = _failures(res, guess, c, good_scores, o, start_score=start_score,
                                  jump_factor=o.retry_factor * jump, **more)
                notes.append("start corrected by restarts")
            if chk.ambiguous:
                far = max(d for d, sc in zip(chk.distances, chk.scores, strict=True)
                          if abs(sc - chk.result.score) <= 0.01)
                flags.append(f"ambiguous optimum (a restart {far[0]:.2f} mm, {far[1]:.2f} deg away "
                             f"scores within 0.01)")
        if (retried and chk is not None and not chk.improved and not chk.ambiguous and flags
                and all(_confirmable(f) for f in flags) and _same_optimum(first, res.pose, c)):
            # the image changed, not the registration: the first search, the wider ones and the
            # restarts all end at the same pose
            notes.append(f"{flags[0]}: the wider search and {o.verify_restarts} restarts confirmed the "
                         f"optimum")
            flags = []
    conf = None
    pending = None
    if o.confidence and res.fit is not None and defer_confidence:
        pending = (res.fit, o, good_sigmas)
    elif o.confidence and res.fit is not None:
        conf = confidence_of(res.fit, o)  # the last design about the optimum
    elif o.confidence:
        try:
            roi = search_roi(renderer, res.pose, index, views=tuple(range(frame.n_views)), center=c,
                             reach_mm=2.0, margin_px=opts.margin_px, points=bone.outline)
            cost = RegistrationCost(renderer, frame, bone=index, base_pose=res.pose, center=c, roi=roi,
                                    terms=opts.terms, others=others)
            conf = curvature_confidence(cost, np.zeros(6), step=o.confidence_step)
            if o.confidence_scale != 1.0:
                k = float(o.confidence_scale)
                conf = replace(conf, sigma=conf.sigma * k, covariance=conf.covariance * k * k)
            conf = conf.to_dict()
        except OutsideViewError:
            conf = None
        evals += 73 if conf is not None else 0
    if pending is None:
        more = _conf_flags(conf, flags, o, good_sigmas)
        if more and conf is not None and not cancelled() and remeasurable(res, o.registration):
            # the σ's stage move from the similarity's optimum, not from where its search stopped
            if host_only:  # (stage_sigma)
                return None
            got = remeasured(renderer, frame, res, bone=index, center=c, options=o.registration,
                             others=others, outline=bone.outline, cancel=cancel, profile=o.profile)
            if got is not None:
                res, conv = got
                add(conv)
                was, conf = conf, confidence_of(res.fit, o)
                more = _conf_flags(conf, flags, o, good_sigmas)
                notes.append(f"confidence's stage move from the similarity's optimum: {_lengths(was)} -> "
                             f"{_lengths(conf)} (its search had stopped before the stage)")
        flags += more
    dt = time.perf_counter() - t0
    # confidence, restarts, set-up (the final stage's set-up is a part of its likelihood_s)
    timing["other_s"] = dt - sum(v for k, v in timing.items() if k.endswith("_s") and k not in _PARTS)
    return Attempt(res, flags, retried, evals, dt, conf, timing, tuple(notes), pending)
