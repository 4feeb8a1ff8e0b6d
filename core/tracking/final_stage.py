"""The opt-in final stage of a registration (:class:`core.tracking.register.RegistrationOptions`
``final``; the register module's docs): the similarity's optimum refined by weighted least
squares on the device (:mod:`core.tracking.engine_likelihood`), its confidence the refinement's
sandwich covariance."""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from ..geometry.transforms import params_from_pose
from .cost import CostTimer, FrameImages, OutsideViewError, search_roi, snap_roi
from .engine_likelihood import likelihood_engine

__all__ = ["LikelihoodFit", "final_stage"]


@dataclass(frozen=True, eq=False)
class LikelihoodFit:
    """The refinement's confidence in the form :func:`core.tracking.confidence.confidence_from_fit`
    reads (``Σ = 2 · noise · H⁻¹``): ``H = 2 Σ⁻¹`` and ``noise = 1`` give back ``covariance``, the
    stage's covariance (mm, degrees; ``final_confidence`` of the options, from
    :meth:`core.tracking.engine_likelihood.LikelihoodEngine.refine`); ``x`` the refined
    parameters, ``chi2`` the weighted residual, ``covariance_independent`` the covariance that
    treats the pixels as independent (for comparison)."""

    H: np.ndarray
    noise: float
    covariance: np.ndarray
    x: np.ndarray
    chi2: float
    covariance_independent: np.ndarray
    method: str = "likelihood"

    @classmethod
    def of(cls, covariance, *, x, chi2: float, covariance_independent) -> LikelihoodFit:
        C = np.asarray(covariance, dtype=float)
        return cls(2.0 * np.linalg.inv(C), 1.0, C, np.asarray(x, dtype=float), float(chi2),
                   np.asarray(covariance_independent, dtype=float))


def final_stage(renderer, frame: FrameImages, res, *, bone: int, initial_pose, center, options,
                views: Sequence[int], others=None):
    """``res`` (a :class:`core.tracking.register.RegistrationResult`) refined by the final stage of
    ``options`` (its :class:`~core.tracking.register.RegistrationOptions`; module docs): a
    registration result, ``res`` itself without a stage or after a cancelled one.
    ``initial_pose``: the registration's (``x`` is relative to it). This module does not import
    :mod:`core.tracking.register`, which calls it."""
    o = options
    if o.final is None or any(s.reason == "cancelled" for s in res.stages):
        return res
    t0 = time.perf_counter()
    timing = dict(res.timing)
    views = tuple(views)
    center = np.asarray(center, dtype=float)
    try:
        roi = snap_roi(search_roi(renderer, res.pose, bone, views=views, center=center, reach_mm=1.0,
                               margin_px=o.margin_px), renderer, views)
        eng = likelihood_engine(renderer, bone=bone, views=views, highpass_px=o.final_highpass_px,
                                lag_px=o.final_lag_px, others_gain=o.final_others_gain)
        eng.timer = CostTimer()
        eng.set_frame(frame, base_pose=res.pose, center=center, roi=roi, others=others)
        timing["likelihood_setup_s"] = time.perf_counter() - t0
        out = eng.refine(iters=o.final_iters)
    except (OutsideViewError, np.linalg.LinAlgError):  # the similarity's pose stands
        timing["likelihood_s"] = time.perf_counter() - t0
        timing["likelihood_taken"] = 0
        return replace(res, timing=timing)
    d = np.asarray(out["x"], dtype=float)
    cov = np.asarray(out["covariance_independent" if o.final_confidence == "independent" else "covariance"],
                     dtype=float)
    if o.final_confidence == "sandwich+move":  # the two costs' disagreement: a systematic part neither sees
        cov = cov + np.outer(d, d)
    reach = np.array([o.final_reach[0]] * 3 + [o.final_reach[1]] * 3)
    dt = time.perf_counter() - t0
    timing["likelihood_s"] = dt
    timing["likelihood_steps"] = int(out["iterations"])
    timing["total_s"] = timing.get("total_s", 0.0) + dt
    evals = res.evaluations + 13 * int(out["iterations"])
    timing["likelihood_move_mm"] = float(np.linalg.norm(d[:3]))  # NaN when the steps failed
    timing["likelihood_move_deg"] = float(np.linalg.norm(d[3:]))
    if not (np.all(np.isfinite(d)) and np.all(np.abs(d) <= reach) and np.all(np.isfinite(cov))):
        timing["likelihood_taken"] = 0
        return replace(res, timing=timing, evaluations=evals, time_s=res.time_s + dt)
    pose = eng.poses(d[None])[0]
    p = params_from_pose(pose, center=center, base=np.asarray(initial_pose, dtype=float))
    x = np.r_[p[:3], np.degrees(p[3:])]
    timing["likelihood_taken"] = 1
    fit = LikelihoodFit.of(cov, x=x, chi2=float(out["chi2"]),
                           covariance_independent=out["covariance_independent"])
    return replace(res, pose=pose, x=x, fit=fit, timing=timing, evaluations=evals, time_s=res.time_s + dt,
                   generations=res.generations + int(out["iterations"]))
