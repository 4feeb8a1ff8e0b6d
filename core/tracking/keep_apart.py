"""Joint tracking with ``contact``: a registered pose that comes into a neighbour polished apart
(:func:`keep_apart`, called by :func:`core.tracking.frame_step.track_frame` for each registration).

Where bone ``i``'s registered pose comes closer than ``TrackingOptions.contact_margin_mm`` to a
neighbour registered in the same frame, :func:`core.tracking.contact.polish_with_contact`
re-optimises the image similarity with the interpenetration penalty about it, and its pose replaces
the registration's. With the final stage (``TrackingOptions.refine_likelihood``) the registration's
pose was the stage's, and the polish — a similarity search — drops the stage's refinement: the polished
pose stands with the stage's outcome ``likelihood_taken`` 0 and a note (f0b8a7a).

:data:`RESTAGE` (off) runs the stage once more from the polished pose and keeps its pose where it comes no
deeper into a neighbour than the polished pose (the stage's outcome and confidence, a note; the second
stage's time, steps and renders added to the attempt's). It did not pay: the stage knows no penalty, and
from the polished pose it went back to its own optimum, as deep in the neighbour as before, in every case
tried (the ideal 128² talus-calcaneus frames, this 2-core x86_64 machine's CPU: with a 6 mm margin 1.63 mm
in, polished to 0.84 mm, the stage again 1.63 mm in, as ``test_keep_apart_stage`` pins; with 2 and 3 mm,
0.12 and 0.58 mm back in), so the polished pose stood at the cost of a second stage. Keeping the
stage's refinement needs the penalty in the stage's own cost (:mod:`core.tracking.engine_likelihood`).
Moving the staged pose off the neighbour in the stage's own metric (the nearest pose in ``xᵀ H x`` no
deeper than the polished one; SLSQP on the host) was tried on the same frames and not kept: the stage's
σ there is a few µm, every such pose hundreds of σ away, and the nearest in that metric was 1.9 mm /
2.6° from the stage's pose where the polish moved it 0.4 mm / 1.0°.
"""

from __future__ import annotations

import time
from dataclasses import replace as _replace

from .attempt import Attempt, confidence_of
from .cost import OutsideViewError

__all__ = ["RESTAGE", "keep_apart"]

#: A polished pose that the final stage had refined goes through the stage once more, its pose kept where no
#: deeper (module docs: it went back to its own optimum in every case tried); off: the polished pose stands,
#: the stage's outcome ``likelihood_taken`` 0.
RESTAGE = False

#: the stage's times and counts added to the attempt's (as the restart check's kept stage's are)
_STAGE_WORK = ("likelihood_s", "likelihood_setup_s", "likelihood_steps", "likelihood_renders")


def keep_apart(run, frame, i: int, a: Attempt, others, placed: list, opts) -> None:
    """When bone ``i``'s registered pose (``a.result``) comes closer than the margin to a neighbour
    registered in this frame (``placed``: (index, pose)), polish it under the interpenetration penalty
    of :mod:`core.tracking.contact` and, where the stage had refined it and :data:`RESTAGE` is on, run the
    stage of ``opts`` (the registration options) once more from the polished pose (module docs). ``a`` is
    updated in place: pose, score, fit, confidence, work, a note with the depth resolved. ``others``: the
    neighbours the registration subtracted (the stage subtracts them too)."""
    from . import contact

    o = run.options
    neighbours = [(run.contacts[k], P) for k, P in placed]
    me = run.contacts[i]
    m = o.contact_margin_mm
    depth = float(contact.penetration_depths(me, a.result.pose[None], neighbours, margin=m)[0])
    if depth <= 0:
        return
    t0 = time.perf_counter()
    bone = run.bones[i]
    try:
        P, score, fit, evals, left = contact.polish_with_contact(
            run.renderer, frame, bone=i, pose=a.result.pose, center=bone.centroid, contact=me,
            neighbours=neighbours, terms=opts.terms, others=others, outline=bone.outline,
            weight=o.contact_weight, margin=m, margin_px=opts.margin_px, cancel=run.cancel)
    except OutsideViewError:
        return
    staged = bool((a.result.timing or {}).get("likelihood_taken"))
    res = _replace(a.result, pose=P, score=score, fit=fit)
    if staged:  # (the polish moved the final stage's pose: the stage ran, its pose is not the one kept)
        res = _replace(res, timing={**res.timing, "likelihood_taken": 0})
    a.evaluations += evals
    note = f"contact: {depth:.2f} mm interpenetration resolved to {left:.2f} mm"
    spent = 0.0  # (the second stage's wall time: its likelihood_s, not other_s)
    if staged:
        t1 = time.perf_counter()
        again = _restage(run, frame, i, res, others, opts) if RESTAGE and not run.cancel() else None
        spent = time.perf_counter() - t1
        if again is not None:  # (its work counted whether its pose is kept or not)
            a.evaluations += again.evaluations - res.evaluations
            if a.timing is not None:
                for k in _STAGE_WORK:
                    if k in again.timing:
                        a.timing[k] = a.timing.get(k, 0) + again.timing[k]
        if again is None or not again.timing.get("likelihood_taken"):
            note += "; the final stage's pose polished with the similarity"
        elif (deeper := _deeper(run, i, res.pose, again, neighbours)) is None:
            res, fit = again, again.fit
            note += "; the final stage run again from the polished pose, its pose kept"
        else:
            note += (f"; the final stage run again from the polished pose came {deeper:.2f} mm into a "
                     f"neighbour: the polished pose kept")
    a.result = res
    dt = time.perf_counter() - t0
    a.time_s += dt
    if a.timing is not None:
        a.timing["other_s"] = a.timing.get("other_s", 0.0) + dt - spent
    if o.confidence and fit is not None:
        a.confidence = confidence_of(fit, o)
    a.notes = (*a.notes, note)


def _restage(run, frame, i: int, res, others, opts):
    """``res`` (the polished result) through the final stage of ``opts`` (None where the frame lies
    outside a view there); its outcome and work in its timing (the first stage's work left out)."""
    from .final_stage import final_stage

    fresh = _replace(res, timing={k: v for k, v in res.timing.items() if k not in _STAGE_WORK})
    try:  # (its timing then holds this stage's work alone)
        return final_stage(run.renderer, frame, fresh, bone=i, initial_pose=res.pose,
                           center=run.bones[i].centroid, options=opts, views=tuple(range(frame.n_views)),
                           others=others)
    except OutsideViewError:
        return None


def _deeper(run, i: int, polished, again, neighbours: list) -> float | None:
    """The depth (mm) by which the stage's pose ``again.pose`` comes into a neighbour where deeper than
    the polished pose's; None where not (the stage's pose is kept)."""
    from . import contact

    m = run.options.contact_margin_mm
    d0, d1 = (float(contact.penetration_depths(run.contacts[i], P[None], neighbours, margin=m)[0])
              for P in (polished, again.pose))
    return None if d1 <= d0 else d1
