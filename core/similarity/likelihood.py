"""Weighted least squares on the line-integral image: a likelihood-like cost (numpy reference).

What the photons say (the physics behind :mod:`core.tracking.bound`): a flatfield-corrected
fluoroscope pixel holds the relative fluence ``F = n / N`` of ``n ~ Poisson(N e^{-L})`` quanta, so
its line integral ``y = -ln F`` has variance ``≈ 1 / (N F)``. To first order the log-likelihood of
a pose is therefore a weighted sum of squares of ``y`` minus its model, weighted by the expected
counts (``∝ F``). The model of one view's region is

    y ≈ a · (k ∗ D_θ) + a_o · (k ∗ D_others) + c₀ + c_u u + c_v v       (+ quadratic terms)

``D_θ`` the bone's DRR at pose ``θ``, ``D_others`` the other bones' DRRs at their (fixed) poses,
``k`` an optional point spread function *estimated from calibration images* (e.g.
:func:`core.imaging.psf.psf_from_pinholes`; never the synthetic generator's kernel), and the gain
``a``, the neighbours' gain ``a_o`` and the smooth background (a plane, or a quadratic with
``background=2``) fitted linearly for every pose (variable projection): soft tissue, glare,
roll-off and the HU → μ scale need not be known. :func:`wls_chi2` returns ``χ²`` per pose (the sum
over views of the weighted residual after that linear fit): half of it is the negative
log-likelihood up to a constant, so ``χ²/2``'s Hessian in the pose is the Fisher information when
the weights are the inverse noise variances.

The weights: :func:`expected_counts` — the fluoroscope's relative fluence, smoothed to take the
noise out of the weights (the noise of ``F`` must not weight its own pixel), times a constant that
does not move the optimum.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

__all__ = ["expected_counts", "wls_chi2", "wls_fit"]


def expected_counts(line_integral, *, sigma_px: float = 2.0, mask=None) -> np.ndarray:
    """Weights ``∝`` the expected counts of each pixel: ``exp(-y)`` of the line-integral image
    smoothed by a Gaussian of ``sigma_px`` (0 where ``mask`` is False)."""
    y = np.asarray(line_integral, dtype=np.float64)
    if y.ndim != 2:
        raise ValueError(f"line_integral: expected a 2-D image, got shape {y.shape}")
    ys = ndimage.gaussian_filter(y, float(sigma_px), mode="nearest") if sigma_px > 0 else y
    w = np.exp(-ys)
    if mask is not None:
        w = np.where(np.asarray(mask, bool), w, 0.0)
    return w


def _background(shape, order: int) -> np.ndarray:
    """``(n_terms, h, w)`` background regressors: 1, u, v (and u², uv, v² for order 2), scaled
    to [-1, 1] over the region."""
    h, w = shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    u = 2 * u / max(w - 1, 1) - 1
    v = 2 * v / max(h - 1, 1) - 1
    terms = [np.ones_like(u)]
    if order >= 1:
        terms += [u, v]
    if order >= 2:
        terms += [u * u, u * v, v * v]
    return np.stack(terms)


def blur(images, psf) -> np.ndarray:
    """Convolve each ``(…, h, w)`` image with ``psf`` (normalised; borders replicate)."""
    import cv2

    a = np.asarray(images, dtype=np.float32)
    k = np.asarray(psf, dtype=np.float32)
    k = k / k.sum()
    flat = a.reshape(-1, *a.shape[-2:])
    out = np.empty_like(flat)
    for i, im in enumerate(flat):
        out[i] = cv2.filter2D(im, -1, k[::-1, ::-1], borderType=cv2.BORDER_REPLICATE)
    return out.reshape(a.shape)


def wls_fit(drr, fluoro, weights, *, others=None, background: int = 1):
    """Weighted linear fit of one view for a batch of DRRs.

    Parameters
    ----------
    drr : (B, h, w) array
        The bone's DRRs (already blurred by a PSF when one is used).
    fluoro : (h, w) array
        The fluoroscope region in DRR polarity (line integrals).
    weights : (h, w) array
        Per-pixel weights (:func:`expected_counts`; 0 = unused pixel).
    others : (h, w) array, optional
        The other bones' DRR sum (fixed), a regressor with its own gain.
    background : int
        Order of the background polynomial (0 constant, 1 plane, 2 quadratic).

    Returns
    -------
    chi2 : (B,) float64
        Weighted residual sum of squares after the fit.
    coef : (B, p) float64
        ``(a, [a_o], background…)`` of each DRR.
    """
    D = np.asarray(drr, dtype=np.float64)
    if D.ndim == 2:
        D = D[None]
    y = np.asarray(fluoro, dtype=np.float64)
    W = np.asarray(weights, dtype=np.float64)
    if D.shape[1:] != y.shape or W.shape != y.shape:
        raise ValueError(f"drr, fluoro, weights: expected (B, h, w), (h, w), (h, w); got {D.shape}, "
                         f"{y.shape}, {W.shape}")
    sel = W.ravel() > 0
    if not sel.any():
        raise ValueError("weights: no pixel with a positive weight")
    w = W.ravel()[sel]
    fixed = [_background(y.shape, int(background)).reshape(-1, y.size)[:, sel]]
    if others is not None:
        fixed.insert(0, np.asarray(others, np.float64).ravel()[sel][None])
    F = np.concatenate(fixed)  # (q, n): regressors shared by every pose
    yv = y.ravel()[sel]
    Dv = D.reshape(len(D), -1)[:, sel]  # (B, n)
    # normal equations, blocks: [d·d, d·F; F·d, F·F] with weights
    Fw = F * w
    FF = Fw @ F.T  # (q, q)
    Fy = Fw @ yv  # (q,)
    dw = Dv * w
    dd = np.einsum("bn,bn->b", dw, Dv)
    dF = dw @ F.T  # (B, q)
    dy = dw @ yv  # (B,)
    yy = float(yv @ (w * yv))
    q = F.shape[0]
    A = np.empty((len(D), q + 1, q + 1))
    A[:, 0, 0] = dd
    A[:, 0, 1:] = dF
    A[:, 1:, 0] = dF
    A[:, 1:, 1:] = FF
    r = np.concatenate([dy[:, None], np.broadcast_to(Fy, (len(D), q))], axis=1)
    coef = np.linalg.solve(A, r[..., None])[..., 0]
    chi2 = yy - np.einsum("bp,bp->b", coef, r)
    return np.maximum(chi2, 0.0), coef


def highpass(images, sigma_px: float) -> np.ndarray:
    """``image - G_σ ∗ image`` for each ``(…, h, w)`` image (borders replicate): what is left
    after a smooth background of scale ``sigma_px`` is taken out."""
    import cv2

    a = np.asarray(images, dtype=np.float32)
    flat = a.reshape(-1, *a.shape[-2:])
    out = np.empty_like(flat)
    for i, im in enumerate(flat):
        out[i] = im - cv2.GaussianBlur(im, (0, 0), float(sigma_px), borderType=cv2.BORDER_REPLICATE)
    return out.reshape(a.shape)


def wls_chi2(drrs, fluoros, weights, *, others=None, psf=None, background: int = 1,
             highpass_px: float | None = None) -> np.ndarray:
    """``(B,)`` χ² summed over views (module docs).

    ``drrs``: one ``(B, h_v, w_v)`` array per view; ``fluoros``, ``weights``: one ``(h_v, w_v)``
    per view; ``others``: one ``(h_v, w_v)`` or None per view (or None); ``psf``: an odd kernel
    applied to the bone's and the others' DRRs, or None; ``highpass_px``: σ (pixels) of the smooth
    background taken out of the DRRs by :func:`highpass` (the fluoroscope regions must be
    high-passed alike by the caller), or None."""
    nv = len(fluoros)
    if len(drrs) != nv or len(weights) != nv:
        raise ValueError(f"drrs, weights: expected {nv} views like fluoros")
    oth = [None] * nv if others is None else list(others)
    total = None
    for v in range(nv):
        D = np.asarray(drrs[v], np.float32)
        o = oth[v]
        if psf is not None:
            D = blur(D, psf)
            o = None if o is None else blur(o, psf)
        if highpass_px:
            D = highpass(D, highpass_px)
            o = None if o is None else highpass(o, highpass_px)
        c, _ = wls_fit(D, fluoros[v], weights[v], others=o, background=background)
        total = c if total is None else total + c
    return total


def wls_gauss_newton_step(drr0, ddrr, fluoro, weights, *, background: int = 0):
    """One Gauss–Newton step of one view's weighted fit, by variable projection.

    ``drr0 (h, w)``: the bone's DRR at the current pose; ``ddrr (6, h, w)``: its derivatives in
    the 6 pose parameters; the model ``a · drr + background`` (gain and polynomial fitted
    linearly). Returns ``(JᵀJ (6, 6), Jᵀr (6,), χ² float, dof int)`` of the weighted residual ``r``
    at the current pose, its Jacobian ``J`` taken with the linear parameters projected out
    (Golub–Pereyra, gain held in the derivative): summed over views, ``δ = -(JᵀJ)⁻¹ Jᵀr``."""
    y = np.asarray(fluoro, np.float64)
    W = np.asarray(weights, np.float64)
    sel = W.ravel() > 0
    sw = np.sqrt(W.ravel()[sel])
    B = _background(y.shape, int(background)).reshape(-1, y.size)[:, sel]
    d0 = np.asarray(drr0, np.float64).ravel()[sel]
    A = np.concatenate([d0[None], B]).T * sw[:, None]  # (n, p) weighted regressors
    yw = y.ravel()[sel] * sw
    Q, _ = np.linalg.qr(A)
    r = yw - Q @ (Q.T @ yw)
    coef = np.linalg.lstsq(A, yw, rcond=None)[0]
    dD = np.asarray(ddrr, np.float64).reshape(6, -1)[:, sel] * sw * coef[0]  # (6, n)
    Jm = -(dD - (dD @ Q) @ Q.T)  # projected: the linear parameters re-fit along every direction
    return Jm @ Jm.T, Jm @ r, float(r @ r), int(sel.sum() - A.shape[1])
