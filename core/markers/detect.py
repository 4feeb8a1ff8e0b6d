"""Detection of bead candidates in a corrected frame, given the expected bead diameter in pixels.

Algorithm (thesis §5.4.2 asks for "threshold + circularity + size"; a scale-space blob detector
does all three without a global threshold that depends on the exposure):

1. **Scale space.** The bead signal (``-image`` for dark beads) is filtered with the
   scale-normalised Laplacian of Gaussian ``-σ² ∇²G_σ`` at seven scales spanning
   ``size_range`` (a disc of radius ``R`` responds most at ``σ = R / sqrt 2``).
2. **Candidates** are maxima over space and scale (3 × 3 × 3) whose response exceeds
   ``min_snr`` times that scale's noise (the robust spread of the response over the image).
3. **Size**: the radius ``sqrt 2 σ*`` at the best scale (parabolic in log σ) must lie within
   ``size_range`` × the expected radius — larger blobs (soft-tissue folds, the large faint
   circles of some phantoms) peak at larger scales and are rejected.
4. **Circularity**: the ratio of the Hessian's eigenvalues at the best scale (1 for a round
   blob, → 0 for ridges such as bone edges or lettering) must be ≥ ``min_circularity``.
5. **Contrast**: background (median of the ring 2r–3r) minus the mean of the central disc
   (r/2), in image units; ``snr`` = contrast / pixel noise (MAD of the image's Laplacian).
   Noise statistics exclude pixels at the image's extreme values (saturated field, black
   collimator), whose zero spread would make any ripple look significant.
6. Overlapping detections keep the stronger; with ``refine`` each survivor is localised by the
   recommended localizer (:func:`core.markers.batch.localize`, search radius one radius) and
   dropped if that fails.

Pixel convention: ``(u, v) = (column, row)``, origin at the centre of the top-left pixel.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from ._windows import extract
from .batch import RECOMMENDED, localize
from .results import STATUS

__all__ = ["BeadDetections", "detect_beads", "field_mask"]


@dataclass(frozen=True, eq=False)
class BeadDetections:
    """Bead candidates of one frame, strongest first.

    Attributes
    ----------
    uv : (N, 2)
        Centres ``(u, v)`` in pixels (sub-pixel when refined).
    sigma : (N, 2)
        Uncertainty of ``uv`` (px; NaN when not refined).
    radius : (N,)
        Radius from the best scale, pixels.
    contrast : (N,)
        Background minus bead centre, image units.
    snr : (N,)
        ``contrast`` over the pixel noise.
    circularity : (N,)
        Hessian eigenvalue ratio in [0, 1] (1 = round).
    quality : (N,)
        ``min(1, snr / (2 min_snr)) × circularity`` in [0, 1].
    """

    uv: np.ndarray
    sigma: np.ndarray
    radius: np.ndarray
    contrast: np.ndarray
    snr: np.ndarray
    circularity: np.ndarray
    quality: np.ndarray

    def __len__(self) -> int:
        return len(self.uv)


def _check(image, diameter_px, size_range, min_snr, min_circularity, polarity) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim != 2 or img.dtype.kind not in "uif" or min(img.shape) < 8:
        raise ValueError(f"image: expected a real 2-D image of at least 8 × 8 pixels, got "
                         f"{img.dtype} array of shape {img.shape}")
    d = float(diameter_px)
    if not (np.isfinite(d) and 2.0 <= d <= 200.0):
        raise ValueError(f"diameter_px: expected a bead diameter of 2–200 px, got {diameter_px!r}")
    lo, hi = (float(x) for x in size_range)
    if not 0 < lo < 1 < hi:
        raise ValueError(f"size_range: expected (lo, hi) with 0 < lo < 1 < hi, got {size_range!r}")
    if not (np.isfinite(min_snr) and min_snr > 0):
        raise ValueError(f"min_snr: expected a positive number, got {min_snr!r}")
    if not 0 <= min_circularity <= 1:
        raise ValueError(f"min_circularity: expected a value in [0, 1], got {min_circularity!r}")
    if polarity not in ("dark", "bright"):
        raise ValueError(f"polarity: expected 'dark' or 'bright', got {polarity!r}")
    return img


def field_mask(image, *, margin_px: int = 40) -> np.ndarray:
    """``(H, W)`` bool: the exposed field (above the image's minimum, e.g. inside the round
    intensifier aperture or the collimator), shrunk by ``margin_px`` pixels so that edge
    lettering and the field's rim are excluded. Pass it as ``mask`` to :func:`detect_beads`."""
    img = np.asarray(image)
    if img.ndim != 2:
        raise ValueError(f"image: expected a 2-D image, got shape {img.shape}")
    if int(margin_px) != margin_px or margin_px < 0:
        raise ValueError(f"margin_px: expected an integer >= 0, got {margin_px!r}")
    lit = np.pad((img > img.min()).astype(np.uint8), 1)
    dist = cv2.distanceTransform(lit, cv2.DIST_L2, 5)[1:-1, 1:-1]
    return dist > margin_px


def _unclipped(img: np.ndarray) -> np.ndarray:
    """Pixels away (2 px) from values clipped at the image's minimum or maximum (saturation,
    collimator): the noise statistics are taken there only."""
    lo, hi = img.min(), img.max()
    # ndimage.binary_erosion's (cross, 2 iterations, outside = False), by OpenCV
    cross = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))
    m = cv2.erode(((img > lo) & (img < hi)).astype(np.uint8), cross, iterations=2,
                  borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)
    return m if m.sum() >= 64 else np.ones(img.shape, bool)


def _log_kernels(sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """The 1-D Gaussian (order 0) and its second derivative (order 2) of
    ``ndimage.gaussian_laplace`` (truncated at 4 σ), as correlation kernels."""
    s2 = float(sigma) ** 2
    x = np.arange(-int(4.0 * float(sigma) + 0.5), int(4.0 * float(sigma) + 0.5) + 1, dtype=np.float64)
    g = np.exp(-0.5 / s2 * x * x)
    g /= g.sum()
    return g.astype(np.float32), ((x * x / s2 - 1.0) / s2 * g).astype(np.float32)


def _neg_log(img32: np.ndarray, sigma: float) -> np.ndarray:
    """``-σ² ∇²G_σ * img`` (edges replicated): ``ndimage.gaussian_laplace(img, σ, mode="nearest")``
    by OpenCV's separable filters (float32, several times faster on large frames)."""
    g0, g2 = _log_kernels(sigma)
    b = cv2.BORDER_REPLICATE
    lap = cv2.sepFilter2D(img32, cv2.CV_32F, g0, g2, borderType=b)  # d²/drow²
    lap += cv2.sepFilter2D(img32, cv2.CV_32F, g2, g0, borderType=b)  # d²/dcol²
    return -(float(sigma) ** 2) * lap


def _plane_max3(z: np.ndarray) -> np.ndarray:
    """The 3 × 3 maximum of each plane of a ``(K, H, W)`` stack (edges replicated)."""
    k3 = np.ones((3, 3), np.uint8)
    return np.stack([cv2.dilate(zk, k3) for zk in z])


def _masked_median(win: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """``np.median(win[i][mask[i]])`` of every window at once (NaN where a mask is empty)."""
    M = len(win)
    flat = np.where(mask, win, np.inf).reshape(M, -1)
    n = mask.reshape(M, -1).sum(axis=1)
    srt = np.sort(flat, axis=1)
    lo = np.take_along_axis(srt, np.maximum((n - 1) // 2, 0)[:, None], axis=1)[:, 0]
    hi = np.take_along_axis(srt, np.maximum(n // 2, 0)[:, None], axis=1)[:, 0]
    with np.errstate(invalid="ignore"):
        return np.where(n > 0, np.where(n % 2 == 1, lo, (lo + hi) / 2), np.nan)


def _hessian_ratio(win: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Eigenvalue ratio of the Gaussian-smoothed Hessian at each window's centre (M,)."""
    S = win.shape[-1]
    off = np.arange(S) - S // 2
    x, y = off[None, None, :], off[None, :, None]
    s2 = sigma[:, None, None] ** 2
    G = np.exp(-(x * x + y * y) / (2 * s2))
    G /= G.sum(axis=(1, 2), keepdims=True)
    hxx = (win * G * (x * x - s2) / (s2 * s2)).sum(axis=(1, 2))
    hyy = (win * G * (y * y - s2) / (s2 * s2)).sum(axis=(1, 2))
    hxy = (win * G * (x * y) / (s2 * s2)).sum(axis=(1, 2))
    tr, det = hxx + hyy, hxx * hyy - hxy * hxy
    disc = np.sqrt(np.maximum(tr * tr / 4 - det, 0.0))
    l1, l2 = tr / 2 - disc, tr / 2 + disc  # l1 <= l2; a bright blob of signal has both < 0
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(l1 < 0, np.clip(l2 / l1, 0.0, 1.0), 0.0)
    return np.where(np.isfinite(ratio), ratio, 0.0)


def detect_beads(image, *, diameter_px: float, polarity: str = "dark", min_snr: float = 6.0,
                 size_range=(0.6, 1.6), min_circularity: float = 0.5, mask=None,
                 refine: bool = True, max_beads: int | None = None) -> BeadDetections:
    """Find round beads of about ``diameter_px`` pixels in a corrected image.

    Parameters
    ----------
    image : (H, W) array
        Flatfield-corrected (or raw) image; beads darker than their surroundings unless
        ``polarity="bright"``.
    diameter_px : float
        Expected projected bead diameter in pixels.
    polarity : {"dark", "bright"}
    min_snr : float
        Minimum scale-space response over its noise and minimum contrast over the pixel noise.
    size_range : (lo, hi)
        Accepted radius as a fraction of the expected radius.
    min_circularity : float
        Minimum Hessian eigenvalue ratio (0–1).
    mask : (H, W) bool array, optional
        Where beads may be (e.g. inside the intensifier's round field).
    refine : bool
        Localise each detection with the recommended localizer (sub-pixel ``uv`` and ``sigma``).
    max_beads : int, optional
        Keep at most this many (highest quality).

    Returns
    -------
    BeadDetections
        Strongest first.
    """
    img = _check(image, diameter_px, size_range, min_snr, min_circularity, polarity)
    sig = (-1.0 if polarity == "dark" else 1.0) * img.astype(np.float64)
    r0 = float(diameter_px) / 2.0
    lo, hi = (float(x) for x in size_range)
    radii = r0 * np.geomspace(lo / 1.3, hi * 1.3, 7)
    sigmas = radii / np.sqrt(2.0)
    sig32 = sig.astype(np.float32)
    resp = np.stack([_neg_log(sig32, s) for s in sigmas])
    valid = _unclipped(img)
    flat = resp.reshape(len(resp), -1)[:, np.flatnonzero(valid)[::7]]
    med = np.median(flat, axis=1)
    noise = 1.4826 * np.median(np.abs(flat - med[:, None]), axis=1)
    noise = np.where(noise > 0, noise, np.finfo(float).tiny)
    z = (resp - med[:, None, None]) / noise[:, None, None]
    # maxima over space and scale (z == ndimage.maximum_filter(z, size=3, mode="nearest")) above
    # min_snr at the inner scales (the best scale is interpolated between its neighbours): the
    # 3 x 3 maximum of each scale, then the neighbouring scales' at the few points left
    zmax = _plane_max3(z)
    peaks = (z[1:-1] == zmax[1:-1]) & (z[1:-1] >= min_snr)
    if mask is not None:
        m = np.asarray(mask, dtype=bool)
        if m.shape != img.shape:
            raise ValueError(f"mask: expected shape {img.shape}, got {m.shape}")
        peaks &= m[None]
    k, rows, cols = np.nonzero(peaks)
    k += 1
    zc = z[k, rows, cols]
    top = (zc >= zmax[k - 1, rows, cols]) & (zc >= zmax[k + 1, rows, cols])
    k, rows, cols = k[top], rows[top], cols[top]
    # parabolic interpolation of the best scale in log σ
    zc, zl, zh = z[k, rows, cols], z[k - 1, rows, cols], z[k + 1, rows, cols]
    den = zl - 2 * zc + zh
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(den < 0, np.clip(0.5 * (zl - zh) / den, -0.5, 0.5), 0.0)
    step = np.log(sigmas[1] / sigmas[0])
    s_best = sigmas[k] * np.exp(t * step)
    radius = np.sqrt(2.0) * s_best
    keep = (radius >= lo * r0) & (radius <= hi * r0)
    rows, cols, radius, s_best, score = rows[keep], cols[keep], radius[keep], s_best[keep], zc[keep]
    empty = BeadDetections(*(np.zeros((0, 2)),) * 2, *(np.zeros(0),) * 5)
    if rows.size == 0:
        return empty
    # contrast, noise and circularity from windows around each candidate
    half = int(np.ceil(3.0 * radius.max())) + 1
    win = extract(sig[None], np.zeros(len(rows), np.int64), np.stack([cols, rows], axis=1), half).data
    off = np.arange(2 * half + 1) - half
    d = np.hypot(off[None, :], off[:, None])[None]
    rr = radius[:, None, None]
    ring = (d >= 2 * rr) & (d <= 3 * rr)
    core = d <= np.maximum(rr / 2, 1.0)
    bg = _masked_median(win, ring)
    centre = (win * core).sum(axis=(1, 2)) / core.sum(axis=(1, 2))
    contrast = centre - bg
    lap = ndimage.laplace(sig)[valid]
    pix_noise = 1.4826 * np.median(np.abs(lap - np.median(lap))) / np.sqrt(20.0)
    snr = contrast / max(pix_noise, np.finfo(float).tiny)
    ok = (snr >= min_snr) & (contrast > 0)
    circ = np.zeros(len(ok))
    circ[ok] = _hessian_ratio(win[ok], s_best[ok])  # only where the contrast passed
    ok &= circ >= min_circularity
    uv = np.stack([cols, rows], axis=1).astype(np.float64)[ok]
    radius, contrast, snr, circ, score = radius[ok], contrast[ok], snr[ok], circ[ok], score[ok]
    # non-maximum suppression: overlapping candidates keep the strongest
    order = np.argsort(-score)
    uv, radius, contrast, snr, circ = uv[order], radius[order], contrast[order], snr[order], circ[order]
    taken = np.ones(len(uv), bool)
    if len(uv) > 1:
        dist = np.linalg.norm(uv[:, None] - uv[None], axis=2)
        overlap = dist < np.maximum(radius[:, None], radius[None])
        for i in range(len(uv)):  # greedy suppression; candidates are few
            if taken[i]:
                taken[i + 1 :] &= ~overlap[i, i + 1 :]
    uv, radius, contrast, snr, circ = uv[taken], radius[taken], contrast[taken], snr[taken], circ[taken]
    sigma = np.full_like(uv, np.nan)
    if refine and len(uv):
        loc = localize(img, uv, diameter_px=2.0 * radius, method=RECOMMENDED, polarity=polarity,
                       search_radius=float(np.median(radius)), min_snr=3.0)
        # a "flat" refinement means no bead there: drop it; other failures (a neighbouring
        # bead inside the fitted patch) keep the scale-space position without an uncertainty
        good = loc.status != STATUS["flat"]
        uv = np.where(loc.ok[:, None], loc.uv, uv)[good]
        sigma = loc.sigma[good]
        radius, contrast, snr, circ = radius[good], contrast[good], snr[good], circ[good]
    quality = np.clip(snr / (2.0 * min_snr), 0.0, 1.0) * circ
    order = np.argsort(-quality, kind="stable")
    if max_beads is not None:
        order = order[: int(max_beads)]
    return BeadDetections(uv[order], sigma[order], radius[order], contrast[order], snr[order],
                          circ[order], quality[order])
