"""Gradient-based metrics of thesis §6.2.3: GD, GC, GI, GO (numpy references).

Gradients ``g = (E_u, E_v)`` of both images come from a first-derivative operator of
:mod:`core.imaging.edges` (default Sobel, gain-normalised, borders replicate) on the whole ROI,
then are compared over Ω. Magnitudes are Euclidean, ``|g| = sqrt(E_u² + E_v²)``. Orientations are
taken modulo π (bone dark on bright in one image and bright on dark in the other still agree):
the angle ``Δ ∈ [0, π/2]`` between the two orientations is ``acos(|g_D · g_F| / (|g_D| |g_F|))``.
Gradients with ``|g| <= 1e-6 · max(1, max|image|)`` (rounding noise on a flat image) count as
zero; pixels where either gradient is zero have no orientation and weight 0.

Noise in the fluoroscope adds to its gradient *magnitudes* on average (``E|g + n|² = |g|² +
E|n|²``), more where fewer photons arrive (behind dense bone), so a correlation of magnitudes
favours poses that put the DRR's edges there. :func:`gradient_correlation`'s ``noise_energy``
takes that share out (debiased magnitudes); :func:`noise_gradient_energy` measures it from two
flat frames (the photon transfer of the chain, detector blur included) and
:func:`quantum_noise_energy` maps it over a frame (quantum noise: ``var(-ln F) ≈ 1/(N F)``).
On the harder acceptance trial this pedestal is what moves the optimum under noise, and the
debiased magnitudes take out about 60 % (tibia) to all (talus) of its mean shift at 512²
(:mod:`core.studies.tracking.gc_noise_bias`); ``sqrt(max(m² - E, 0))`` still leaves about a
third of a pure-noise pixel's pedestal.
"""

from __future__ import annotations

import math

import numpy as np

from ..imaging.edges import FIRST_DERIVATIVE_OPERATORS, gradient
from .domain import prepare
from .intensity import concordance, pearson

__all__ = [
    "GO_RANDOM_WEIGHT",
    "GRADIENT_OPERATORS",
    "debiased_magnitude",
    "frame_noise_energy",
    "gradient_correlation",
    "gradient_difference",
    "gradient_information",
    "gradient_orientation",
    "noise_energy_of_samples",
    "noise_gradient_energy",
    "noise_samples",
    "quantum_noise_energy",
    "white_noise_gradient_gain",
]

#: mean of De Silva's weight (2 - ln(1 + Δ)) / 2 for Δ uniform on [0, π/2] (unrelated orientations)
GO_RANDOM_WEIGHT = 1.0 - ((1 + np.pi / 2) * np.log1p(np.pi / 2) - np.pi / 2) / np.pi


#: relative size below which a gradient magnitude is rounding noise (see the module docs)
ZERO_GRADIENT = 1e-6

#: operators the gradient metrics accept (fixed kernels; smooth the fluoroscope with fluoro_sigma)
GRADIENT_OPERATORS = tuple(op for op in FIRST_DERIVATIVE_OPERATORS if op != "gaussian")


def _gradients(drr, fluoro, operator: str, domain_options: dict, *, omega: bool = False):
    if operator not in GRADIENT_OPERATORS:
        raise ValueError(f"operator: expected one of {GRADIENT_OPERATORS}, got {operator!r}")
    d, f, om = prepare(drr, fluoro, **domain_options)
    out = []
    for img in (d, f):
        gu, gv = gradient(img, operator=operator)
        gu, gv = gu[om], gv[om]
        flat = np.hypot(gu, gv) <= ZERO_GRADIENT * max(1.0, float(np.abs(img).max()))
        out.append((np.where(flat, 0.0, gu), np.where(flat, 0.0, gv)))
    return (out[0], out[1], om) if omega else (out[0], out[1])


def _smoothed_gradient(img: np.ndarray, sigma: float, operator: str) -> tuple[np.ndarray, np.ndarray]:
    from scipy import ndimage

    img = np.asarray(img, dtype=np.float64)
    if sigma > 0:
        img = ndimage.gaussian_filter(img, sigma, mode="nearest")
    return gradient(img, operator=operator)


def white_noise_gradient_gain(*, fluoro_sigma: float = 0.0, operator: str = "sobel") -> float:
    """``E|g_n|² / var(n)`` for white noise ``n`` of variance ``var(n)``: the energy of the
    derivative filter (Gaussian of ``fluoro_sigma`` px, then ``operator``), ``Σ h_u² + h_v²``.

    With quantum noise alone (no detector blur) and ``N`` quanta per pixel at full fluence, the
    line-integral image's noise has ``var ≈ 1/(N F)``: ``gain / N`` is the noise energy of a
    flat frame (:func:`quantum_noise_energy`'s ``flat_energy``)."""
    if operator not in GRADIENT_OPERATORS:
        raise ValueError(f"operator: expected one of {GRADIENT_OPERATORS}, got {operator!r}")
    s = float(fluoro_sigma)
    if not (np.isfinite(s) and s >= 0):
        raise ValueError(f"fluoro_sigma: expected a non-negative number, got {fluoro_sigma!r}")
    n = 2 * (int(4 * s + 0.5) + 3) + 1
    delta = np.zeros((n, n))
    delta[n // 2, n // 2] = 1.0
    gu, gv = _smoothed_gradient(delta, s, operator)
    return float(np.sum(gu * gu + gv * gv))


def noise_gradient_energy(flat_a, flat_b, *, fluoro_sigma: float = 0.0, operator: str = "sobel",
                          mask=None, margin: int = 8) -> float:
    """Expected squared gradient magnitude ``E|g_n|²`` of a fluoroscope's noise at full fluence,
    measured from two uniform frames of the same dose — a calibration's photon transfer.

    Both are flatfield-normalised fluence (after the same corrections as the tracked frames),
    unclipped: two of the flatfield's empty-field frames as ``(DN - dark) / G`` without the clip
    at 1 (clipped, they lose half their noise), or two frames through a uniform plate. Their
    line integrals' difference holds twice the noise and none of the (shared) structure:
    ``E|g_n|² = F̄ · mean |∇(G_σ ∗ (y_a - y_b))|² / 2``
    over ``mask`` (default where both frames exceed 0.05, ``margin`` px from the border and the
    mask's edge), with the smoothing and operator of the metric, scaled by their mean fluence
    ``F̄`` to full fluence (quantum noise: ``var(-ln F) ∝ 1/F``). It includes the detector's
    blur (correlated noise), which a per-pixel variance would miss."""
    from scipy import ndimage

    a, b = (np.asarray(x, dtype=np.float64) for x in (flat_a, flat_b))
    if a.ndim != 2 or a.shape != b.shape:
        raise ValueError(f"flat_a, flat_b: expected two 2-D frames of one shape, got {a.shape}, {b.shape}")
    ok = (a > 0.05) & (b > 0.05) if mask is None else np.asarray(mask, dtype=bool)
    if ok.shape != a.shape:
        raise ValueError(f"mask: expected shape {a.shape}, got {ok.shape}")
    m = int(margin)
    if m > 0:
        ok = ndimage.binary_erosion(ok, iterations=m, border_value=0)
    if not ok.any():
        raise ValueError("flat_a, flat_b: no usable pixels (fluence above 0.05, inside the margin)")
    la, lb = np.log(np.clip(a, 1e-6, None)), np.log(np.clip(b, 1e-6, None))
    gu, gv = _smoothed_gradient(lb - la, float(fluoro_sigma), operator)
    fbar = float(np.mean(0.5 * (a + b)[ok]))
    return fbar * float(np.mean((gu * gu + gv * gv)[ok])) / 2.0


#: :func:`frame_noise_energy`'s defaults: the brightest quarter of the usable points of a lattice of
#: about 16 384 points (8-pixel steps in a 1024² view, 1-8 pixels), their median of ``|g|² F``, at
#: most 2048 of them
NOISE_BRIGHT_FRACTION = 0.25
NOISE_QUANTILE = 0.5
NOISE_LATTICE = 16384
NOISE_SAMPLES = 2048


def _patch_radius(fluoro_sigma: float) -> int:
    """Half-width of the patch that holds the smoothing (4σ) and the 3 × 3 operator."""
    return (int(4.0 * float(fluoro_sigma) + 0.5) if fluoro_sigma > 0 else 0) + 1


def noise_samples(fluence, *, radius: int, mask=None, valid_range: tuple[float, float] | None = (0.02, 0.999),
                  bright_fraction: float = NOISE_BRIGHT_FRACTION, step: int | None = None,
                  max_samples: int = NOISE_SAMPLES) -> np.ndarray:
    """``(n, (2 radius + 1)²)`` float32: the line integrals ``-ln F`` of square patches about the
    brightest ``bright_fraction`` of the usable points of a ``step``-pixel lattice (default: about
    :data:`NOISE_LATTICE` points, 1-8 pixels apart; at most ``max_samples``, evenly thinned):
    points ``radius`` pixels inside the frame, inside ``mask``, whose whole patch lies inside
    ``valid_range`` (clipped or black pixels have lost their noise).
    :func:`noise_energy_of_samples` turns them into ``E₁`` at any smoothing that fits the patch."""
    f = np.asarray(fluence, dtype=np.float32)
    if f.ndim != 2:
        raise ValueError(f"fluence: expected a 2-D flatfield-normalised frame, got shape {f.shape}")
    if not 0 < bright_fraction <= 1:
        raise ValueError(f"bright_fraction: expected a fraction in (0, 1], got {bright_fraction!r}")
    R = int(radius)
    H, W = f.shape
    k = 2 * R + 1
    empty = np.zeros((0, k * k), np.float32)
    if H < k or W < k:
        return empty
    st = int(step) if step is not None else int(min(8, max(1, math.isqrt(H * W // NOISE_LATTICE))))
    grid = f[R:H - R:st, R:W - R:st]
    gw = grid.shape[1]
    F = grid.ravel()
    ok = np.isfinite(F)
    if valid_range is not None:
        ok &= (F > valid_range[0]) & (F < valid_range[1])
    if mask is not None:
        m = np.asarray(mask, dtype=bool)
        if m.shape != f.shape:
            raise ValueError(f"mask: expected shape {f.shape}, got {m.shape}")
        ok &= m[R:H - R:st, R:W - R:st].ravel()
    pts = np.flatnonzero(ok)
    if not len(pts):
        return empty
    n = max(round(bright_fraction * len(pts)), 1)
    if n < len(pts):
        pts = np.sort(pts[np.argpartition(-F[pts], n - 1)[:n]])
    if len(pts) > max_samples:  # evenly thinned over the frame
        pts = pts[np.linspace(0, len(pts) - 1, int(max_samples)).astype(np.int64)]
    # the patch about lattice point (i, j) starts at pixel (i·st, j·st): one flat gather of the
    # patches' pixels (a tenth of the time of indexing a sliding-window view)
    off = (np.arange(k, dtype=np.intp)[:, None] * W + np.arange(k, dtype=np.intp)[None, :]).ravel()
    start = (pts // gw) * (st * W) + (pts % gw) * st
    P = np.ascontiguousarray(f).ravel().take(start[:, None] + off[None, :])
    if valid_range is not None:  # every pixel of the patch inside the open interval
        P = P[(P.min(axis=1) > valid_range[0]) & (P.max(axis=1) < valid_range[1])]
    np.clip(P, 1.0 / 4096, 1.0, out=P)
    np.log(P, out=P)
    np.negative(P, out=P)
    return P


_KERNELS: dict = {}


def _patch_kernels(fluoro_sigma: float, operator: str, radius: int) -> np.ndarray:
    """``(k², 3)``: the weights of a ``(2 radius + 1)²`` patch (row-major) giving the smoothed value
    and the two components of the smoothed gradient at its centre (the correlation of the Gaussian
    of ``fluoro_sigma`` px, truncated at 4σ, and ``operator``)."""
    key = (round(float(fluoro_sigma), 6), operator, int(radius))
    hit = _KERNELS.get(key)
    if hit is None:
        k = 2 * int(radius) + 1
        ys, gu, gv = _smoothed_delta(k, float(fluoro_sigma), operator)
        # a correlation filter applied to a delta is the flipped weights
        hit = np.stack([a[::-1, ::-1].ravel() for a in (ys, gu, gv)], axis=1)
        if len(_KERNELS) >= 64:
            _KERNELS.pop(next(iter(_KERNELS)))
        _KERNELS[key] = hit
    return hit


def _smoothed_delta(k: int, sigma: float, operator: str):
    """``(G_σ ∗ δ, its u and v gradients)`` of a centred delta in a ``k × k`` patch: the Gaussian
    (truncated at 4σ, zero outside) as the outer product of its 1-D weights, which is what
    :func:`scipy.ndimage.gaussian_filter` (``mode="constant"``) gives for a delta, without its
    2-D passes."""
    from scipy import ndimage

    c = k // 2
    if sigma > 0:
        d = np.zeros(k)
        d[c] = 1.0
        g = ndimage.gaussian_filter1d(d, sigma, mode="constant", truncate=4.0)
        img = np.outer(g, g)
    else:
        img = np.zeros((k, k))
        img[c, c] = 1.0
    gu, gv = gradient(img, operator=operator)
    return img, gu, gv


def noise_energy_of_samples(samples, *, fluoro_sigma: float = 0.0, operator: str = "sobel",
                            quantile: float = NOISE_QUANTILE) -> float:
    """``E₁`` from :func:`noise_samples`' patches: the ``quantile`` of ``q = |g|² F_s`` at their
    centres (``g`` the gradient after the smoothing of ``fluoro_sigma`` px and ``operator``,
    ``F_s = exp(-G_σ ∗ y)``) over that quantile of the unit exponential, ``-ln(1 - quantile)``
    (:func:`frame_noise_energy`). 0.0 for fewer than 100 patches."""
    if operator not in GRADIENT_OPERATORS:
        raise ValueError(f"operator: expected one of {GRADIENT_OPERATORS}, got {operator!r}")
    if not 0 < quantile < 1:
        raise ValueError(f"quantile: expected a fraction in (0, 1), got {quantile!r}")
    P = np.asarray(samples, dtype=np.float32)
    if P.ndim != 2 or len(P) < 100:
        return 0.0
    R = (math.isqrt(P.shape[1]) - 1) // 2
    if _patch_radius(fluoro_sigma) > R:
        raise ValueError(f"samples: patches of radius {R} are too small for fluoro_sigma {fluoro_sigma!r}")
    K = _patch_kernels(fluoro_sigma, operator, R).astype(np.float32)
    Z = P @ K
    q = (Z[:, 1] ** 2 + Z[:, 2] ** 2) * np.exp(-Z[:, 0])
    return float(np.quantile(q, quantile) / -np.log1p(-quantile))


def frame_noise_energy(fluence, *, fluoro_sigma: float = 0.0, operator: str = "sobel", mask=None,
                       valid_range: tuple[float, float] | None = (0.02, 0.999),
                       bright_fraction: float = NOISE_BRIGHT_FRACTION, quantile: float = NOISE_QUANTILE,
                       step: int | None = None, max_samples: int = NOISE_SAMPLES) -> float:
    """``E₁``, the expected squared gradient magnitude of a frame's quantum noise at full fluence
    (``E|g_n|² = E₁ / F``), estimated from the frame itself.

    The line integrals ``y = -ln F`` are smoothed by ``fluoro_sigma`` px and differentiated with
    ``operator`` as the metric does. Where the anatomy's own gradient is small against the
    noise's, ``q = |g|² F_s`` (``F_s = exp(-G_σ ∗ y)``) is ``E₁`` times a unit exponential
    variable (isotropic noise: two independent gradient components of equal variance), and
    anatomy only makes ``q`` larger. The estimate is the ``quantile`` (the median) of ``q`` over the
    brightest ``bright_fraction`` (a quarter) of the usable points of a ``step``-pixel lattice (8
    pixels at 1024², at most ``max_samples``; :func:`noise_samples`), divided by that quantile of
    the unit exponential, ``-ln(1 - quantile)``: soft tissue, where the anatomy's gradients are the
    weakest and the counts highest; ``q`` is computed at those points alone (a patch each,
    :func:`noise_energy_of_samples`), about a millisecond for a 1024² view. Inside bones the
    texture's gradients dominate: in the bones' search regions of the harder acceptance trial
    (512², 1 mm voxels, frames 1 and 6) a low quantile over all pixels gave 2-3 times the
    calibration's ``E₁`` (two plate frames, :func:`noise_gradient_energy`), the brightest quarter of
    the whole frame 0.92-1.08 times it (mean 0.99 over 16 frames, views and doses; median or 10 %
    or 25 % quantile alike; half the frame's pixels instead of a quarter: 1.15-1.7). A low quantile
    is hurt most by gradients of the anatomy present everywhere (a ramp of soft tissue), the
    median least. Usable: inside ``valid_range`` (open interval) over the whole patch and inside
    ``mask`` (True = usable) when given. Returns 0.0 when fewer than 100 points are usable.
    """
    s = float(fluoro_sigma)
    if not (np.isfinite(s) and s >= 0):
        raise ValueError(f"fluoro_sigma: expected a non-negative number, got {fluoro_sigma!r}")
    P = noise_samples(fluence, radius=_patch_radius(s), mask=mask, valid_range=valid_range,
                      bright_fraction=bright_fraction, step=step, max_samples=max_samples)
    return noise_energy_of_samples(P, fluoro_sigma=s, operator=operator, quantile=quantile)


def quantum_noise_energy(fluoro, flat_energy: float, *, smooth_px: float = 2.0) -> np.ndarray:
    """Per-pixel ``E|g_n|²`` of quantum noise over a frame: ``flat_energy / F``, ``F`` the
    frame's relative fluence smoothed by ``smooth_px`` (so a pixel's own noise does not set its
    correction), ``flat_energy`` the energy at full fluence (:func:`noise_gradient_energy` from
    flat frames, or :func:`white_noise_gradient_gain` / quanta per pixel).

    ``fluoro`` is the frame's flatfield-normalised fluence in [0, 1] (from a line integral ``y``:
    ``np.exp(-y)``); pixels of less fluence than ``1/4096`` get that floor's energy."""
    from scipy import ndimage

    f = np.asarray(fluoro, dtype=np.float64)
    e = float(flat_energy)
    if not (np.isfinite(e) and e >= 0):
        raise ValueError(f"flat_energy: expected a non-negative number, got {flat_energy!r}")
    if smooth_px > 0:
        f = ndimage.gaussian_filter(f, float(smooth_px), mode="nearest")
    return e / np.clip(f, 1.0 / 4096, None)


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


def debiased_magnitude(gu, gv, noise_energy) -> np.ndarray:
    """``sqrt(max(|g|² - E|g_n|², 0))``: a noisy gradient's magnitude with the noise's expected
    share taken out (``noise_energy`` a scalar or an array broadcasting with ``gu``)."""
    return np.sqrt(np.maximum(gu * gu + gv * gv - noise_energy, 0.0))


def _noise_map(noise_energy, shape) -> np.ndarray:
    e = np.asarray(noise_energy, dtype=np.float64)
    if e.ndim not in (0, 2) or (e.ndim == 2 and e.shape != shape):
        raise ValueError(f"noise_energy: expected a number or an array of the fluoroscope's shape {shape}, "
                         f"got shape {e.shape}")
    if not np.all(np.isfinite(e)) or np.any(e < 0):
        raise ValueError("noise_energy: expected finite, non-negative expected squared gradients")
    return e


def noise_per_ref(noise_energy, shapes) -> list[np.ndarray]:
    """``noise_energy`` given per view (or per view, a list per bone), as one checked map (or
    number) per ROI of ``shapes`` (:class:`core.similarity.BatchedMetric`'s ``noise_energy``)."""
    items = []
    for v in noise_energy:
        items.extend(v if isinstance(v, (list, tuple)) else [v])
    if len(items) != len(shapes):
        raise ValueError(f"noise_energy: expected one entry per fluoroscope ROI ({len(shapes)}), "
                         f"got {len(items)}")
    return [_noise_map(e, tuple(s)) for e, s in zip(items, shapes, strict=True)]


def gradient_correlation(drr, fluoro, *, operator: str = "sobel", components: bool = False,
                         noise_energy=None, **domain_options) -> float:
    """Gradient correlation (eq. 6.11): NCC of the gradient magnitudes over Ω. Range [-1, 1].

    With ``components=True``, Penney's form instead: the mean of the NCCs of the u and of the v
    derivative images over Ω, ``(r(E_u^D, E_u^F) + r(E_v^D, E_v^F)) / 2``. Zero-mean noise in the
    fluoroscope adds to its components without bias, whereas it inflates every magnitude (more
    where the signal is weak); the components keep the gradients' signs.

    ``noise_energy`` (magnitudes only): the expected squared gradient magnitude ``E|g_n|²`` that
    the fluoroscope's noise adds at each pixel (a number, or an array of the fluoroscope's shape;
    with this ``operator`` and after the ``fluoro_sigma`` smoothing: :func:`quantum_noise_energy`
    from a calibration's :func:`noise_gradient_energy`). The fluoroscope's magnitudes become
    :func:`debiased_magnitude`, ``sqrt(max(|g_F|² - E|g_n|², 0))``; the DRR's are left as they are.
    """
    if noise_energy is None:
        gd, gf = _gradients(drr, fluoro, operator, domain_options)
        if components:
            return 0.5 * (pearson(gd[0], gf[0]) + pearson(gd[1], gf[1]))
        return pearson(np.hypot(*gd), np.hypot(*gf))
    if components:
        raise ValueError("noise_energy: the components' form has no noise share to take out (give one or "
                         "the other)")
    e = _noise_map(noise_energy, np.shape(fluoro))
    gd, gf, om = _gradients(drr, fluoro, operator, domain_options, omega=True)
    if e.ndim == 2:
        e = e[om]
    return pearson(np.hypot(*gd), debiased_magnitude(gf[0], gf[1], e))


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
