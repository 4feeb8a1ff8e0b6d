"""Richardson–Lucy deconvolution, global and spatially varying (thesis §3.4.3).

Richardson–Lucy (Richardson 1972, Lucy 1974) is the maximum-likelihood deconvolution for
Poisson data: starting from the blurred image ``B``, each iteration multiplies the estimate by
the back-projected ratio ``B / (h * x)``: ``x ← x · (h̃ * (B / (h * x)))`` (``h̃`` the flipped
PSF). More iterations sharpen more and amplify noise more (thesis Fig. 3.9).

Damping (White 1994; MATLAB ``deconvlucy``'s DAMPAR): where the data and the re-blurred estimate
already agree within ``damping`` standard deviations of the Poisson noise, the update is
suppressed, so flat, noisy regions stop being "sharpened" while edges still are. The noise is
Poisson in detected quanta, so damping needs ``photons_per_unit`` — the quanta that make an image
value of 1 (for flatfielded frames: the quanta per pixel at full fluence).

Images are float (e.g. flatfielded I/I0 in [0, 1]); convolutions are OpenCV ``filter2D`` with
reflecting borders (no wrap-around). :func:`richardson_lucy_varying` deconvolves overlapping
tiles around the nodes of a :class:`~core.imaging.psf.PSFGrid`, each with its own kernel, and
blends them with the grid's piecewise-linear weights (a partition of unity).
"""

from __future__ import annotations

import cv2
import numpy as np

from .._validate import as_float_array, positive
from .psf import PSFGrid, normalise_psf

__all__ = ["richardson_lucy", "richardson_lucy_varying"]


def _check(iterations, damping, photons_per_unit) -> tuple[int, float, float | None]:
    if int(iterations) != iterations or iterations < 0:
        raise ValueError(f"iterations: expected an integer >= 0, got {iterations!r}")
    if not (np.isfinite(damping) and damping >= 0):
        raise ValueError(f"damping: expected a threshold >= 0 in noise σ, got {damping!r}")
    n = None
    if damping > 0:
        if photons_per_unit is None:
            raise ValueError("photons_per_unit: needed with damping > 0 (Poisson noise in quanta per "
                             "image unit, e.g. the quanta per pixel at full fluence)")
        n = positive(photons_per_unit, "photons_per_unit")
    return int(iterations), float(damping), n


def richardson_lucy(image, psf, *, iterations: int = 10, damping: float = 0.0,
                    photons_per_unit: float | None = None, clip: tuple[float, float] | None = (0.0, 1.0),
                    eps: float = 1e-6) -> np.ndarray:
    """Richardson–Lucy deconvolution of a 2-D image (float32 result).

    Parameters
    ----------
    image : (H, W) array_like
        Blurred image, non-negative (negative values are clipped to 0).
    psf : (k, k) array_like
        Point spread function, odd-sized (normalised to unit sum here).
    iterations : int
        RL iterations (0 returns the input).
    damping : float
        Damping threshold in Poisson noise σ (0 = undamped; MATLAB's DAMPAR).
    photons_per_unit : float, optional
        Quanta per unit image value; needed when ``damping > 0``.
    clip : (low, high) or None
        Clip the result to this range (default [0, 1], for flatfielded frames).
    eps : float
        Floor of the re-blurred estimate in the ratio.
    """
    it, damp, n = _check(iterations, damping, photons_per_unit)
    b = np.clip(as_float_array(image, "image", ndim=2, dtype=np.float32), 0.0, None)
    k = normalise_psf(psf).astype(np.float32)
    kf = k[::-1, ::-1].copy()
    x = b.copy()
    gm = 10.0
    for _ in range(it):
        # filter2D correlates: correlating with the flipped kernel convolves
        re = np.maximum(cv2.filter2D(x, -1, kf, borderType=cv2.BORDER_REFLECT), eps)
        ratio = b / re
        if damp > 0:
            with np.errstate(divide="ignore", invalid="ignore"):
                w = b * n
                r = re * n
                dev = np.where(w > 0, w * np.log(w / r), 0.0) + r - w
            g = np.minimum(2.0 * dev / (damp * damp), 1.0)
            g = g ** (gm - 1) * (gm - (gm - 1) * g)
            ratio = 1.0 + g * (ratio - 1.0)
        x = x * cv2.filter2D(ratio.astype(np.float32), -1, k, borderType=cv2.BORDER_REFLECT)
    if clip is not None:
        x = np.clip(x, float(clip[0]), float(clip[1]))
    return x.astype(np.float32, copy=False)


def richardson_lucy_varying(image, grid: PSFGrid, *, iterations: int = 10, damping: float = 0.0,
                            photons_per_unit: float | None = None,
                            clip: tuple[float, float] | None = (0.0, 1.0),
                            margin_px: int | None = None) -> np.ndarray:
    """Spatially varying Richardson–Lucy: tiles around the grid nodes, blended.

    Each node's tile spans the cells next to it (where its weight is non-zero) plus
    ``margin_px`` (default three kernel widths) so tile borders do not reach the blended part;
    it is deconvolved with the node's kernel and added with the node's weight. Options as in
    :func:`richardson_lucy`.
    """
    if not isinstance(grid, PSFGrid):
        raise ValueError(f"grid: expected a PSFGrid, got {type(grid).__name__}")
    img = as_float_array(image, "image", ndim=2, dtype=np.float32)
    _check(iterations, damping, photons_per_unit)
    H, W = img.shape
    wv, wu = grid.weights((H, W))
    m = 3 * grid.kernels.shape[-1] if margin_px is None else int(margin_px)
    out = np.zeros((H, W), np.float32)
    for a in range(grid.centers_v.size):
        rows = np.flatnonzero(wv[a] > 0)
        if rows.size == 0:
            continue
        for b in range(grid.centers_u.size):
            cols = np.flatnonzero(wu[b] > 0)
            if cols.size == 0:
                continue
            v0, v1 = max(rows[0] - m, 0), min(rows[-1] + 1 + m, H)
            u0, u1 = max(cols[0] - m, 0), min(cols[-1] + 1 + m, W)
            tile = richardson_lucy(img[v0:v1, u0:u1], grid.kernels[a, b], iterations=iterations,
                                   damping=damping, photons_per_unit=photons_per_unit, clip=clip)
            wt = np.outer(wv[a, v0:v1], wu[b, u0:u1]).astype(np.float32)
            out[v0:v1, u0:u1] += wt * tile
    return out
