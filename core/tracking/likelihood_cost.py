"""A likelihood-like cost of one bone in one frame, for an opt-in final refinement.

:class:`LikelihoodCost` scores poses by the weighted least-squares χ² of the bone's DRRs against
the fluoroscope's line integrals (:mod:`core.similarity.likelihood`), with the same parameters as
:class:`core.tracking.cost.RegistrationCost`; :meth:`LikelihoodCost.refine` minimises it by
Gauss–Newton steps. What it was measured to gain and why: :mod:`core.studies.tracking.bound_gap`,
:mod:`core.studies.tracking.ml_cost`. The same refinement on the device, the registrations' opt-in
final stage: :mod:`core.tracking.engine_likelihood`, :mod:`core.tracking.final_stage`.

Backgrounds beyond the plane and quadratic of the numpy reference (``basis="legendre"`` or
``"bspline"``, :func:`background_basis`) and extra fixed regressors (``regressors``, e.g. a
soft-tissue DRR) take a general path: the weighted background is orthonormalised once per set of
weights and the DRR, its derivatives and the line integrals are projected off it, then the gain
as before. Whether such a background can replace the stage's high-pass:
:mod:`core.studies.tracking.background_fit` (it cannot: the soft-tissue envelope varies on the
bone's own scale within the region).
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np

from .cost import CostTimer, FrameImages, RegistrationCost, fluoro_rois

__all__ = ["BASES", "LikelihoodCost", "background_basis"]

#: the smooth background's bases (:func:`background_basis`)
BASES = ("monomial", "legendre", "bspline")


def background_basis(shape, order: int, basis: str = "monomial") -> np.ndarray:
    """``(n_terms, h, w)`` regressors of a smooth background over a region of ``shape``, the
    coordinates scaled to [-1, 1]: ``"monomial"`` — 1, u, v (and u², uv, v² for order 2: the
    numpy reference's, :mod:`core.similarity.likelihood`); ``"legendre"`` — the products
    ``P_i(u) P_j(v)`` of Legendre polynomials with ``i + j <= order`` (``(order+1)(order+2)/2``
    terms, well conditioned at high orders); ``"bspline"`` — the tensor products of cubic
    B-splines on ``order`` equal intervals per axis (``(order+3)²`` terms, a partition of unity)."""
    h, w = (int(x) for x in shape)
    order = int(order)
    if basis == "monomial":
        from ..similarity.likelihood import _background

        return _background((h, w), order)
    v, u = np.linspace(-1, 1, h), np.linspace(-1, 1, w)
    if basis == "legendre":
        from numpy.polynomial import legendre

        Pu = np.stack([legendre.legval(u, np.eye(order + 1)[i]) for i in range(order + 1)])
        Pv = np.stack([legendre.legval(v, np.eye(order + 1)[i]) for i in range(order + 1)])
        return np.stack([Pv[j][:, None] * Pu[i][None, :] for i in range(order + 1)
                         for j in range(order + 1 - i)])
    if basis == "bspline":
        Bu, Bv = _bspline_1d(u, order), _bspline_1d(v, order)
        return np.einsum("jy,ix->ijyx", Bv, Bu).reshape(-1, h, w)
    raise ValueError(f"basis: expected one of {BASES}, got {basis!r}")


def _bspline_1d(x: np.ndarray, n: int) -> np.ndarray:
    """``(n + 3, len(x))`` cubic B-splines on ``n`` equal intervals of [-1, 1] at ``x``."""
    t = (np.asarray(x, float) + 1) / 2 * n  # knot units, 0 … n
    out = np.zeros((n + 3, len(t)))
    for k in range(n + 3):  # spline k centred on knot k - 1
        d = np.abs(t - (k - 1))
        out[k] = np.where(d < 1, (4 - 6 * d**2 + 3 * d**3) / 6, np.where(d < 2, (2 - d) ** 3 / 6, 0.0))
    return out


def _step_general(drr0, ddrr, fluoro, weights, R, Qb=None):
    """:func:`core.similarity.likelihood.wls_gauss_newton_step` with any fixed background
    regressors ``R (q, h, w)``; also returns the weighted residual image ``√w r`` (0 where unused).
    ``Qb``: an orthonormal basis of the weighted regressors over the used pixels (:func:`_basis_q`;
    made here when None)."""
    y = np.asarray(fluoro, np.float64)
    W = np.asarray(weights, np.float64)
    sel = W.ravel() > 0
    sw = np.sqrt(W.ravel()[sel])
    if Qb is None:
        Qb = _basis_q(R, W)

    def off(a):  # the part of a (…, n) orthogonal to the background
        return a - (a @ Qb) @ Qb.T

    d0 = off(np.asarray(drr0, np.float64).ravel()[sel] * sw)
    yw = off(y.ravel()[sel] * sw)
    dd = float(d0 @ d0)
    gain = float(d0 @ yw) / dd
    q0 = d0 / np.sqrt(dd)
    r = yw - q0 * float(q0 @ yw)
    dD = off(np.asarray(ddrr, np.float64).reshape(6, -1)[:, sel] * sw) * gain  # (6, n)
    Jm = -(dD - np.outer(dD @ q0, q0))  # projected: the linear parameters re-fit along every direction
    e = np.zeros(y.size)
    e[sel] = r
    return Jm @ Jm.T, Jm @ r, float(r @ r), int(sel.sum() - Qb.shape[1] - 1), e.reshape(y.shape)


def _basis_q(R, weights) -> np.ndarray:
    """``(n, q')`` orthonormal basis of the regressors ``R (q, h, w)`` times ``√w`` over the pixels
    with a positive weight (directions the region cannot tell apart dropped)."""
    W = np.asarray(weights, np.float64).ravel()
    sel = W > 0
    B = (np.asarray(R, np.float64).reshape(len(R), -1)[:, sel] * np.sqrt(W[sel])).T
    Q, T = np.linalg.qr(B)
    d = np.abs(np.diag(T))
    return Q[:, d > 1e-9 * max(d.max(), 1e-300)]


class LikelihoodCost:
    """``cost(X (B, 6)) -> (B,)``: half the weighted least-squares χ² of the bone's DRRs against
    the fluoroscope's line integrals (:mod:`core.similarity.likelihood`), for one bone in one
    frame at full resolution — a likelihood-like cost for a final refinement, opt-in.

    Per view, the model of the search region is the bone's DRR (blurred by ``psf`` when given)
    times a gain, plus the other bones' DRRs (``others``, at fixed poses, blurred alike) times
    their own gain, plus a smooth background (``background``: polynomial order, or intervals per
    axis of a B-spline; ``basis``: :func:`background_basis`; ``regressors``: per view more fixed
    images over the region, e.g. a soft-tissue DRR, each with its own coefficient: given as the
    frame shows them, high-passed by ``highpass_px`` like the frame but not blurred by ``psf``), all
    fitted linearly at every pose;
    pixels weigh by their expected counts (the smoothed relative fluence) over the usable pixels
    of the region — or, with ``dilate`` (pixels), only over the bone's footprint at the base pose
    grown by that much. ``psf`` must come from calibration images (e.g.
    :func:`core.imaging.psf.psf_from_pinholes`), never from a generator's truth.

    Same mapping of parameters as :class:`RegistrationCost` (:meth:`poses`, :meth:`params`).
    Larger = worse; the value is not bounded (χ²/2, not 1 - score).
    """

    def __init__(self, renderer, frame: FrameImages, *, bone: int, base_pose, center, roi,
                 views: Sequence[int] | None = None, others=None, psf=None, background: int = 1,
                 dilate: int | None = None, weight_sigma_px: float = 2.0, highpass_px: float | None = None,
                 others_gain: bool = True, basis: str = "monomial", regressors=None) -> None:
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
        if basis not in BASES:
            raise ValueError(f"basis: expected one of {BASES}, got {basis!r}")
        if basis == "monomial" and int(background) not in (0, 1, 2):
            raise ValueError(f"background: expected a polynomial order 0, 1 or 2, got {background!r}")
        if basis != "monomial" and not 0 <= int(background) <= 32:
            raise ValueError(f"background: expected an order (intervals) 0 to 32, got {background!r}")
        if basis == "bspline" and int(background) < 1:
            raise ValueError(f"background: a B-spline needs at least 1 interval, got {background!r}")
        self.background = int(background)
        self.basis = basis
        #: per view, extra fixed regressors ``(k, h, w)`` over the region (or None)
        self.regressors = None if regressors is None else [
            None if r is None else np.asarray(r, np.float64).reshape(-1, *np.shape(r)[-2:])
            for r in regressors]
        self._general = basis != "monomial" or self.regressors is not None
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
        if not others_gain:  # the neighbours' DRRs subtracted at gain 1 (blurred by psf alike), not fitted
            from ..similarity.likelihood import blur

            self.fluoro_rois = tuple(r if o is None else r - (o if self.psf is None else blur(o, self.psf))
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
        if not self._general:
            c = 0.5 * wls_chi2(D, self.fluoro_rois, self.weights, others=self.others, psf=self.psf,
                               background=self.background, highpass_px=self.highpass_px)
        else:
            c = 0.5 * self._chi2_general(D)
        t2 = time.perf_counter()
        self.timer.render += t1 - t0
        self.timer.metric += t2 - t1
        self.timer.calls += 1
        self.timer.evaluations += len(X)
        return np.where(np.isfinite(c), c, np.inf)

    def _regressors(self, v: int) -> np.ndarray:
        """View ``v``'s fixed background regressors ``(q, h, w)`` (made once)."""
        cache = self.__dict__.setdefault("_basis_cache", {})
        if v not in cache:
            R = background_basis(self.fluoro_rois[v].shape, self.background, self.basis)
            extra = None if self.regressors is None else self.regressors[v]
            if extra is not None and self.highpass_px:  # high-passed as the frame is (not blurred)
                from ..similarity.likelihood import highpass

                extra = highpass(extra, self.highpass_px).astype(np.float64)
            if extra is not None:
                if extra.shape[1:] != R.shape[1:]:
                    raise ValueError(f"regressors: view {v} expected (k, {R.shape[1]}, {R.shape[2]}), "
                                     f"got {extra.shape}")
                R = np.concatenate([R, extra])
            cache[v] = R
        return cache[v]

    def _q(self, v: int, w) -> np.ndarray:
        """:func:`_basis_q` of view ``v``'s regressors under the weights ``w`` (the last one kept)."""
        cache = self.__dict__.setdefault("_q_cache", {})
        if v not in cache or cache[v][0] is not w:
            cache[v] = (w, _basis_q(self._regressors(v), w))
        return cache[v][1]

    def _filtered(self, img, *, cast: bool = True) -> np.ndarray:
        """``img`` as the model sees it: float32 (``cast``), blurred by :attr:`psf` and high-passed
        by :attr:`highpass_px` where set."""
        from ..similarity.likelihood import blur, highpass

        if cast:
            img = np.asarray(img, np.float32)
        if self.psf is not None:
            img = blur(img, self.psf)
        if self.highpass_px:
            img = highpass(img, self.highpass_px)
        return img

    def _chi2_general(self, D) -> np.ndarray:
        """χ² of each pose with the background of :attr:`basis` (the neighbours a regressor)."""
        total = 0.0
        for v, Dv in enumerate(D):
            Dv, o = self._filtered(Dv), self.others[v]
            o = None if o is None else self._filtered(o, cast=False)
            W = self.weights[v].ravel()
            sel = W > 0
            sw = np.sqrt(W[sel])
            R = self._regressors(v).reshape(-1, W.size)
            if o is not None:
                R = np.concatenate([np.asarray(o, np.float64).reshape(1, -1), R])
            F = (R[:, sel] * sw).T
            yw = np.asarray(self.fluoro_rois[v], np.float64).ravel()[sel] * sw
            c = np.empty(len(Dv))
            for i, d in enumerate(Dv):
                A = np.column_stack([np.asarray(d, np.float64).ravel()[sel] * sw, F])
                r = yw - A @ np.linalg.lstsq(A, yw, rcond=None)[0]
                c[i] = r @ r
            total = total + c
        return np.asarray(total, float)

    def refine(self, x0=None, *, iters: int = 4, step=(0.05, 0.05), tol=(1e-3, 1e-3),
               robust: float | None = None, robust_sigma_px: float = 2.0,
               robust_kind: str = "cauchy") -> dict:
        """Gauss–Newton minimisation of the cost from ``x0`` (default the base pose): each
        iteration renders the pose and its 12 central-difference neighbours (``step`` mm,
        degrees) in one launch and solves the variable-projection normal equations summed over
        views (:func:`core.similarity.likelihood.wls_gauss_newton_step`); stops when a step is
        below ``tol`` or the cost stops falling. Returns ``{"x", "cost", "iterations",
        "covariance"}``: ``covariance`` is ``s² (JᵀJ)⁻¹`` (mm², deg²) with ``s²`` the residual
        variance per weight unit (``χ²/dof``), the curvature's confidence of the estimate (it
        treats pixels as independent: blurred frames' correlated noise makes it too small).

        ``robust``: then each pixel's weight is multiplied by the device stage's robust factor of
        the residual at that pose (:func:`core.tracking.final_stage.robust_factors`: threshold
        ``robust``, window ``robust_sigma_px``, ``robust_kind``) and the pose refined again from
        there; the result is the second refinement's, with ``"first"`` the first's pose."""
        if any(o is not None for o in self.others):
            raise ValueError("refine: fits the bone's gain only; build the cost with others_gain=False "
                             "(the neighbours' DRRs subtracted at gain 1)")
        x = np.zeros(6) if x0 is None else np.asarray(x0, float).copy()
        x, best, n_it = self._gauss_newton(x, self.weights, iters, step, tol)
        first = x.copy()
        if robust is not None:
            from .final_stage import robust_factors

            e = self.residual(x)
            used = np.zeros(e.shape, bool)
            for v, w in enumerate(self.weights):
                used[v, : w.shape[0], : w.shape[1]] = w > 0
            f = robust_factors(e, used, float(robust), sigma_px=robust_sigma_px, kind=robust_kind)
            wr = [w * f[v, : w.shape[0], : w.shape[1]] for v, w in enumerate(self.weights)]
            x, best, n2 = self._gauss_newton(x, wr, iters, step, tol)
            n_it += n2
        _, chi2, JJ, dof = best
        cov = (chi2 / max(dof, 1)) * np.linalg.inv(JJ)
        self.timer.calls += n_it
        self.timer.evaluations += 13 * n_it
        out = {"x": x, "cost": 0.5 * chi2, "iterations": n_it, "covariance": cov}
        if robust is not None:
            out["first"] = first
        return out

    def _gauss_newton(self, x, weights, iters, step, tol):
        from ..similarity.likelihood import wls_gauss_newton_step

        hv = np.array([step[0]] * 3 + [step[1]] * 3)
        X = np.concatenate([np.zeros((1, 6)), np.diag(hv), -np.diag(hv)])
        best = None
        n_it = 0
        for it in range(1, int(iters) + 1):
            n_it = it
            D = self._render(x + X)
            JJ, Jr, chi2, dof = np.zeros((6, 6)), np.zeros(6), 0.0, 0
            for v, Dv in enumerate(D):
                Dv = self._filtered(Dv)
                dD = (Dv[1:7] - Dv[7:13]) / (2 * hv[:, None, None])
                if not self._general:
                    a, b, c, d = wls_gauss_newton_step(Dv[0], dD, self.fluoro_rois[v], weights[v],
                                                       background=self.background)
                else:
                    a, b, c, d, _ = _step_general(Dv[0], dD, self.fluoro_rois[v], weights[v],
                                                  self._regressors(v), self._q(v, weights[v]))
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

    def residual(self, x, weights=None) -> np.ndarray:
        """``(views, H, W)`` weighted residual images ``√w (y - model)`` at parameters ``x`` after
        the linear fit (zero-padded to the largest region; 0 where a pixel is unused)."""
        weights = self.weights if weights is None else weights
        D = self._render(np.asarray(x, float)[None])
        res = []
        for v, Dv in enumerate(D):
            Dv = self._filtered(Dv)
            res.append(_step_general(Dv[0], np.zeros((6, *Dv.shape[1:])), self.fluoro_rois[v], weights[v],
                                     self._regressors(v), self._q(v, weights[v]))[4])
        out = np.zeros((len(res), max(r.shape[0] for r in res), max(r.shape[1] for r in res)))
        for v, r in enumerate(res):
            out[v, : r.shape[0], : r.shape[1]] = r
        return out
