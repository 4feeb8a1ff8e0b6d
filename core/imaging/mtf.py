"""Spatial resolution: MTF from a slanted edge, MTF50, line-pair modulation (thesis §3.4–3.4.1).

Slanted-edge MTF (after ISO 12233; thesis Fig. 3.6)
---------------------------------------------------
1. The edge is located row by row (centroid of the row's derivative, refined once inside a
   Hann window around the first line fit) and a line ``u = a + b v`` is fitted; the edge angle
   is ``atan(b)``. A horizontal edge is handled by transposing. The edge should be tilted by a
   few degrees (thesis: ~5°) so that the rows sample it at many sub-pixel phases.
2. Every pixel centre's signed distance from the line is binned at ``1 / oversample`` pixels: the
   super-resolved edge spread function (ESF), optionally Gaussian-smoothed (``esf_smooth_px``;
   the thesis smoothed it, which lowers the MTF by the Gaussian's own transfer).
3. Its central difference is the line spread function (LSF), Hann-windowed about its peak.
4. ``MTF = |FFT(LSF)|`` normalised at zero frequency and divided by the transfer of the
   central difference (``sinc(2 f Δ)``) and of the binning (``sinc(f Δ)``), ``Δ`` the bin.

Frequencies are in cycles/mm (``pixel_mm`` converts); MTF50 is the first frequency where the MTF
falls to 0.5, the limiting frequency where it falls to ``limit_level`` (default 0.1). For 1/3 mm
pixels the sampling limit (Nyquist) is 1.5 cycles/mm (thesis §3.4).

Line pairs
----------
:func:`line_pair_modulation` gives ``(Imax - Imin) / (Imax + Imin)`` of the profile across each
ROI of a bar pattern (robust 95th/5th percentiles; subtract any dark offset first).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter1d

from .._validate import as_float_array, positive

__all__ = ["MTFResult", "crossing_frequency", "gaussian_mtf", "line_pair_modulation", "slanted_edge_mtf"]


@dataclass(frozen=True, eq=False)
class MTFResult:
    """A measured MTF.

    Attributes
    ----------
    frequency : (m,) float64   cycles/mm, from 0 to the oversampled limit
    mtf : (m,) float64         modulation, 1 at zero frequency
    mtf50 : float              cycles/mm where the MTF first falls to 0.5 (nan if never)
    limit : float              cycles/mm where it first falls to ``limit_level`` (nan if never)
    limit_level : float
    nyquist : float            sampling limit 1 / (2 pixel_mm), cycles/mm
    edge_angle_rad : float     edge tilt from the pixel column (or row) direction
    distance_px, esf, lsf : (k,) float64   binned distance (pixels), ESF and LSF
    """

    frequency: np.ndarray
    mtf: np.ndarray
    mtf50: float
    limit: float
    limit_level: float
    nyquist: float
    edge_angle_rad: float
    distance_px: np.ndarray
    esf: np.ndarray
    lsf: np.ndarray

    def at(self, frequency) -> np.ndarray:
        """MTF interpolated at ``frequency`` (cycles/mm)."""
        return np.interp(frequency, self.frequency, self.mtf)

    def to_dict(self) -> dict:
        return {"mtf50_cycles_per_mm": self.mtf50, "limit_cycles_per_mm": self.limit,
                "limit_level": self.limit_level, "nyquist_cycles_per_mm": self.nyquist,
                "edge_angle_rad": self.edge_angle_rad,
                "frequency_cycles_per_mm": self.frequency.tolist(), "mtf": self.mtf.tolist()}


def gaussian_mtf(frequency, sigma_mm: float) -> np.ndarray:
    """Analytic MTF ``exp(-2 π² σ² f²)`` of a Gaussian PSF of ``sigma_mm`` at ``frequency`` (cycles/mm)."""
    f = np.asarray(frequency, dtype=float)
    return np.exp(-2 * np.pi**2 * float(sigma_mm) ** 2 * f**2)


def crossing_frequency(frequency, mtf, level: float) -> float:
    """First frequency where ``mtf`` falls to ``level`` (linear interpolation; nan if never)."""
    f, m = np.asarray(frequency, float), np.asarray(mtf, float)
    below = np.flatnonzero(m <= level)
    if below.size == 0:
        return float("nan")
    k = int(below[0])
    if k == 0:
        return float(f[0])
    return float(f[k - 1] + (m[k - 1] - level) / (m[k - 1] - m[k]) * (f[k] - f[k - 1]))


def _edge_positions(img: np.ndarray, window: np.ndarray | None = None) -> np.ndarray:
    """Edge position in each row: centroid of the row's |derivative| (optionally windowed)."""
    d = np.abs(np.gradient(img, axis=1))
    if window is not None:
        d = d * window
    u = np.arange(img.shape[1], dtype=float)
    s = d.sum(axis=1)
    s[s == 0] = np.nan
    return (d * u).sum(axis=1) / s


def _edge_line(img: np.ndarray) -> tuple[float, float]:
    """Robust first line fit ``u = a + b v``: per-row peak of the smoothed derivative, refined
    by the centroid within ±4 px, then a line fit with outlier rows (> 3 MAD) dropped."""
    sm = gaussian_filter1d(gaussian_filter1d(img, 1.5, axis=1), 2.0, axis=0)
    d = np.abs(np.gradient(sm, axis=1))
    H, W = img.shape
    k = np.argmax(d, axis=1)
    u = np.arange(W, dtype=float)
    win = np.abs(u[None, :] - k[:, None]) <= 4
    pos = (d * win * u).sum(axis=1) / np.maximum((d * win).sum(axis=1), 1e-300)
    rows = np.arange(H, dtype=float)
    keep = np.ones(H, bool)
    for _ in range(3):
        b, a = np.polyfit(rows[keep], pos[keep], 1)
        r = pos - (a + b * rows)
        mad = 1.4826 * np.median(np.abs(r[keep])) + 1e-9
        new = np.abs(r) < 3 * mad + 0.5
        if new.sum() < 4 or np.array_equal(new, keep):
            break
        keep = new
    return float(a), float(b)


def _crop(image, roi):
    img = as_float_array(image, "image", ndim=2)
    if roi is None:
        return img
    try:
        u0, v0, w, h = (int(x) for x in roi)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"roi: expected (u0, v0, width, height), got {roi!r}") from exc
    H, W = img.shape
    if w < 8 or h < 8 or u0 < 0 or v0 < 0 or u0 + w > W or v0 + h > H:
        raise ValueError(f"roi: ({u0}, {v0}, {w}, {h}) must lie inside the {W} x {H} image and be >= 8 x 8")
    return img[v0 : v0 + h, u0 : u0 + w]


def slanted_edge_mtf(image, *, pixel_mm: float, roi=None, oversample: int = 4, esf_smooth_px: float = 0.0,
                     limit_level: float = 0.1, half_width_px: float | None = None) -> MTFResult:
    """MTF of the imaging chain from an image of a straight, slightly tilted edge.

    Parameters
    ----------
    image : (H, W) array_like
        Frame (raw or flatfielded) containing one straight edge across ``roi``.
    pixel_mm : float
        Pixel size (mm) in the plane the frequencies refer to.
    roi : (u0, v0, width, height), optional
        Region holding the edge (default: the whole image).
    oversample : int
        ESF bins per pixel (4 as in ISO 12233).
    esf_smooth_px : float
        Gaussian σ (pixels) applied to the ESF (0 = none).
    limit_level : float
        Modulation defining the limiting frequency.
    half_width_px : float, optional
        Half-width of the ESF about the edge (default: a quarter of the across-edge ROI size,
        at most 16 px: wider adds more noise than it adds long PSF tails).
    """
    px = positive(pixel_mm, "pixel_mm")
    if int(oversample) != oversample or not 1 <= oversample <= 16:
        raise ValueError(f"oversample: expected an integer in 1..16, got {oversample!r}")
    if not 0 < limit_level < 0.5:
        raise ValueError(f"limit_level: expected a modulation in (0, 0.5), got {limit_level}")
    img = _crop(image, roi)
    gu = np.abs(np.gradient(img, axis=1)).mean()
    gv = np.abs(np.gradient(img, axis=0)).mean()
    if gv > gu:  # a horizontal edge: work on the transpose
        img = img.T
    H, W = img.shape
    rows = np.arange(H, dtype=float)
    if np.ptp(img) <= 0:
        raise ValueError("image: the ROI is uniform, no edge found")
    a, b = _edge_line(img)
    hw = float(half_width_px) if half_width_px is not None else min(W / 4, 16.0)
    u = np.arange(W, dtype=float)
    win = 0.5 * (1 + np.cos(np.pi * np.clip((u[None, :] - (a + b * rows[:, None])) / (2 * hw), -1, 1)))
    pos = _edge_positions(img, win)
    ok = np.isfinite(pos)
    b, a = np.polyfit(rows[ok], pos[ok], 1)
    angle = float(np.arctan(b))
    if abs(angle) < np.radians(0.5):
        raise ValueError(f"image: the edge is only {np.degrees(angle):.2f}° from the pixel grid; tilt it "
                         f"by a few degrees (thesis: ~5°) so the rows sample sub-pixel phases")
    dist = (u[None, :] - (a + b * rows[:, None])) * np.cos(angle)
    step = 1.0 / int(oversample)
    n_half = int(np.floor(hw / step))
    edges = (np.arange(-n_half, n_half + 2) - 0.5) * step
    k = np.digitize(dist.ravel(), edges) - 1
    sel = (k >= 0) & (k < len(edges) - 1)
    cnt = np.bincount(k[sel], minlength=len(edges) - 1).astype(float)
    tot = np.bincount(k[sel], weights=img.ravel()[sel], minlength=len(edges) - 1)
    centres = (edges[:-1] + edges[1:]) / 2
    filled = cnt > 0
    if filled.sum() < 0.8 * len(cnt):
        raise ValueError("roi: too few pixels near the edge to fill the oversampled ESF; use a taller ROI")
    esf = np.interp(centres, centres[filled], tot[filled] / cnt[filled])
    if esf_smooth_px > 0:
        esf = gaussian_filter1d(esf, esf_smooth_px / step, mode="nearest")
    lsf = np.gradient(esf)
    peak = int(np.argmax(np.abs(lsf)))
    n = len(lsf)
    x = np.arange(n) - peak
    lsf_w = lsf * 0.5 * (1 + np.cos(np.pi * np.clip(x / max(peak, n - 1 - peak, 1), -1, 1)))
    spec = np.abs(np.fft.rfft(lsf_w))
    if spec[0] <= 0:
        raise ValueError("image: the edge has no contrast")
    f_px = np.fft.rfftfreq(n, d=step)  # cycles per pixel
    corr = np.sinc(2 * f_px * step) * np.sinc(f_px * step)
    with np.errstate(divide="ignore", invalid="ignore"):
        mtf = np.where(corr > 0.1, spec / spec[0] / corr, np.nan)
    good = np.isfinite(mtf)
    f_mm = f_px[good] / px
    mtf = mtf[good]
    return MTFResult(f_mm, mtf, crossing_frequency(f_mm, mtf, 0.5),
                     crossing_frequency(f_mm, mtf, limit_level),
                     float(limit_level), 0.5 / px, angle, centres, esf, lsf)


def line_pair_modulation(image, rois, *, axis: str = "u", dark: float = 0.0) -> np.ndarray:
    """Modulation ``(Imax - Imin) / (Imax + Imin)`` of a bar pattern in each ROI.

    Parameters
    ----------
    image : (H, W) array_like
    rois : sequence of (u0, v0, width, height)
        One ROI per line-pair group.
    axis : {"u", "v"}
        Direction along which the bars alternate (``"u"``: bars are vertical lines).
    dark : float
        Offset subtracted first (e.g. the dark level of a raw frame).
    """
    if axis not in ("u", "v"):
        raise ValueError(f"axis: expected 'u' or 'v', got {axis!r}")
    out = []
    for roi in rois:
        crop = _crop(image, roi) - float(dark)
        profile = crop.mean(axis=0 if axis == "u" else 1)
        hi, lo = np.percentile(profile, 95), np.percentile(profile, 5)
        out.append((hi - lo) / (hi + lo) if hi + lo > 0 else np.nan)
    return np.asarray(out, dtype=float)
