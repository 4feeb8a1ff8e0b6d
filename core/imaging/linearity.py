"""Linearity of grey level against tube settings (thesis §3.2, Fig. 3.3).

A phantom (thesis: Gammex 471 tissue plugs) is imaged over a sweep of kV or mA; each setting's
sequence is averaged over time, the mean grey level inside a region of interest of each plug is
taken (:func:`roi_statistics`), optionally divided by the full scale (e.g. 4095 for 12 bits),
and a straight line is fitted per plug against the setting with its coefficient of
determination ``R²`` (:func:`linearity_study`). ROIs are circles ``("circle", u, v, radius)``
or rectangles ``("rect", u0, v0, width, height)`` in pixels, ``(u, v) = (column, row)`` with
the origin at the centre of the top-left pixel.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .._validate import as_float_array, positive

__all__ = ["LinearFit", "LinearityResult", "linear_fit", "linearity_study", "roi_mask", "roi_statistics"]


def roi_mask(shape, roi) -> np.ndarray:
    """Boolean ``(H, W)`` mask of a circle or rectangle ROI (see the module docs)."""
    H, W = (int(s) for s in shape)
    kind = roi[0] if len(roi) else None
    v, u = np.ogrid[:H, :W]
    if kind == "circle" and len(roi) == 4:
        cu, cv, r = (float(x) for x in roi[1:])
        m = (u - cu) ** 2 + (v - cv) ** 2 <= positive(r, "roi radius") ** 2
    elif kind == "rect" and len(roi) == 5:
        u0, v0, w, h = (int(x) for x in roi[1:])
        m = (u >= u0) & (u < u0 + w) & (v >= v0) & (v < v0 + h)
    else:
        raise ValueError(f"roi: expected ('circle', u, v, radius) or ('rect', u0, v0, w, h), got {roi!r}")
    if not m.any():
        raise ValueError(f"roi: {roi!r} covers no pixel of the {W} x {H} image")
    return m


def _mean_frame(x, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 3:
        a = a.mean(axis=0)
    return as_float_array(a, name, ndim=2)


def roi_statistics(images: Sequence, rois: Sequence) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard deviation ``(n_images, n_rois)`` of each ROI in each image.

    Each item of ``images`` is a frame ``(H, W)`` or a sequence ``(n, H, W)`` (averaged over time
    first, as the thesis averaged 4000 frames per setting).
    """
    frames = [_mean_frame(x, f"images[{i}]") for i, x in enumerate(images)]
    if not frames:
        raise ValueError("images: expected at least one frame")
    shape = frames[0].shape
    masks = [roi_mask(shape, r) for r in rois]
    mean = np.empty((len(frames), len(masks)))
    std = np.empty_like(mean)
    for i, f in enumerate(frames):
        if f.shape != shape:
            raise ValueError(f"images[{i}]: expected shape {shape}, got {f.shape}")
        for j, m in enumerate(masks):
            mean[i, j], std[i, j] = f[m].mean(), f[m].std()
    return mean, std


@dataclass(frozen=True)
class LinearFit:
    """``y ≈ slope · x + intercept`` with its ``r2`` and RMS residual."""

    slope: float
    intercept: float
    r2: float
    residual_rms: float
    n: int


def linear_fit(x, y) -> LinearFit:
    """Least-squares line through ``(x, y)`` (at least 2 points, ``x`` not all equal)."""
    xa = as_float_array(x, "x", ndim=1)
    ya = as_float_array(y, "y", shape=(xa.size,))
    if xa.size < 2 or np.ptp(xa) == 0:
        raise ValueError(f"x: expected at least 2 distinct settings, got {xa.tolist()}")
    b, a = np.polyfit(xa, ya, 1)
    r = ya - (a + b * xa)
    ss = np.sum((ya - ya.mean()) ** 2)
    r2 = 1.0 - np.sum(r**2) / ss if ss > 0 else 1.0
    return LinearFit(float(b), float(a), float(r2), float(np.sqrt(np.mean(r**2))), int(xa.size))


@dataclass(frozen=True, eq=False)
class LinearityResult:
    """ROI means over a setting sweep and one line fit per ROI."""

    settings: np.ndarray
    means: np.ndarray
    stds: np.ndarray
    fits: tuple[LinearFit, ...]
    names: tuple[str, ...]
    full_scale: float | None

    def to_dict(self) -> dict:
        return {"settings": self.settings.tolist(), "full_scale": self.full_scale,
                "rois": [{"name": n, "means": self.means[:, j].tolist(), "stds": self.stds[:, j].tolist(),
                          "slope": f.slope, "intercept": f.intercept, "r2": f.r2,
                          "residual_rms": f.residual_rms}
                         for j, (n, f) in enumerate(zip(self.names, self.fits, strict=True))]}


def linearity_study(images: Sequence, settings, rois: Sequence, *, names: Sequence[str] | None = None,
                    full_scale: float | None = None) -> LinearityResult:
    """Grey level vs tube setting, per ROI (thesis §3.2).

    Parameters
    ----------
    images : sequence
        One frame or frame sequence per setting.
    settings : (n,) array_like
        The swept setting (kV or mA) of each item of ``images``.
    rois : sequence of ROI tuples
        One per phantom plug.
    names : sequence of str, optional
        Plug names (default ``roi0``, ``roi1``, …).
    full_scale : float, optional
        Divide the means by this (4095 for 12-bit frames: the thesis's normalised intensity).
    """
    x = as_float_array(settings, "settings", ndim=1)
    if len(images) != x.size:
        raise ValueError(f"settings: expected one setting per image ({len(images)}), got {x.size}")
    mean, std = roi_statistics(images, rois)
    if full_scale is not None:
        s = positive(full_scale, "full_scale")
        mean, std = mean / s, std / s
    nm = tuple(names) if names is not None else tuple(f"roi{j}" for j in range(len(rois)))
    if len(nm) != len(rois):
        raise ValueError(f"names: expected {len(rois)} names, got {len(nm)}")
    fits = tuple(linear_fit(x, mean[:, j]) for j in range(len(rois)))
    return LinearityResult(x, mean, std, fits, nm, None if full_scale is None else float(full_scale))
