"""Per-frame pose uncertainty: from the cost's curvature at the optimum, or from restarts.

Curvature (:func:`curvature_confidence`, one batched cost call)
---------------------------------------------------------------
The cost is sampled on a second-order stencil about the optimum ``x*`` (mm, degrees): the
centre, the 12 points ``x* ± h_i e_i`` and the 60 points ``x* ± h_i e_i ± h_j e_j`` — 73 poses in
one launch — and a full quadratic ``c(x*+d) ≈ c0 + gᵀd + ½ dᵀHd`` (28 coefficients) is fitted by
least squares. The fit's residual RMS ``σ_c`` measures how rough the cost is at the scale of the
stencil (image noise, interpolation), and the pose uncertainty is the half-width of the region
where the quadratic rises by less than that roughness — poses the data cannot tell apart::

    Σ = 2 σ_c H⁻¹,     sigma_i = sqrt(Σ_ii)          (mm for t, degrees for r)

This is the Laplace / indifference-region construction; it grows with noise (σ_c) and along
poorly constrained directions (small curvature, e.g. a rotation about a long bone's axis). A
Hessian that is not positive definite (a saddle or a flat direction) gives infinite sigma in the
affected coordinates and ``well_posed = False``. The number is a *scale*, not a calibrated
standard error: the acceptance study of :mod:`core.studies.tracking.acceptance` reports how often the
true error lies within 2 sigma.

The same construction applies to the last full-resolution fit of the quadratic-model search
(:func:`confidence_from_fit`), which samples a 73-point design of half-widths
``(0.25 mm, 0.5°)`` about the optimum anyway: tracking gets the uncertainty of every frame
without another launch.

Restarts (:func:`restart_confidence`)
-------------------------------------
``n`` registrations from starts scattered about the optimum; the spread (standard deviation) of
their results is an empirical repeatability. Costs ``n`` registrations.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["PoseConfidence", "confidence_from_fit", "curvature_confidence", "restart_confidence",
           "stencil"]


@dataclass(frozen=True, eq=False)
class PoseConfidence:
    """Pose uncertainty.

    Attributes
    ----------
    sigma : (6,) array
        Per-parameter uncertainty (tx, ty, tz in mm; rx, ry, rz in degrees, about the centroid).
    covariance : (6, 6) array
    method : {"curvature", "restarts"}
    cost_noise : float
        σ_c, RMS residual of the quadratic fit (curvature) or NaN.
    hessian : (6, 6) array or None
        Fitted Hessian of the cost (per mm², mm·deg, deg²).
    well_posed : bool
        False when the Hessian is not positive definite (or a restart failed).
    """

    sigma: np.ndarray
    covariance: np.ndarray
    method: str
    cost_noise: float = float("nan")
    hessian: np.ndarray | None = None
    well_posed: bool = True

    @property
    def translation_mm(self) -> float:
        """Length of the translation sigma vector, mm."""
        return _norm(self.sigma[:3])

    @property
    def rotation_deg(self) -> float:
        """Length of the rotation sigma vector, degrees."""
        return _norm(self.sigma[3:])

    def to_dict(self) -> dict:
        def clean(v: float):
            return float(v) if math.isfinite(v) else None

        t, r = self.translation_mm, self.rotation_deg
        return {"method": self.method, "sigma": [clean(v) for v in np.ravel(self.sigma).tolist()],
                "translation_mm": clean(t), "rotation_deg": clean(r),
                "cost_noise": clean(float(self.cost_noise)), "well_posed": self.well_posed}


def stencil(n: int = 6) -> np.ndarray:
    """``(1 + 2n + 2n(n-1), n)`` unit second-order stencil: centre, ±e_i, ±e_i ± e_j
    (:func:`core.tracking.quadratic.design` ``"full"``)."""
    from .quadratic import design

    return design(n, "full")


def _norm(x) -> float:
    """``float(np.linalg.norm(x))`` of a float vector (the same square root of ``x.dot(x)``)."""
    x = np.asarray(x, dtype=float).ravel()
    return math.sqrt(float(x.dot(x)))


def _any_flat(w: np.ndarray) -> bool:
    """Whether an eigenvalue of ``w`` is zero up to round-off (``w <= 1e-9 max |w|``), on Python
    numbers (NaN: numpy's comparison)."""
    v = w.tolist()
    if any(x != x for x in v):
        return bool((w <= 1e-9 * max(float(np.abs(w).max()), 1e-300)).any())
    lim = 1e-9 * max(max(abs(x) for x in v), 1e-300)
    return any(x <= lim for x in v)


def _from_hessian(H: np.ndarray, noise: float, method: str) -> PoseConfidence:
    H = 0.5 * (np.asarray(H, dtype=float) + np.asarray(H, dtype=float).T)
    w, V = np.linalg.eigh(H)
    # a floor on the noise: float32 metric arithmetic cannot resolve cost differences below ~1e-6
    noise_eff = max(float(noise), 1e-6)
    if _any_flat(w):
        flat = w <= 1e-9 * max(float(np.abs(w).max()), 1e-300)  # zero up to round-off
        cov = np.full((6, 6), np.inf)
        sig = np.sqrt(np.abs(np.diag(2 * noise_eff * np.linalg.pinv(H))))
        # coordinates touched by a non-positive direction are unbounded
        bad = np.abs(V[:, flat]).max(axis=1) > 0.3
        sig[bad] = np.inf
        return PoseConfidence(sig, cov, method, float(noise), H, False)
    cov = 2.0 * noise_eff * np.linalg.inv(H)
    return PoseConfidence(np.sqrt(np.diag(cov)), cov, method, float(noise), H, True)


def curvature_confidence(cost, x, *, step=(0.25, 0.25)) -> PoseConfidence:
    """Uncertainty of the optimum ``x`` (mm, degrees) of ``cost(X (B, 6)) -> (B,)`` from the
    curvature of a quadratic fitted on a 73-point stencil of half-widths ``step`` (mm, degrees)
    — one batched call of ``cost``."""
    from .quadratic import fit_quadratic

    x = np.asarray(x, dtype=float).ravel()
    if x.shape != (6,):
        raise ValueError(f"x: expected 6 parameters (mm, degrees), got shape {x.shape}")
    h = np.array([step[0]] * 3 + [step[1]] * 3, dtype=float)
    if np.any(h <= 0) or not np.all(np.isfinite(h)):
        raise ValueError(f"step: expected positive (mm, degrees) steps, got {step!r}")
    D = stencil(6) * h
    f = np.asarray(cost(x + D), dtype=float)
    fit = fit_quadratic(D, f, h, x=x)
    return _from_hessian(fit.H, fit.noise, "curvature")


def confidence_from_fit(fit) -> PoseConfidence:
    """Uncertainty from a :class:`core.tracking.quadratic.QuadraticFit` of the cost about the
    optimum (6 parameters in mm and degrees): ``Σ = 2 σ_c H⁻¹`` as in
    :func:`curvature_confidence`, ``method = "curvature"``."""
    H = np.asarray(fit.H, dtype=float)
    if H.shape != (6, 6):
        raise ValueError(f"fit: expected a 6-parameter quadratic fit, got a Hessian of shape {H.shape}")
    return _from_hessian(H, fit.noise, "curvature")


def restart_confidence(renderer, frame, *, bone: int, pose, center, options=None, n: int = 5,
                       spread=(1.0, 1.0), seed: int = 0, views=None, others=None) -> PoseConfidence:
    """Repeatability of :func:`core.tracking.register.register` from ``n`` starts drawn uniformly
    within ``±spread`` (mm, degrees) of ``pose``: the standard deviation of the results'
    parameters about ``pose`` (mm, degrees)."""
    from ..geometry.transforms import params_from_pose, pose_from_params
    from .register import RegistrationOptions, register

    if int(n) != n or n < 2:
        raise ValueError(f"n: expected at least 2 restarts, got {n!r}")
    o = options or RegistrationOptions()
    g = np.random.default_rng(seed)
    pose = np.asarray(pose, dtype=float)
    out, ok = [], True
    for k in range(int(n)):
        d = g.uniform(-1, 1, size=6) * np.array([spread[0]] * 3 + [spread[1]] * 3)
        start = pose_from_params(np.r_[d[:3], np.radians(d[3:])], center=center, base=pose)
        from dataclasses import replace

        r = register(renderer, frame, bone=bone, initial_pose=start, center=center,
                     options=replace(o, seed=o.seed + 17 * k), views=views, others=others)
        ok &= r.converged
        p = params_from_pose(r.pose, center=center, base=pose)
        out.append(np.r_[p[:3], np.degrees(p[3:])])
    P = np.array(out)
    cov = np.cov(P.T)
    return PoseConfidence(P.std(axis=0, ddof=1), cov, "restarts", well_posed=bool(ok))
