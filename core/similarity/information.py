"""Information-based metrics of thesis §6.2.2: mutual information and regional MI (numpy).

Histograms (MI, NMI)
--------------------
Each image's values over Ω are mapped onto ``bins`` bin *centres* spanning its own range on Ω:
``t = (x - min_Ω) / (max_Ω - min_Ω) · (bins - 1)``. With ``binning="linear"`` (default) a pixel
adds weight ``1 - frac(t)`` to bin ``floor(t)`` and ``frac(t)`` to the next (partial-volume
interpolation; the joint histogram takes the products), so the metric changes continuously as a
DRR moves — an optimizer sees no steps from pixels jumping between bins. ``"nearest"`` puts each
pixel in the bin of the nearest centre. Entropies are in nats. An image constant on Ω has zero
entropy; its MI scores are 0.0.
"""

from __future__ import annotations

import numpy as np

from .domain import _nonneg_int, prepare

__all__ = ["joint_histogram", "mutual_information", "regional_mutual_information"]


def _bin_weights(x: np.ndarray, bins: int, binning: str) -> tuple[np.ndarray, np.ndarray]:
    """Lower bin index (int) and the weight of the upper bin for each value."""
    lo, hi = float(x.min()), float(x.max())
    if hi <= lo:
        return np.zeros(x.size, dtype=np.int64), np.zeros(x.size)
    t = (x - lo) / (hi - lo) * (bins - 1)
    if binning == "nearest":
        return np.clip(np.rint(t), 0, bins - 1).astype(np.int64), np.zeros(x.size)
    i0 = np.clip(np.floor(t), 0, bins - 2).astype(np.int64)
    return i0, np.clip(t - i0, 0.0, 1.0)


def joint_histogram(a: np.ndarray, b: np.ndarray, *, bins: int = 32, binning: str = "linear") -> np.ndarray:
    """``(bins, bins)`` joint histogram (counts, float64) of two equal-length 1-D samples.

    See the module docs for the binning; rows index ``a``, columns ``b``.
    """
    if binning not in ("linear", "nearest"):
        raise ValueError(f"binning: expected 'linear' or 'nearest', got {binning!r}")
    nb = _nonneg_int(bins, "bins")
    if nb < 2:
        raise ValueError(f"bins: expected at least 2 histogram bins, got {bins!r}")
    hist = np.zeros((nb, nb))
    if a.size == 0:
        return hist
    ia, fa = _bin_weights(a, nb, binning)
    ib, fb = _bin_weights(b, nb, binning)
    ja, jb = np.minimum(ia + 1, nb - 1), np.minimum(ib + 1, nb - 1)
    for r, wr in ((ia, 1.0 - fa), (ja, fa)):
        for c, wc in ((ib, 1.0 - fb), (jb, fb)):
            np.add.at(hist, (r, c), wr * wc)
    return hist


def _entropy(p: np.ndarray) -> float:
    q = p[p > 0]
    return float(-(q * np.log(q)).sum())


def entropies(hist: np.ndarray) -> tuple[float, float, float]:
    """``(H_a, H_b, H_ab)`` in nats from a joint histogram of counts."""
    total = hist.sum()
    if total <= 0:
        return 0.0, 0.0, 0.0
    p = hist / total
    return _entropy(p.sum(axis=1)), _entropy(p.sum(axis=0)), _entropy(p)


def mutual_information(drr, fluoro, *, bins: int = 32, normalized: bool = False,
                       binning: str = "linear", **domain_options) -> float:
    """Mutual information of D and F over Ω (eq. 6.8), normalised by the images' self-information.

    ``MI = H_D + H_F - H_DF`` (nats). With ``normalized=False`` the score is
    ``MI / sqrt(MI_DD · MI_FF)``, where ``MI_XX = 2 H_X - H_XX`` is an image's MI with itself under
    the same binning (``= H_X`` for ``"nearest"``, which makes this Strehl & Ghosh's
    ``MI / sqrt(H_D H_F)``; smaller for the partial-volume ``"linear"`` binning, whose joint
    histogram of an image with itself is not diagonal). With ``normalized=True`` it is Studholme's
    ``NMI = (H_D + H_F) / H_DF`` as ``(NMI - 1) / sqrt((NMI_DD - 1)(NMI_FF - 1))``. Both are 1 for an
    image against itself (or any increasing or decreasing transform of itself, up to binning) and
    0 for independent images; range [0, 1] (for ``"nearest"`` exactly; ``"linear"`` can exceed 1 by
    a rounding margin). 0.0 when either image is constant on Ω or Ω is empty.
    """
    d, f, om = prepare(drr, fluoro, **domain_options)
    a, b = d[om], f[om]
    ha, hb, hab = entropies(joint_histogram(a, b, bins=bins, binning=binning))
    _, _, haa = entropies(joint_histogram(a, a, bins=bins, binning=binning))
    _, _, hbb = entropies(joint_histogram(b, b, bins=bins, binning=binning))
    return mi_score(ha, hb, hab, haa, hbb, normalized=normalized)


def mi_score(ha: float, hb: float, hab: float, haa: float, hbb: float, *, normalized: bool) -> float:
    """The normalised MI / NMI score from marginal, joint and self-joint entropies (nats)."""
    if min(ha, hb, hab, haa, hbb) <= 0:
        return 0.0
    if normalized:
        da, db = 2.0 * ha / haa - 1.0, 2.0 * hb / hbb - 1.0
        if da <= 0 or db <= 0:
            return 0.0
        return float(max((ha + hb) / hab - 1.0, 0.0) / np.sqrt(da * db))
    sa, sb = 2.0 * ha - haa, 2.0 * hb - hbb
    if sa <= 0 or sb <= 0:
        return 0.0
    return float(max(ha + hb - hab, 0.0) / np.sqrt(sa * sb))


def _neighbourhoods(img: np.ndarray, om: np.ndarray, radius: int) -> np.ndarray:
    """``(N_Ω, (2r+1)²)`` neighbourhood vectors of the Ω pixels (borders replicate)."""
    r = radius
    pad = np.pad(img, r, mode="edge")
    rr, cc = np.nonzero(om)
    cols = [pad[rr + r + dr, cc + r + dc] for dr in range(-r, r + 1) for dc in range(-r, r + 1)]
    return np.stack(cols, axis=1)


def regional_mutual_information(drr, fluoro, *, radius: int = 1, eps: float = 1e-6,
                                **domain_options) -> float:
    """Regional mutual information (Russakoff et al. 2004), normalised to [0, 1].

    Every Ω pixel contributes the ``2d``-vector of its ``(2r+1)² = d`` neighbourhood values in both
    images. With the covariance ``C`` of these vectors (means removed) and its two diagonal blocks
    ``C_D, C_F``, the Gaussian estimate of the regional MI is
    ``RMI = ½ (ln det C_D + ln det C_F - ln det C)`` nats (Russakoff's eq. for normally distributed
    points). The score is ``1 - exp(-2 RMI / d) = 1 - (det C / (det C_D det C_F))^(1/d)``: the
    geometric mean of the squared canonical correlations' complement, 0 for independent
    neighbourhoods and → 1 as one image's neighbourhoods determine the other's. ``eps`` times the
    mean variance is added to each block's diagonal (regularisation: an image against itself
    scores ``1 - O(eps)``). 0.0 with fewer than ``2d + 1`` Ω pixels or a constant image.
    """
    r = _nonneg_int(radius, "radius")
    if r < 1:
        raise ValueError(f"radius: expected a neighbourhood radius >= 1 px, got {radius!r}")
    e = float(eps)
    if not np.isfinite(e) or e <= 0:
        raise ValueError(f"eps: expected a small positive regularisation, got {eps!r}")
    d, f, om = prepare(drr, fluoro, **domain_options)
    k = (2 * r + 1) ** 2
    if om.sum() < 2 * k + 1:
        return 0.0
    x = np.concatenate([_neighbourhoods(d, om, r), _neighbourhoods(f, om, r)], axis=1)
    # Shift by the first vector before removing the mean: a column of equal values then becomes
    # exactly zero, so a constant image gives an exactly-zero covariance block and scores 0.0.
    # Centring on the mean alone leaves residues of ±1 ulp (the mean of n copies of 0.7 is not
    # 0.7), a rank-1 block of size ~1e-32 that passes the variance test, and a score made of
    # slogdet round-off (±5e-11, its sign depending on the BLAS build).
    x = x - x[0]
    x = x - x.mean(axis=0)
    c = x.T @ x / len(x)
    va, vb = np.trace(c[:k, :k]) / k, np.trace(c[k:, k:]) / k
    if va <= 0 or vb <= 0:
        return 0.0
    c[:k, :k] += e * va * np.eye(k)
    c[k:, k:] += e * vb * np.eye(k)
    _, ld = np.linalg.slogdet(c)
    _, la = np.linalg.slogdet(c[:k, :k])
    _, lb = np.linalg.slogdet(c[k:, k:])
    rmi = max(0.5 * (la + lb - ld), 0.0)
    return float(1.0 - np.exp(-2.0 * rmi / k))
