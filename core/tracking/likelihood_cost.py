"""A likelihood-like cost of one bone in one frame, for an opt-in final refinement.

:class:`LikelihoodCost` scores poses by the weighted least-squares χ² of the bone's DRRs against
the fluoroscope's line integrals (:mod:`core.similarity.likelihood`), with the same parameters as
:class:`core.tracking.cost.RegistrationCost`; :meth:`LikelihoodCost.refine` minimises it by
Gauss–Newton steps. What it was measured to gain and why: :mod:`core.studies.tracking.bound_gap`,
:mod:`core.studies.tracking.ml_cost`. The same refinement on the device, the registrations' opt-in
final stage: :mod:`core.tracking.engine_likelihood`, :mod:`core.tracking.final_stage`.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np

from .cost import CostTimer, FrameImages, RegistrationCost, fluoro_rois

__all__ = ["LikelihoodCost"]


class LikelihoodCost:
    """``cost(X (B, 6)) -> (B,)``: half the weighted least-squares χ² of the bone's DRRs against
    the fluoroscope's line integrals (:mod:`core.similarity.likelihood`), for one bone in one
    frame at full resolution — a likelihood-like cost for a final refinement, opt-in.

    Per view, the model of the search region is the bone's DRR (blurred by ``psf`` when given)
    times a gain, plus the other bones' DRRs (``others``, at fixed poses, blurred alike) times
    their own gain, plus a smooth background (``background``: polynomial order), all fitted
    linearly at every pose; pixels weigh by their expected counts (the smoothed relative
    fluence) over the usable pixels of the region — or, with ``dilate`` (pixels), only over the
    bone's footprint at the base pose grown by that much. ``psf`` must come from calibration
    images (e.g. :func:`core.imaging.psf.psf_from_pinholes`), never from a generator's truth.

    Same mapping of parameters as :class:`RegistrationCost` (:meth:`poses`, :meth:`params`).
    Larger = worse; the value is not bounded (χ²/2, not 1 - score).
    """

    def __init__(self, renderer, frame: FrameImages, *, bone: int, base_pose, center, roi,
                 views: Sequence[int] | None = None, others=None, psf=None, background: int = 1,
                 dilate: int | None = None, weight_sigma_px: float = 2.0, highpass_px: float | None = None,
                 others_gain: bool = True) -> None:
        from scipy import ndimage

        from ..similarity.likelihood import expected_counts, highpass

        self.renderer = renderer
        self.views = tuple(range(frame.n_views)) if views is None else tuple(int(v) for v in views)
        self.bone = int(bone)
        self.base = np.asarray(base_pose, dtype=float)
        self.center = np.asarray(center, dtype=float)
        self.roi = np.asarray(roi, dtype=np.int64).reshape(len(self.views), 4)
        self._roi_arg = self.roi[None, :, None, :]
        self.psf = None if psf is None else np.asarray(psf, dtype=np.float64)
        if self.psf is not None and (self.psf.ndim != 2 or self.psf.shape[0] % 2 == 0
                                     or self.psf.shape[1] % 2 == 0 or self.psf.sum() <= 0):
            raise ValueError(f"psf: expected an odd-sized 2-D kernel with a positive sum, "
                             f"got {self.psf.shape}")
        if int(background) not in (0, 1, 2):
            raise ValueError(f"background: expected a polynomial order 0, 1 or 2, got {background!r}")
        self.background = int(background)
        self.timer = CostTimer()
        rois, masks = fluoro_rois(renderer, frame, views=self.views, roi=self.roi)
        self.fluoro_rois = tuple(rois)
        self.others = [None] * len(self.views)
        if others is not None and len(others[1]):
            poses_o = np.asarray(others[0], dtype=float)
            batch = renderer.render(poses_o[None], views=self.views, bones=list(others[1]), roi=self._roi_arg)
            bg = batch.numpy()[0].sum(axis=1)
            self.others = [np.ascontiguousarray(bg[i, : r.shape[0], : r.shape[1]])
                           for i, r in enumerate(rois)]
        if dilate is not None:
            base = self._render(np.zeros((1, 6)))
            masks = [m & (ndimage.binary_dilation(d[0] > 0, iterations=int(dilate)) if dilate else d[0] > 0)
                     for m, d in zip(masks, base, strict=True)]
        self.weights = tuple(expected_counts(r, sigma_px=weight_sigma_px, mask=m)
                             for r, m in zip(rois, masks, strict=True))
        if not others_gain:  # the neighbours' DRRs subtracted as they are (gain 1), not fitted
            self.fluoro_rois = tuple(r if o is None else r - o
                                     for r, o in zip(self.fluoro_rois, self.others, strict=True))
            self.others = [None] * len(self.views)
        self.highpass_px = None if not highpass_px else float(highpass_px)
        if self.highpass_px:
            self.fluoro_rois = tuple(highpass(r, self.highpass_px) for r in self.fluoro_rois)

    poses = RegistrationCost.poses
    params = RegistrationCost.params

    def _render(self, X) -> list[np.ndarray]:
        P = self.poses(X)
        batch = self.renderer.render(P[:, None], views=self.views, bones=[self.bone], roi=self._roi_arg)
        img = batch.numpy()[:, :, 0]
        return [img[:, i, : r.shape[0], : r.shape[1]] for i, r in enumerate(self.fluoro_rois)]

    def __call__(self, X) -> np.ndarray:
        """``(B,)`` χ²/2 of each parameter row (mm, degrees)."""
        from ..similarity.likelihood import wls_chi2

        t0 = time.perf_counter()
        X = np.atleast_2d(np.asarray(X, dtype=float))
        D = self._render(X)
        t1 = time.perf_counter()
        c = 0.5 * wls_chi2(D, self.fluoro_rois, self.weights, others=self.others, psf=self.psf,
                           background=self.background, highpass_px=self.highpass_px)
        t2 = time.perf_counter()
        self.timer.render += t1 - t0
        self.timer.metric += t2 - t1
        self.timer.calls += 1
        self.timer.evaluations += len(X)
        return np.where(np.isfinite(c), c, np.inf)

    def refine(self, x0=None, *, iters: int = 4, step=(0.05, 0.05), tol=(1e-3, 1e-3)) -> dict:
        """Gauss–Newton minimisation of the cost from ``x0`` (default the base pose): each
        iteration renders the pose and its 12 central-difference neighbours (``step`` mm,
        degrees) in one launch and solves the variable-projection normal equations summed over
        views (:func:`core.similarity.likelihood.wls_gauss_newton_step`); stops when a step is
        below ``tol`` or the cost stops falling. Returns ``{"x", "cost", "iterations",
        "covariance"}``: ``covariance`` is ``s² (JᵀJ)⁻¹`` (mm², deg²) with ``s²`` the residual
        variance per weight unit (``χ²/dof``), the curvature's confidence of the estimate (it
        treats pixels as independent: blurred frames' correlated noise makes it too small)."""
        if any(o is not None for o in self.others):
            raise ValueError("refine: fits the bone's gain only; build the cost with others_gain=False "
                             "(the neighbours' DRRs subtracted at gain 1)")
        x = np.zeros(6) if x0 is None else np.asarray(x0, float).copy()
        x, best, n_it = self._gauss_newton(x, self.weights, iters, step, tol)
        _, chi2, JJ, dof = best
        cov = (chi2 / max(dof, 1)) * np.linalg.inv(JJ)
        self.timer.calls += n_it
        self.timer.evaluations += 13 * n_it
        return {"x": x, "cost": 0.5 * chi2, "iterations": n_it, "covariance": cov}

    def _gauss_newton(self, x, weights, iters, step, tol):
        from ..similarity.likelihood import blur, highpass, wls_gauss_newton_step

        hv = np.array([step[0]] * 3 + [step[1]] * 3)
        X = np.concatenate([np.zeros((1, 6)), np.diag(hv), -np.diag(hv)])
        best = None
        n_it = 0
        for it in range(1, int(iters) + 1):
            n_it = it
            D = self._render(x + X)
            JJ, Jr, chi2, dof = np.zeros((6, 6)), np.zeros(6), 0.0, 0
            for v, Dv in enumerate(D):
                Dv = Dv.astype(np.float32)
                if self.psf is not None:
                    Dv = blur(Dv, self.psf)
                if self.highpass_px:
                    Dv = highpass(Dv, self.highpass_px)
                dD = (Dv[1:7] - Dv[7:13]) / (2 * hv[:, None, None])
                a, b, c, d = wls_gauss_newton_step(Dv[0], dD, self.fluoro_rois[v], weights[v],
                                                   background=self.background)
                JJ, Jr, chi2, dof = JJ + a, Jr + b, chi2 + c, dof + d
            if best is not None and chi2 > best[1]:  # the last step went uphill: keep the previous pose
                x = best[0]
                break
            best = (x.copy(), chi2, JJ, dof)
            delta = -np.linalg.solve(JJ, Jr)
            x = x + delta
            if np.all(np.abs(delta) < np.asarray([tol[0]] * 3 + [tol[1]] * 3)):
                break
        return x, best, n_it
