"""Bead signature models and the sizes derived from a bead's expected diameter in pixels.

A steel bead of diameter ``D`` mm seen with magnification ``M`` on a detector of pixel pitch
``p`` mm casts a round shadow of ``diameter_px = D · M / p`` pixels (thesis §4.3: 2–3 mm beads,
0.327 mm pixels, 9–12 px signatures once the blur is included). Every localizer takes that
*projected* diameter; the bead **radius** ``r = diameter_px / 2`` sets

* the Gaussian weight of thesis Eq. 4.3, ``W = exp(-d²/σ²)``, with ``σ = r / sqrt(ln 2)`` so
  that ``W`` falls to one half at the bead's edge (:func:`gaussian_sigma`);
* the sigmoid of thesis Eq. 4.4 (Borlin et al.), written for the bead *signal* (background minus
  image) as ``S(d) = k / (1 + exp(β (d - α)))`` with ``α = r`` (the half-maximum radius, half
  the FWHM) and the edge steepness ``β`` in 1/px (:func:`sigmoid_profile`); Eq. 4.4 itself is
  the image-intensity form ``k - S``;
* the window of the one-shot algorithms, ``h = ceil(2 r) + 2`` pixels about the guess
  (19 × 19 for the thesis's 3-px-radius beads; :func:`window_half_size`).

Distances ``d`` are in pixels from the model centre.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "gaussian_profile",
    "gaussian_sigma",
    "radius_array",
    "sigmoid_profile",
    "window_half_size",
]


def radius_array(diameter_px, n: int) -> np.ndarray:
    """``(n,)`` bead radii in pixels from a scalar or per-bead ``diameter_px`` (validated)."""
    try:
        d = np.asarray(diameter_px, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"diameter_px: expected a number or an array of numbers, got "
                         f"{type(diameter_px).__name__}") from exc
    if d.ndim > 1 or (d.ndim == 1 and d.shape[0] != n):
        raise ValueError(f"diameter_px: expected a scalar or shape ({n},), got {d.shape}")
    if not np.all(np.isfinite(d)) or np.any(d < 1.0) or np.any(d > 200.0):
        raise ValueError("diameter_px: expected projected bead diameters of 1–200 pixels")
    return np.broadcast_to(d / 2.0, (n,)).astype(np.float64)


def gaussian_sigma(radius_px) -> np.ndarray:
    """σ (px) of the Eq. 4.3 weight ``exp(-d²/σ²)`` that is 1/2 at the bead radius."""
    return np.asarray(radius_px, dtype=np.float64) / np.sqrt(np.log(2.0))


def gaussian_profile(d2, radius_px) -> np.ndarray:
    """Eq. 4.3 Gaussian ``exp(-d²/σ²)`` of squared distances ``d2`` (px²), σ from the radius."""
    s = gaussian_sigma(radius_px)
    return np.exp(-np.asarray(d2) / (s * s))


def sigmoid_profile(d, radius_px, beta: float) -> np.ndarray:
    """Eq. 4.4 bead signal ``1 / (1 + exp(β (d - α)))``, ``α = radius_px``, ``β`` in 1/px."""
    z = np.clip(beta * (np.asarray(d) - radius_px), -60.0, 60.0)
    return 1.0 / (1.0 + np.exp(z))


def window_half_size(radius_px: float) -> int:
    """Half-size ``h`` (px) of the one-shot localizers' window: ``ceil(2 r) + 2``."""
    return int(np.ceil(2.0 * float(radius_px))) + 2
