"""Point spread function from pinhole images, and PSF grids (thesis §3.4.2).

:func:`psf_from_pinholes` follows the thesis: many static frames of a lead bar with sub-pixel
holes are averaged (Poisson noise), each pinhole's spot is cropped, the dark field (the bar's
background: a dark frame, a level, or the median of the crop's border) is subtracted, and the
crop is normalised — to unit sum for deconvolution (:attr:`PSFEstimate.psf`) and to unit peak for
display (:meth:`PSFEstimate.peak_normalised`). Spots are re-centred with a sub-pixel shift so the
kernel's centroid sits on its centre pixel (a kernel off-centre would shift deconvolved images).

A hole of diameter ``D`` is not a point: the estimate is the PSF convolved with the hole's disc
(for the thesis's 0.3 mm holes and ~0.33 mm pixels a small widening, reported, not removed).

:class:`PSFGrid` holds kernels on a regular grid of image positions for the spatially varying
deconvolution of :mod:`core.imaging.deconvolution`. :func:`psf_mtf` is the exact MTF of a
discrete kernel along u (the analytic reference for the slanted-edge MTF).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.ndimage import shift as nd_shift

from .._validate import as_float_array, positive
from .serialize import decode_array, encode_array

__all__ = ["PSFEstimate", "PSFGrid", "gaussian_psf", "normalise_psf", "psf_from_pinholes", "psf_mtf"]


def normalise_psf(psf, name: str = "psf") -> np.ndarray:
    """Odd-sized, non-negative kernel with unit sum (float64)."""
    k = as_float_array(psf, name, ndim=2)
    if k.shape[0] % 2 == 0 or k.shape[1] % 2 == 0:
        raise ValueError(f"{name}: expected an odd-sized kernel, got shape {k.shape}")
    k = np.clip(k, 0.0, None)
    s = k.sum()
    if not s > 0:
        raise ValueError(f"{name}: the kernel has no positive weight")
    return k if abs(s - 1.0) < 1e-12 else k / s  # idempotent: a saved kernel reloads bit-exact


def gaussian_psf(sigma_px: float, size: int | None = None) -> np.ndarray:
    """Sampled Gaussian kernel of ``sigma_px`` (size default ``2·ceil(4σ) + 1``), unit sum."""
    s = positive(sigma_px, "sigma_px")
    n = int(size) if size is not None else 2 * int(np.ceil(4 * s)) + 1
    if n % 2 == 0 or n < 3:
        raise ValueError(f"size: expected an odd integer >= 3, got {size!r}")
    x = np.arange(n) - n // 2
    g = np.exp(-0.5 * (x / s) ** 2)
    k = np.outer(g, g)
    return k / k.sum()


def psf_mtf(psf, frequency_cycles_per_px) -> np.ndarray:
    """MTF of a discrete kernel along u: ``|Σ_x lsf(x) e^{-2πi f x}|`` with ``lsf = Σ_v psf``."""
    k = normalise_psf(psf)
    lsf = k.sum(axis=0)
    x = np.arange(lsf.size) - lsf.size // 2
    f = np.asarray(frequency_cycles_per_px, dtype=float)
    return np.abs(np.exp(-2j * np.pi * f[..., None] * x) @ lsf)


def _fwhm(k: np.ndarray) -> float:
    """Full width at half maximum of the kernel's central row profile (pixels, interpolated)."""
    row = k[k.shape[0] // 2]
    half = row.max() / 2
    above = np.flatnonzero(row >= half)
    lo, hi = above[0], above[-1]
    left = lo - (row[lo] - half) / (row[lo] - row[lo - 1]) if lo > 0 else float(lo)
    right = hi + (row[hi] - half) / (row[hi] - row[hi + 1]) if hi < row.size - 1 else float(hi)
    return float(right - left)


@dataclass(frozen=True, eq=False)
class PSFEstimate:
    """A measured PSF.

    Attributes
    ----------
    psf : (k, k) float64        mean kernel, unit sum, centroid on the centre pixel
    kernels : (n, k, k) float64 each pinhole's kernel, unit sum
    centers_uv : (n, 2) float64 pinhole spot centroids ``(u, v)``, pixels
    fwhm_px : float             FWHM of ``psf`` along u
    """

    psf: np.ndarray
    kernels: np.ndarray
    centers_uv: np.ndarray
    fwhm_px: float

    def peak_normalised(self) -> np.ndarray:
        """The mean kernel scaled to a peak of 1 (thesis: normalised to peak and dark field)."""
        return self.psf / self.psf.max()


def _find_spots(img: np.ndarray, size: int, n_sigma: float) -> np.ndarray:
    sm = cv2.GaussianBlur(img.astype(np.float32), (0, 0), 1.0)
    med = float(np.median(sm))
    sig = 1.4826 * float(np.median(np.abs(sm - med))) + 1e-12
    peak = cv2.dilate(sm, np.ones((size, size), np.uint8))
    cand = np.argwhere((sm == peak) & (sm > med + n_sigma * sig))
    h = size // 2
    H, W = img.shape
    cand = cand[(cand[:, 0] >= h) & (cand[:, 0] < H - h) & (cand[:, 1] >= h) & (cand[:, 1] < W - h)]
    return cand[:, ::-1].astype(float)  # (u, v)


def psf_from_pinholes(frames, *, size: int = 21, centers_uv=None, dark=None, n_sigma: float = 10.0,
                      recenter: bool = True) -> PSFEstimate:
    """Estimate the PSF from pinhole frames (see the module docs).

    Parameters
    ----------
    frames : (H, W) or (n, H, W) array_like
        Pinhole images; a stack is averaged.
    size : int
        Odd side of the kernel (pixels).
    centers_uv : (m, 2) array_like, optional
        Approximate pinhole positions; default: local maxima ``n_sigma`` noise σ above the median.
    dark : float or (H, W) array_like, optional
        Dark field subtracted first; default: the median of each crop's one-pixel border.
    recenter : bool
        Shift each spot by its sub-pixel centroid offset (cubic spline) before averaging.
    """
    a = np.asarray(frames, dtype=np.float64)
    img = a.mean(axis=0) if a.ndim == 3 else a
    img = as_float_array(img, "frames", ndim=2)
    if int(size) != size or size < 5 or size % 2 == 0:
        raise ValueError(f"size: expected an odd integer >= 5, got {size!r}")
    h = size // 2
    if dark is not None:
        img = img - (float(dark) if np.ndim(dark) == 0 else as_float_array(dark, "dark", shape=img.shape))
    cen = _find_spots(img, size, n_sigma) if centers_uv is None else as_float_array(centers_uv, "centers_uv",
                                                                                       shape=(None, 2))
    H, W = img.shape
    kernels, centres = [], []
    for c in cen:
        u0, v0 = np.rint(c).astype(int)
        if not (h + 1 <= u0 < W - h - 1 and h + 1 <= v0 < H - h - 1):
            continue
        crop = img[v0 - h : v0 + h + 1, u0 - h : u0 + h + 1].copy()
        if dark is None:
            border = np.concatenate([crop[0], crop[-1], crop[1:-1, 0], crop[1:-1, -1]])
            crop -= np.median(border)
        w = np.clip(crop, 0, None)
        if w.sum() <= 0:
            continue
        y, x = np.mgrid[-h : h + 1, -h : h + 1]
        du, dv = (w * x).sum() / w.sum(), (w * y).sum() / w.sum()
        if recenter:
            crop = nd_shift(crop, (-dv, -du), order=3, mode="nearest")
        kernels.append(normalise_psf(crop, "spot"))
        centres.append((u0 + du, v0 + dv))
    if not kernels:
        raise ValueError(f"frames: no pinhole spot {n_sigma} σ above the background away from the border")
    K = np.stack(kernels)
    psf = normalise_psf(K.mean(axis=0))
    return PSFEstimate(psf, K, np.asarray(centres), _fwhm(psf))


@dataclass(frozen=True, eq=False)
class PSFGrid:
    """PSF kernels on a regular grid of image positions (spatially varying blur).

    Attributes
    ----------
    centers_u : (nx,) float64   grid column positions (pixels, increasing)
    centers_v : (ny,) float64   grid row positions (pixels, increasing)
    kernels : (ny, nx, k, k) float64   unit-sum kernel at each node
    """

    centers_u: np.ndarray
    centers_v: np.ndarray
    kernels: np.ndarray

    def __post_init__(self) -> None:
        cu = as_float_array(self.centers_u, "centers_u", ndim=1)
        cv = as_float_array(self.centers_v, "centers_v", ndim=1)
        if np.any(np.diff(cu) <= 0) or np.any(np.diff(cv) <= 0):
            raise ValueError("centers_u, centers_v: expected strictly increasing positions")
        k = as_float_array(self.kernels, "kernels", ndim=4)
        if k.shape[:2] != (cv.size, cu.size):
            raise ValueError(f"kernels: expected shape ({cv.size}, {cu.size}, k, k), got {k.shape}")
        k = np.stack([[normalise_psf(k[a, b], "kernels") for b in range(cu.size)] for a in range(cv.size)])
        object.__setattr__(self, "centers_u", cu)
        object.__setattr__(self, "centers_v", cv)
        object.__setattr__(self, "kernels", k)

    def weights(self, shape) -> tuple[np.ndarray, np.ndarray]:
        """Piecewise-linear partition of unity: ``(wv (ny, H), wu (nx, W))``; node ``(a, b)``
        weighs pixel ``(v, u)`` by ``wv[a, v] · wu[b, u]`` (flat beyond the outer nodes)."""
        H, W = (int(s) for s in shape)
        return _tents(self.centers_v, H), _tents(self.centers_u, W)

    def to_dict(self, *, array_encoder=encode_array) -> dict:
        return {"type": "psf_grid", "centers_u": self.centers_u.tolist(),
                "centers_v": self.centers_v.tolist(),
                "kernels": array_encoder(self.kernels)}

    @classmethod
    def from_dict(cls, d: dict, *, array_decoder=decode_array) -> PSFGrid:
        return cls(np.asarray(d["centers_u"], float), np.asarray(d["centers_v"], float),
                   np.asarray(array_decoder(d["kernels"]), float))


def _tents(c: np.ndarray, n: int) -> np.ndarray:
    x = np.arange(n, dtype=float)
    w = np.empty((c.size, n))
    for i in range(c.size):
        e = np.zeros(c.size)
        e[i] = 1.0
        w[i] = np.interp(x, c, e)  # flat (0 or 1) beyond the outer nodes
    return w
