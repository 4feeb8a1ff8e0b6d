"""Gradient-based metrics of thesis §6.2.3: GD, GC, GI, GO (numpy references).

Gradients ``g = (E_u, E_v)`` of both images come from a first-derivative operator of
:mod:`core.imaging.edges` (default Sobel, gain-normalised, borders replicate) on the whole ROI,
then are compared over Ω. Magnitudes are Euclidean, ``|g| = sqrt(E_u² + E_v²)``. Orientations are
taken modulo π (bone dark on bright in one image and bright on dark in the other still agree):
the angle ``Δ ∈ [0, π/2]`` between the two orientations is ``acos(|g_D · g_F| / (|g_D| |g_F|))``.
Gradients with ``|g| <= 1e-6 · max(1, max|image|)`` (rounding noise on a flat image) count as
zero; pixels where either gradient is zero have no orientation and weight 0.
"""

from __future__ import annotations

import numpy as np

from ..imaging.edges import FIRST_DERIVATIVE_OPERATORS, gradient
from .domain import prepare
from .intensity import concordance, pearson

__all__ = [
    "GO_RANDOM_WEIGHT",
    "GRADIENT_OPERATORS",
    "gradient_correlation",
    "gradient_difference",
    "gradient_information",
    "gradient_orientation",
]

#: mean of De Silva's weight (2 - ln(1 + Δ)) / 2 for Δ uniform on [0, π/2] (unrelated orientations)
GO_RANDOM_WEIGHT = 1.0 - ((1 + np.pi / 2) * np.log1p(np.pi / 2) - np.pi / 2) / np.pi


#: relative size below which a gradient magnitude is rounding noise (see the module docs)
ZERO_GRADIENT = 1e-6

#: operators the gradient metrics accept (fixed kernels; smooth the fluoroscope with fluoro_sigma)
GRADIENT_OPERATORS = tuple(op for op in FIRST_DERIVATIVE_OPERATORS if op != "gaussian")


def _gradients(drr, fluoro, operator: str, domain_options: dict):
    if operator not in GRADIENT_OPERATORS:
        raise ValueError(f"operator: expected one of {GRADIENT_OPERATORS}, got {operator!r}")
    d, f, om = prepare(drr, fluoro, **domain_options)
    out = []
    for img in (d, f):
        gu, gv = gradient(img, operator=operator)
        gu, gv = gu[om], gv[om]
        flat = np.hypot(gu, gv) <= ZERO_GRADIENT * max(1.0, float(np.abs(img).max()))
        out.append((np.where(flat, 0.0, gu), np.where(flat, 0.0, gv)))
    return out[0], out[1]


def _cos2(gd, gf) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(|g_D|, |g_F|, cos²Δ)`` with cos²Δ = 0 where either gradient vanishes."""
    md, mf = np.hypot(*gd), np.hypot(*gf)
    dot = gd[0] * gf[0] + gd[1] * gf[1]
    den = (md * mf) ** 2
    c2 = np.divide(dot * dot, den, out=np.zeros_like(dot), where=den > 0)
    return md, mf, np.minimum(c2, 1.0)


def gradient_difference(drr, fluoro, *, operator: str = "sobel", **domain_options) -> float:
    """Gradient difference (eq. 6.10): SID of the gradient magnitudes, normalised as :func:`sid`.

    ``1 - Σ_Ω (|g_D| - |g_F|)² / E_perm[…]`` (Lin's concordance of the magnitudes). Range [-1, 1];
    0.0 for an empty Ω or constant, equal magnitudes.
    """
    gd, gf = _gradients(drr, fluoro, operator, domain_options)
    return concordance(np.hypot(*gd), np.hypot(*gf))


def gradient_correlation(drr, fluoro, *, operator: str = "sobel", components: bool = False,
                         **domain_options) -> float:
    """Gradient correlation (eq. 6.11): NCC of the gradient magnitudes over Ω. Range [-1, 1].

    With ``components=True``, Penney's form instead: the mean of the NCCs of the u and of the v
    derivative images over Ω, ``(r(E_u^D, E_u^F) + r(E_v^D, E_v^F)) / 2``. Zero-mean noise in the
    fluoroscope adds to its components without bias, whereas it inflates every magnitude (more
    where the signal is weak); the components keep the gradients' signs.
    """
    gd, gf = _gradients(drr, fluoro, operator, domain_options)
    if components:
        return 0.5 * (pearson(gd[0], gf[0]) + pearson(gd[1], gf[1]))
    return pearson(np.hypot(*gd), np.hypot(*gf))


def gradient_information(drr, fluoro, *, operator: str = "sobel", **domain_options) -> float:
    """Gradient information (De Silva / Pluim; eq. 6.12), centred and scale-free.

    ``GI = (1/N) Σ_Ω cos(2Δ) · min(|g_D| / m_D, |g_F| / m_F)`` with ``m`` the mean magnitude of
    each image over Ω. Dividing by the means makes GI independent of either image's intensity
    scale (DRR line integrals and fluoroscope values differ in gain); ``cos 2Δ = 2 w - 1`` is the
    thesis weight ``w = (cos Δ' + 1)/2`` taken with orientations modulo π (``Δ' = 2Δ``) and centred
    so that random orientations average 0. An image against itself scores 1; range [-1, 1]
    (bounded by ``mean min(...) <= 1``); 0.0 when either image has no gradient on Ω.
    """
    gd, gf = _gradients(drr, fluoro, operator, domain_options)
    md, mf, c2 = _cos2(gd, gf)
    if md.size == 0 or md.mean() <= 0 or mf.mean() <= 0:
        return 0.0
    m = np.minimum(md / md.mean(), mf / mf.mean())
    return float(np.mean((2.0 * c2 - 1.0) * m))


def gradient_orientation(drr, fluoro, *, operator: str = "sobel", n_lb_fraction: float = 0.25,
                         **domain_options) -> float:
    """Gradient orientation (De Silva; eq. 6.13), centred.

    Pixels of Ω whose gradient magnitude exceeds the median over Ω in *both* images form the set
    S. Each contributes De Silva's log weight ``w' = (2 - ln(1 + Δ)) / 2`` (Δ in radians, ≤ π/2
    with orientations modulo π), centred as ``(w' - w̄) / (1 - w̄)`` with ``w̄`` =
    :data:`GO_RANDOM_WEIGHT` (its mean over random orientations), and
    ``GO = Σ_S … / max(|S|, N_lb)`` with ``N_lb = n_lb_fraction · |Ω|`` (default ¼: the expected
    size of S for unrelated images), which stops a handful of coincident edge pixels from scoring
    high. An image against itself scores 1 (|S| ≈ |Ω|/2 ≥ N_lb), unrelated images ≈ 0. Range
    ``[(1 - ln(1 + π/2)/2 - w̄)/(1 - w̄), 1] ≈ [-0.73, 1]``; 0.0 for an empty S.
    """
    fr = float(n_lb_fraction)
    if not 0 <= fr <= 1:
        raise ValueError(f"n_lb_fraction: expected a fraction of |Ω| in [0, 1], got {n_lb_fraction!r}")
    gd, gf = _gradients(drr, fluoro, operator, domain_options)
    md, mf, c2 = _cos2(gd, gf)
    if md.size == 0:
        return 0.0
    sel = (md > np.median(md)) & (mf > np.median(mf))
    n_sel = int(sel.sum())
    if n_sel == 0:
        return 0.0
    delta = np.arccos(np.sqrt(c2[sel]))
    w = (2.0 - np.log1p(delta)) / 2.0
    c = (w - GO_RANDOM_WEIGHT) / (1.0 - GO_RANDOM_WEIGHT)
    return float(c.sum() / max(n_sel, fr * md.size))
