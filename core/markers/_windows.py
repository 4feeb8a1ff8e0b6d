"""Window extraction and per-window background / noise / contrast estimates (vectorised).

Windows are square ``(2H + 1)²`` pixel blocks centred on the *rounded* guess; pixel ``[i, j]``
of the window of a guess rounded to ``(cu, cv)`` lies at ``(u, v) = (cu - H + j, cv - H + i)``.
Pixels outside the image are filled with the nearest edge pixel and flagged in ``valid``.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

__all__ = ["Windows", "extract", "noise_sigma", "smoothed_contrast"]


class Windows:
    """A stack of windows cut from frames, with their placement (plain container)."""

    __slots__ = ("center", "data", "half", "inside")

    def __init__(self, data: np.ndarray, center: np.ndarray, half: int, inside: np.ndarray):
        self.data = data  # (M, S, S) float64
        self.center = center  # (M, 2) int64 (cu, cv)
        self.half = half
        self.inside = inside  # (M,) bool: the whole window lies in the image

    @property
    def size(self) -> int:
        return 2 * self.half + 1


def extract(frames: np.ndarray, frame_index: np.ndarray, center: np.ndarray, half: int,
            dtype=np.float64) -> Windows:
    """Cut ``(M, 2H+1, 2H+1)`` windows centred at integer ``center (M, 2)`` = (cu, cv).

    ``frames`` is ``(F, H, W)``; ``frame_index (M,)`` picks the frame of each window.
    """
    _, h, w = frames.shape
    S = 2 * half + 1
    c0 = center[:, 0] - half
    r0 = center[:, 1] - half
    inside = (c0 >= 0) & (c0 + S <= w) & (r0 >= 0) & (r0 + S <= h)
    data = np.empty((len(center), S, S), dtype)
    if inside.any() and S <= min(h, w):
        # whole blocks through a strided view: copies rows of S pixels, no per-pixel indices
        view = np.lib.stride_tricks.sliding_window_view(frames, (S, S), axis=(1, 2))
        i = np.flatnonzero(inside)
        data[i] = view[frame_index[i], r0[i], c0[i]]
    out = np.flatnonzero(~inside)
    if out.size:
        off = np.arange(-half, half + 1)
        cc = np.clip(center[out, 0:1] + off, 0, w - 1)
        rr = np.clip(center[out, 1:2] + off, 0, h - 1)
        data[out] = frames[frame_index[out, None, None], rr[:, :, None], cc[:, None, :]]
    return Windows(data, center, half, inside)


def border_median(win: np.ndarray) -> np.ndarray:
    """Median of each window's outer frame of pixels: ``(M,)`` background level."""
    top, bot = win[:, 0, :], win[:, -1, :]
    left, right = win[:, 1:-1, 0], win[:, 1:-1, -1]
    return np.median(np.concatenate([top, bot, left, right], axis=1), axis=1)


def noise_sigma(win: np.ndarray) -> np.ndarray:
    """Robust per-window pixel noise σ from horizontal first differences (MAD / sqrt 2).

    Assumes white noise; blur-correlated noise gives a smaller value than the per-pixel σ.
    """
    d = np.diff(win, axis=2).reshape(len(win), -1)
    med = np.median(d, axis=1, keepdims=True)
    return 1.4826 * np.median(np.abs(d - med), axis=1) / np.sqrt(2.0)


def smoothed_contrast(sig: np.ndarray, radius: np.ndarray, mask: np.ndarray | None = None
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Peak of the bead signal smoothed at the bead scale, its noise level and the peak index.

    ``sig (M, S, S)`` is background-subtracted bead signal (bead positive). The smoothing is a
    Gaussian of σ = max(0.7, r / 2) px (one value per call: the median radius). The noise is the
    robust (MAD) spread of the smoothed window — it includes the noise's spatial correlation.
    ``mask (M, S, S)`` restricts where the peak may lie. Returns ``(peak (M,), noise (M,),
    flat index (M,))``.
    """
    s = max(0.7, float(np.median(radius)) / 2.0)
    sm = ndimage.gaussian_filter(sig, sigma=(0.0, s, s), mode="nearest", truncate=3.0)
    flat = sm.reshape(len(sm), -1)
    med = np.median(flat, axis=1, keepdims=True)
    noise = 1.4826 * np.median(np.abs(flat - med), axis=1)
    cand = flat if mask is None else np.where(mask.reshape(len(sm), -1), flat, -np.inf)
    idx = np.argmax(cand, axis=1)
    peak = np.take_along_axis(flat, idx[:, None], axis=1)[:, 0] - med[:, 0]
    return peak, noise, idx


def snr_of(peak: np.ndarray, noise: np.ndarray) -> np.ndarray:
    """``peak / noise`` with a noise-free window giving inf (bead) or 0 (flat)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        snr = np.where(noise > 0, peak / noise, np.where(peak > 0, np.inf, 0.0))
    return np.where(np.isfinite(peak), snr, 0.0)
