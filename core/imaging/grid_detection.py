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
``polarity="auto"`` runs the top-hat both ways (on a binned copy of the image when the features
span 10 px or more) and keeps the polarity with the stronger, more numerous feature responses;
``"bright"``/``"dark"`` force it, and a :class:`ValueError` says so when the image clearly holds
features of the other polarity (e.g. a bead grid passed as a hole plate). Points are
``(u, v) = (column, row)`` pixels, origin at the centre of the top-left pixel.
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
        top-hat peak height over noise σ, times the count of feature-sized regions), scored on
        the image binned ``f × f`` with ``f = ⌊feature_diameter_px / 5⌋`` (features of 10 px
        and more: a quarter of the pixels or fewer to weigh the polarity).
    threshold : float
        Median over the image's blocks of the (local) top-hat threshold used (image units).
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
    """White (``bright``) or black (dark features) top-hat. The morphology runs on the image
    quantised to 16 bits over its range (about twice as fast as on floats); openings and
    closings commute with that monotonic map, so the result differs from the float one by at
    most one quantum (range / 65535)."""
    lo, hi = cv2.minMaxLoc(img)[:2]
    q = cv2.normalize(img, None, 0, 65535, cv2.NORM_MINMAX, cv2.CV_16U)
    op = cv2.MORPH_TOPHAT if bright else cv2.MORPH_BLACKHAT
    th = cv2.morphologyEx(q, op, element, borderType=cv2.BORDER_REPLICATE)
    return np.multiply(th, np.float32((hi - lo) / 65535.0 if hi > lo else 1.0), dtype=np.float32)


def _noise(th: np.ndarray, block: int = 64, floor: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Local median and noise σ of a top-hat image per block of ``block`` pixels (block maps;
    :func:`_full` interpolates them to every pixel).

    Quantum noise grows with the signal and a round field leaves noise-free corners, so one
    global σ would be wrong in both places. σ has a floor of 2 % of the feature peaks so that
    noise-free images threshold sensibly too, and at least ``floor`` (quantisation of
    integer frames, whose saturated or flat regions have no measurable noise). The blocks tile
    the image in equal sizes (the last rows/columns, fewer than the number of blocks, fall in no
    block); each block's median and MAD come from a regular subsample of at least ~1,000 of its
    pixels, all blocks in one call.
    """
    H, W = th.shape
    nb_v, nb_u = max(1, H // block), max(1, W // block)
    bh, bw = H // nb_v, W // nb_u
    # at least ~1,000 samples per block: every pixel of small blocks, a regular subsample of large
    step = max(1, int(np.sqrt(bh * bw / 1024)))
    bh, bw = bh - bh % step, bw - bw % step
    t = th[: nb_v * (H // nb_v), : nb_u * (W // nb_u)].reshape(nb_v, H // nb_v, nb_u, W // nb_u)
    t = t[:, :bh:step, :, :bw:step].swapaxes(1, 2).reshape(nb_v, nb_u, -1)
    med = np.median(t, axis=-1).astype(np.float32)
    mad = (1.4826 * np.median(np.abs(t - med[..., None]), axis=-1)).astype(np.float32)
    sub = th[:: max(1, H // 512), :: max(1, W // 512)]
    peak = float(np.percentile(sub, 99.8)) - float(np.median(sub))
    mad = np.maximum(mad, max(0.02 * peak, floor, 1e-12))
    return med, mad


def _full(block_map: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """A block map interpolated (bilinearly) to every pixel."""
    return cv2.resize(block_map, (shape[1], shape[0]), interpolation=cv2.INTER_LINEAR)


def _regions(th: np.ndarray, thr: np.ndarray):
    mask = cv2.compare(th, thr, cv2.CMP_GT)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    return n, labels, stats


@dataclass(frozen=True, eq=False)
class _Response:
    """Top-hat of one polarity, its noise maps, regions above threshold and their score."""

    th: np.ndarray
    med: np.ndarray  # local median of th, every pixel
    thr: np.ndarray  # local threshold, every pixel
    thr_blocks: np.ndarray  # the threshold per block
    n: int
    labels: np.ndarray
    stats: np.ndarray
    score: float


def _response(img: np.ndarray, d: float, el: float, bright: bool, k: float, min_area_fraction: float,
              floor: float, score: bool = True) -> _Response:
    th = _tophat(img, _disc(el), bright)
    med_b, sig_b = _noise(th, _block(d), floor)
    # the interpolation is linear: the threshold map is that of the block thresholds
    med, thr = _full(med_b, th.shape), _full(med_b + np.float32(k) * sig_b, th.shape)
    n, labels, stats = _regions(th, thr)
    expect = np.pi * d * d / 4
    area = stats[1:, cv2.CC_STAT_AREA]
    ok = (area >= min_area_fraction * expect) & (area <= 4 * expect + 9)
    if not score:
        return _Response(th, med, thr, med_b + np.float32(k) * sig_b, n, labels, stats, float("nan"))
    score = 0.0
    if np.any(ok):
        lab = np.flatnonzero(ok) + 1
        # each region's peak: the maximum of its pixels (only labelled pixels are visited)
        where = np.flatnonzero(labels)
        peaks = np.full(n, -np.inf, np.float32)
        np.maximum.at(peaks, labels.ravel()[where], th.ravel()[where])
        rows = stats[lab, cv2.CC_STAT_TOP] + stats[lab, cv2.CC_STAT_HEIGHT] // 2
        cols = stats[lab, cv2.CC_STAT_LEFT] + stats[lab, cv2.CC_STAT_WIDTH] // 2
        snr = k * (peaks[lab] - med[rows, cols]) / (thr[rows, cols] - med[rows, cols])
        score = float(ok.sum() * np.median(snr))
    return _Response(th, med, thr, med_b + np.float32(k) * sig_b, n, labels, stats, score)


def feature_contrast(image, *, feature_diameter_px: float, polarity: str,
                     threshold_sigma: float = 5.0, min_area_fraction: float = 0.25,
                     noise_floor: float = 0.0) -> float:
    """Score of feature-sized blobs of one ``polarity`` ("bright"/"dark") in ``image``:
    the count of feature-sized regions times their median peak height in noise σ units."""
    img = _mean_image(image)
    d = positive(feature_diameter_px, "feature_diameter_px")
    f = _bin_factor(d)
    return _response(_binned(img, f), d / f, 2.5 * d / f, polarity == "bright", threshold_sigma,
                     min_area_fraction, noise_floor / f).score


def _bin_factor(d: float) -> int:
    """Binning of the polarity score: features stay at least 5 px across."""
    return max(1, int(d // 5))


def _binned(img: np.ndarray, f: int) -> np.ndarray:
    if f == 1:
        return img
    H, W = img.shape
    return cv2.resize(img[: H - H % f, : W - W % f], (W // f, H // f), interpolation=cv2.INTER_AREA)


def _centroids(resp: _Response, keep: np.ndarray):
    """Intensity-weighted centroids of the regions ``keep`` (labels), each grown by one pixel.

    The weight is the top-hat above its local median. Every region is cut out in a window of
    its bounding box plus 2 pixels (regions of one window size at once), its own mask is grown
    by one pixel there (a pixel next to two regions counts for both), and the weighted sums
    are taken over the window — no pass over the whole image.
    """
    n = len(keep)
    uv, sw = np.full((n, 2), np.nan), np.zeros(n)
    if n == 0:
        return uv, sw > 0, sw
    st = resp.stats[keep]
    size = np.maximum(st[:, cv2.CC_STAT_WIDTH], st[:, cv2.CC_STAT_HEIGHT]) + 4
    for S in np.unique(size):
        sel = np.flatnonzero(size == S)
        uv[sel], sw[sel] = _window_centroids(resp, keep[sel], st[sel], int(S))
    good = sw > 0
    return uv[good], good, sw[good]


def _window_centroids(resp: _Response, keep: np.ndarray, st: np.ndarray, S: int):
    H, W = resp.labels.shape
    g = np.arange(S)
    rows = st[:, cv2.CC_STAT_TOP, None] - 2 + g[None]  # (n, S)
    cols = st[:, cv2.CC_STAT_LEFT, None] - 2 + g[None]
    rr, cc = np.clip(rows, 0, H - 1), np.clip(cols, 0, W - 1)
    inside = ((rows == rr) & (g[None] < st[:, cv2.CC_STAT_HEIGHT, None] + 4))[:, :, None] & \
        ((cols == cc) & (g[None] < st[:, cv2.CC_STAT_WIDTH, None] + 4))[:, None, :]
    R, C = rr[:, :, None], cc[:, None, :]
    own = resp.labels[R, C] == keep[:, None, None]
    grown = own.copy()
    grown[:, 1:] |= own[:, :-1]
    grown[:, :-1] |= own[:, 1:]
    g2 = grown.copy()
    g2[:, :, 1:] |= grown[:, :, :-1]
    g2[:, :, :-1] |= grown[:, :, 1:]
    wt = np.where(g2 & inside, np.clip(resp.th[R, C] - resp.med[R, C], 0, None), 0).astype(np.float64)
    sw = wt.sum(axis=(1, 2))
    su = np.einsum("nrc,nc->n", wt, cols.astype(float))
    sv = np.einsum("nrc,nr->n", wt, rows.astype(float))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.column_stack([su / sw, sv / sw]), sw


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
    f = _bin_factor(d)
    small = _binned(img, f)
    resp = {p: _response(small, d / f, 2.5 * d / f, p == "bright", threshold_sigma, min_area_fraction,
                         floor / f) for p in ("bright", "dark")}
    score = {p: r.score for p, r in resp.items()}
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
    r = resp[polarity] if f == 1 and el == 2.5 * d else _response(
        img, d, el, polarity == "bright", threshold_sigma, min_area_fraction, floor, score=False)
    expect = np.pi * d * d / 4
    H, W = img.shape
    b = int(exclude_border_px)
    x, y, w, h, a = (r.stats[1:, c] for c in range(5))
    ok = (a >= min_area_fraction * expect) & (a <= max_area_factor * expect + 9)
    if b > 0:
        ok &= (x >= b) & (y >= b) & (x + w <= W - b) & (y + h <= H - b)
    # elongated or ragged: an edge or a rim, not a round hole or bead
    ok &= (np.maximum(w, h) <= max_aspect * np.minimum(w, h) + 1) & (a >= min_fill * w * h)
    keep = np.flatnonzero(ok) + 1
    uv, good, strength = _centroids(r, keep)
    area = r.stats[keep[good], cv2.CC_STAT_AREA].astype(int)
    return GridPoints(np.asarray(uv, float).reshape(-1, 2), area, np.asarray(strength, float), polarity,
                      score, float(np.median(r.thr_blocks)))
