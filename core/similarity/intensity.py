"""Intensity-based metrics of thesis §6.2.1 and pattern intensity (§6.2.2): numpy references.

Every function compares a DRR with a fluoroscope ROI of the same shape over Ω (see
:mod:`core.similarity.domain`; ``**domain_options`` are ``threshold``, ``dilate``, ``fluoro_mask``
and ``fluoro_sigma``) and returns a float *score*: larger is more similar, an image against
itself scores 1. An empty Ω gives 0.0.
"""

from __future__ import annotations

import numpy as np

from .domain import _nonneg_int, prepare

__all__ = ["lad", "ncc", "pattern_intensity", "sid"]


def _moments(a: np.ndarray, b: np.ndarray) -> tuple[int, float, float, float, float, float]:
    """``(N, mean_a, mean_b, S_aa, S_bb, S_ab)`` with centred sums of squares/products."""
    n = a.size
    ma, mb = a.mean(), b.mean()
    da, db = a - ma, b - mb
    return n, ma, mb, float(da @ da), float(db @ db), float(da @ db)


def pearson(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson correlation of two 1-D samples; 0.0 when either has no variance or is empty."""
    if a.size == 0:
        return 0.0
    _, _, _, saa, sbb, sab = _moments(a, b)
    den = np.sqrt(saa * sbb)
    return float(sab / den) if den > 0 else 0.0


def concordance(a: np.ndarray, b: np.ndarray) -> float:
    """``1 - Σ(a - b)² / E_perm[Σ(a - b)²]`` = Lin's concordance correlation of two samples.

    ``E_perm`` is the expected sum of squared differences when the pixels of ``b`` are paired
    with those of ``a`` at random: ``S_aa + S_bb + N (ā - b̄)²``. Equals
    ``2 S_ab / (S_aa + S_bb + N (ā - b̄)²)``, in [-1, 1]; 0.0 when the denominator vanishes.
    """
    if a.size == 0:
        return 0.0
    n, ma, mb, saa, sbb, sab = _moments(a, b)
    den = saa + sbb + n * (ma - mb) ** 2
    return float(2.0 * sab / den) if den > 0 else 0.0


def sid(drr, fluoro, **domain_options) -> float:
    """Squared intensity differences (eq. 6.1), normalised: ``1 - SID / E_perm[SID]``.

    ``SID = Σ_Ω (D - F)²``; dividing by its expectation under a random pairing of the same pixels
    (:func:`concordance`) gives 1 for identical images, ~0 for unrelated ones and -1 for
    ``F = 2 mean - D``. Range [-1, 1]. Unlike NCC it also penalises offsets and scale
    differences between the images (it compares intensities, not their pattern).
    """
    d, f, om = prepare(drr, fluoro, **domain_options)
    return concordance(d[om], f[om])


def lad(drr, fluoro, *, scale: float = 1.0, **domain_options) -> float:
    """Log absolute differences (eq. 6.2/6.5): ``1 - mean_Ω log2(1 + |D - F| / scale)``.

    The thesis' rescaling: with ``|D - F| <= scale`` at every pixel the score lies in [0, 1]
    (1 = identical, 0 = every difference as large as ``scale``); larger differences give negative
    scores. The logarithm damps outliers (quantum noise, beads). ``scale`` is in image units
    (default 1: the range of a flatfield-normalised image). Unrelated images do not score 0 —
    the definition has no reference point; range (-∞, 1].
    """
    s = float(scale)
    if not np.isfinite(s) or s <= 0:
        raise ValueError(f"scale: expected a positive intensity scale, got {scale!r}")
    d, f, om = prepare(drr, fluoro, **domain_options)
    if not om.any():
        return 0.0
    return float(1.0 - np.mean(np.log2(1.0 + np.abs(d[om] - f[om]) / s)))


def ncc(drr, fluoro, **domain_options) -> float:
    """Normalised cross-correlation (eq. 6.3/6.6): Pearson correlation of D and F over Ω.

    Invariant to linear intensity transforms of either image. Range [-1, 1]; 0.0 when either
    image is constant on Ω.
    """
    d, f, om = prepare(drr, fluoro, **domain_options)
    return pearson(d[om], f[om])


def _neighbour_offsets(radius: int) -> list[tuple[int, int]]:
    r = radius
    return [(dr, dc) for dr in range(-r, r + 1) for dc in range(-r, r + 1)
            if 0 < dr * dr + dc * dc <= r * r]


def _pi_mean(diff: np.ndarray, om: np.ndarray, offsets, s2: float) -> float:
    """Mean of σ²/(σ² + (d_p - d_q)²) over Ω pixels p and their in-image neighbours q."""
    h, w = diff.shape
    total, count = 0.0, 0
    rr, cc = np.nonzero(om)
    for dr, dc in offsets:
        r2, c2 = rr + dr, cc + dc
        ok = (r2 >= 0) & (r2 < h) & (c2 >= 0) & (c2 < w)
        delta = diff[rr[ok], cc[ok]] - diff[r2[ok], c2[ok]]
        total += float(np.sum(s2 / (s2 + delta * delta)))
        count += int(ok.sum())
    return total / count if count else 1.0


def pattern_intensity(drr, fluoro, *, radius: int = 2, sigma: float = 0.05, **domain_options) -> float:
    """Pattern intensity (Weese; eq. 6.9), normalised against a blank DRR.

    With the difference image ``d = F - D``, ``PI = mean over p ∈ Ω and neighbours q
    (0 < |q - p| <= radius, inside the image) of σ² / (σ² + (d_p - d_q)²)``: 1 when ``d`` is
    uniform around every Ω pixel (the DRR explains all local structure of F). The score is
    ``(PI - PI₀) / (1 - PI₀)`` with ``PI₀`` the value for a DRR with no structure (``d = F``): 1
    for identical images (up to an offset), 0 for a DRR that explains nothing, negative when it
    adds structure F does not have. Range (-∞, 1]; 0.0 when F is flat around Ω (``PI₀ = 1``).

    ``sigma`` is in image units: the thesis (after Weese: radius 3, σ = 10 grey levels) used
    radius 2, σ = 10 on 8-bit grey levels, i.e. ≈ 0.04 of the image range; the default 0.05 suits
    line-integral images (``-ln`` of flatfield-normalised fluence, 0 … ~3).
    """
    r = _nonneg_int(radius, "radius")
    if r < 1:
        raise ValueError(f"radius: expected a neighbourhood radius >= 1 px, got {radius!r}")
    s = float(sigma)
    if not np.isfinite(s) or s <= 0:
        raise ValueError(f"sigma: expected a positive intensity scale, got {sigma!r}")
    d, f, om = prepare(drr, fluoro, **domain_options)
    if not om.any():
        return 0.0
    offsets = _neighbour_offsets(r)
    pi = _pi_mean(f - d, om, offsets, s * s)
    pi0 = _pi_mean(f, om, offsets, s * s)
    if pi0 >= 1.0:
        return 0.0
    return float((pi - pi0) / (1.0 - pi0))
