"""Detection of distortion-grid control points: bright holes or dark beads (thesis §3.5.2).

Method (thesis §3.5.2, with the polarity generalised)
------------------------------------------------------
1. Average the frames (a stack is accepted) and, for dark features (beads), negate the image so
   the features are bright.
2. Morphological **top-hat**: subtract the grey *opening* by a disc larger than the features
   (default 2.5 × their diameter). Features vanish from the opening, the slowly varying
   background (roll-off, plate thickness, the dark rim outside a round field) stays, so the
   difference keeps the features on a flat, near-zero background.
3. Threshold at ``threshold_sigma`` robust noise σ (1.4826 × MAD of the top-hat, per block of
   the image) above its median, label connected regions, and drop **speckles** (area below
   ``min_area_fraction`` of the expected disc), blobs far larger than a feature, and elongated
   or ragged regions (edges, the rim of the field).
4. **Intensity-weighted centroids** of the top-hat (above its median) over each region grown by
   a one-pixel margin, so the blurred rim of a feature counts too.

Polarity
--------
``polarity="auto"`` runs the top-hat both ways and keeps the polarity with the stronger,
more numerous feature responses; ``"bright"``/``"dark"`` force it, and a :class:`ValueError`
says so when the image clearly holds features of the other polarity (e.g. a bead grid passed as
a hole plate). Points are ``(u, v) = (column, row)`` pixels, origin at the centre of the
top-left pixel.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .._validate import as_float_array, positive

__all__ = ["GridPoints", "detect_grid_points", "feature_contrast"]

_POLARITIES = ("auto", "bright", "dark")


@dataclass(frozen=True, eq=False)
class GridPoints:
    """Detected control points.

    Attributes
    ----------
    uv : (n, 2) float64
        Intensity-weighted centroids ``(u, v)``, pixels.
    area : (n,) int
        Pixels above the threshold in each feature.
    strength : (n,) float64
        Summed top-hat signal of each feature (image units).
    polarity : {"bright", "dark"}
        Polarity used.
    contrast : dict
        ``{"bright": score, "dark": score}`` — the feature response of each polarity (robust
        top-hat peak height over noise σ, times the count of feature-sized regions).
    threshold : float
        Median over the image of the (local) top-hat threshold used (image units).
    """

    uv: np.ndarray
    area: np.ndarray
    strength: np.ndarray
    polarity: str
    contrast: dict
    threshold: float

    def __len__(self) -> int:
        return len(self.uv)


def _mean_image(image) -> np.ndarray:
    a = np.asarray(image)
    if a.ndim == 3:
        a = a.astype(np.float64).mean(axis=0)
    img = as_float_array(a, "image", ndim=2, dtype=np.float32)
    if min(img.shape) < 16:
        raise ValueError(f"image: expected a frame of at least 16 x 16 pixels, got {img.shape}")
    return img


def _block(d: float) -> int:
    return int(max(32, 6 * d))


def _disc(diameter: float) -> np.ndarray:
    k = max(3, int(np.ceil(diameter)) | 1)
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))


def _tophat(img: np.ndarray, element: np.ndarray, bright: bool) -> np.ndarray:
    src = img if bright else -img
    return cv2.morphologyEx(src, cv2.MORPH_TOPHAT, element, borderType=cv2.BORDER_REPLICATE)


def _noise(th: np.ndarray, block: int = 64, floor: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Local median and noise σ maps of a top-hat image, from blocks of ``block`` pixels.

    Quantum noise grows with the signal and a round field leaves noise-free corners, so one
    global σ would be wrong in both places. σ has a floor of 2 % of the feature peaks so that
    noise-free images threshold sensibly too, and at least ``floor`` (quantisation of
    integer frames, whose saturated or flat regions have no measurable noise).
    """
    H, W = th.shape
    nb_v, nb_u = max(1, H // block), max(1, W // block)
    med = np.empty((nb_v, nb_u), np.float32)
    mad = np.empty((nb_v, nb_u), np.float32)
    for a in range(nb_v):
        for b in range(nb_u):
            t = th[a * H // nb_v : (a + 1) * H // nb_v, b * W // nb_u : (b + 1) * W // nb_u]
            m = np.median(t)
            med[a, b], mad[a, b] = m, 1.4826 * np.median(np.abs(t - m))
    sub = th[:: max(1, H // 512), :: max(1, W // 512)]
    peak = float(np.percentile(sub, 99.8)) - float(np.median(sub))
    mad = np.maximum(mad, max(0.02 * peak, floor, 1e-12))
    size = (W, H)
    return (cv2.resize(med, size, interpolation=cv2.INTER_LINEAR),
            cv2.resize(mad, size, interpolation=cv2.INTER_LINEAR))


def _regions(th: np.ndarray, med: np.ndarray, sig: np.ndarray, k: float):
    mask = (th > med + k * sig).astype(np.uint8)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    return n, labels, stats


def feature_contrast(image, *, feature_diameter_px: float, polarity: str,
                     threshold_sigma: float = 5.0, min_area_fraction: float = 0.25,
                     noise_floor: float = 0.0) -> float:
    """Score of feature-sized blobs of one ``polarity`` ("bright"/"dark") in ``image``:
    the count of feature-sized regions times their median peak height in noise σ units."""
    img = _mean_image(image)
    d = positive(feature_diameter_px, "feature_diameter_px")
    th = _tophat(img, _disc(2.5 * d), polarity == "bright")
    med, sig = _noise(th, _block(d), noise_floor)
    n, labels, stats = _regions(th, med, sig, threshold_sigma)
    expect = np.pi * d * d / 4
    area = stats[1:, cv2.CC_STAT_AREA]
    ok = (area >= min_area_fraction * expect) & (area <= 4 * expect + 9)
    if not np.any(ok):
        return 0.0
    peaks = np.zeros(n)
    np.maximum.at(peaks, labels.ravel(), th.ravel())
    lab = np.flatnonzero(ok) + 1
    rows = stats[lab, cv2.CC_STAT_TOP] + stats[lab, cv2.CC_STAT_HEIGHT] // 2
    cols = stats[lab, cv2.CC_STAT_LEFT] + stats[lab, cv2.CC_STAT_WIDTH] // 2
    snr = (peaks[lab] - med[rows, cols]) / sig[rows, cols]
    return float(ok.sum() * np.median(snr))


def detect_grid_points(image, *, feature_diameter_px: float, polarity: str = "auto",
                       element_px: float | None = None, threshold_sigma: float = 5.0,
                       min_area_fraction: float = 0.25, max_area_factor: float = 4.0,
                       exclude_border_px: int = 2, smooth_sigma_px: float | None = None,
                       noise_floor: float | None = None, max_aspect: float = 2.0,
                       min_fill: float = 0.5) -> GridPoints:
    """Detect the holes (bright) or beads (dark) of a calibration grid image.

    Parameters
    ----------
    image : (H, W) or (n_frames, H, W) array_like
        Raw or flatfielded grid frame(s); a stack is averaged first (thesis: 1000 frames).
    feature_diameter_px : float
        Expected hole/bead diameter in the image, pixels (e.g. 3 mm / 0.29 mm ≈ 10).
    polarity : {"auto", "bright", "dark"}
        Bright holes in a plate, or dark beads; "auto" decides from the image.
    element_px : float, optional
        Diameter of the top-hat disc (default ``2.5 * feature_diameter_px``).
    threshold_sigma : float
        Threshold above the top-hat median in robust noise σ.
    min_area_fraction, max_area_factor : float
        Regions smaller than ``min_area_fraction`` (speckle) or larger than ``max_area_factor``
        times the expected disc area are dropped.
    exclude_border_px : int
        Drop regions touching the image border within this many pixels (cut features).
    max_aspect, min_fill : float
        Shape filter: a region's bounding box may be at most ``max_aspect`` times (+1 px) longer
        than wide, and the region must fill at least ``min_fill`` of it (a disc fills π/4).
    smooth_sigma_px : float, optional
        Gaussian pre-smoothing σ (default ``feature_diameter_px / 8``; 0 = none).
    noise_floor : float, optional
        Smallest noise σ assumed (image units); default 0.5 for integer frames (one grey level
        of quantisation; 8-bit radiographs have saturated, noise-free regions), else 0.

    Returns
    -------
    GridPoints

    Raises
    ------
    ValueError
        Bad arguments, or ``polarity`` forced against an image whose features clearly have the
        other polarity (the message names the detected one).
    """
    if polarity not in _POLARITIES:
        raise ValueError(f"polarity: expected one of {_POLARITIES}, got {polarity!r}")
    floor = (0.5 if np.issubdtype(np.asarray(image).dtype, np.integer) else 0.0) if noise_floor is None \
        else float(noise_floor)
    img = _mean_image(image)
    d = positive(feature_diameter_px, "feature_diameter_px")
    el = positive(element_px, "element_px") if element_px is not None else 2.5 * d
    if el <= d:
        raise ValueError(f"element_px: the top-hat disc ({el}) must be larger than the features ({d})")
    positive(threshold_sigma, "threshold_sigma")
    s = d / 8 if smooth_sigma_px is None else float(smooth_sigma_px)
    if s < 0:
        raise ValueError(f"smooth_sigma_px: expected >= 0, got {smooth_sigma_px}")
    if s > 0:
        img = cv2.GaussianBlur(img, (0, 0), s, borderType=cv2.BORDER_REPLICATE)
    score = {p: feature_contrast(img, feature_diameter_px=d, polarity=p, threshold_sigma=threshold_sigma,
                                 min_area_fraction=min_area_fraction, noise_floor=floor)
             for p in ("bright", "dark")}
    best = max(score, key=score.get)
    if polarity == "auto":
        polarity = best
        if score[best] == 0:
            raise ValueError(f"image: no features of about {d:g} px diameter stand out of the noise "
                             f"(neither bright holes nor dark beads)")
    else:
        other = "dark" if polarity == "bright" else "bright"
        if score[other] > 3 * score[polarity] and score[other] > 0:
            kind = {"bright": "bright holes", "dark": "dark beads"}
            raise ValueError(f"image: polarity={polarity!r} was requested, but the grid features are "
                             f"{kind[other]} (response {score[other]:.0f} vs {score[polarity]:.0f}); "
                             f"pass polarity={other!r} or 'auto'")
    th = _tophat(img, _disc(el), polarity == "bright")
    med, sig = _noise(th, _block(d), floor)
    n, labels, stats = _regions(th, med, sig, threshold_sigma)
    expect = np.pi * d * d / 4
    H, W = img.shape
    b = int(exclude_border_px)
    keep = []
    for k in range(1, n):
        x, y, w, h, a = stats[k]
        if a < min_area_fraction * expect or a > max_area_factor * expect + 9:
            continue
        if b > 0 and (x < b or y < b or x + w > W - b or y + h > H - b):
            continue
        if max(w, h) > max_aspect * min(w, h) + 1 or a < min_fill * w * h:
            continue  # elongated or ragged: an edge or a rim, not a round hole or bead
        keep.append(k)
    weight = np.clip(th - med, 0, None)
    uv, area, strength = [], [], []
    kernel = np.ones((3, 3), np.uint8)
    for k in keep:
        x, y, w, h, a = stats[k]
        x0, y0, x1, y1 = max(x - 2, 0), max(y - 2, 0), min(x + w + 2, W), min(y + h + 2, H)
        m = cv2.dilate((labels[y0:y1, x0:x1] == k).astype(np.uint8), kernel).astype(bool)
        wt = weight[y0:y1, x0:x1] * m
        tot = float(wt.sum())
        if tot <= 0:
            continue
        vv, uu = np.mgrid[y0:y1, x0:x1]
        uv.append(((uu * wt).sum() / tot, (vv * wt).sum() / tot))
        area.append(int(a))
        strength.append(tot)
    return GridPoints(np.asarray(uv, float).reshape(-1, 2), np.asarray(area, int),
                      np.asarray(strength, float), polarity, score,
                      float(np.median(med + threshold_sigma * sig)))
