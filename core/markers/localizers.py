"""The six marker localizers of thesis §4.2, vectorised over many windows.

Each function works on a stack of windows of the bead **signal** ``s = background - image``
(dark beads positive; :func:`core.markers.batch.localize` cuts the windows from the frames and
subtracts the background, the median of the window's outer frame) and returns offsets from the
window's centre pixel. Window coordinates: ``x`` = column offset, ``y`` = row offset from the
centre pixel, in pixels. ``g (M, 2)`` is the initial guess relative to the same centre.

* :func:`intensity_centroid` — Eq. 4.1: ``x̂ = Σ x s / Σ s`` over the disc of radius ``h``
  about the guess (negative signal clipped to 0, as a dark-bead centre of gravity needs).
* :func:`gaussian_centroid` — Eq. 4.2/4.3: weights ``W = exp(-d²/σ²)`` centred on the guess.
* :func:`iterative_gaussian` — 4.2.3: the same, re-centred on each new estimate until it moves
  less than ``tol`` px.
* :func:`iterative_sigmoid` — 4.2.4 (Borlin): weights ``1 / (1 + exp(β (d - α)))``, iterated.
* :func:`template_match` — 4.2.5/4.2.6: cross-correlation with a Gaussian or sigmoid template
  and sub-pixel peak location by the upsampled DFT of Guizar-Sicairos et al. (2008),
  :func:`core.markers.dft.register_translation`.

Uncertainties are first-order propagations of white pixel noise σ_n through each estimator:
``var(x̂) = σ_n² Σ_i (∂x̂/∂s_i)²`` for the centroids (ignoring clipping and the iteration), and
the matched-filter bound ``σ_n² / (a² Σ (∂T/∂x)²)`` for template matching (``a`` = template
amplitude). They are lower bounds when the noise is blurred (spatially correlated).
"""

from __future__ import annotations

import numpy as np

from .dft import register_translation
from .profiles import gaussian_sigma, sigmoid_profile
from .results import STATUS

__all__ = [
    "gaussian_centroid",
    "intensity_centroid",
    "iterative_gaussian",
    "iterative_sigmoid",
    "template_match",
]


def _grid(size: int) -> tuple[np.ndarray, np.ndarray]:
    h = size // 2
    off = np.arange(-h, h + 1, dtype=np.float64)
    return off[None, None, :], off[None, :, None]  # x (1,1,S), y (1,S,1)


def _weighted(sig, w, noise):
    """Weighted centroid of ``sig`` with weights ``w`` (both (M, S, S)) and its white-noise σ."""
    x, y = _grid(sig.shape[-1])
    sw = w * sig
    tot = sw.sum(axis=(1, 2))
    good = tot > 0
    tot_safe = np.where(good, tot, 1.0)
    cx = (sw * x).sum(axis=(1, 2)) / tot_safe
    cy = (sw * y).sum(axis=(1, 2)) / tot_safe
    # d x̂ / d s_i = w_i (x_i - x̂) / Σ w s
    vx = ((w * (x - cx[:, None, None])) ** 2).sum(axis=(1, 2))
    vy = ((w * (y - cy[:, None, None])) ** 2).sum(axis=(1, 2))
    sig_uv = noise[:, None] * np.sqrt(np.stack([vx, vy], axis=1)) / tot_safe[:, None]
    return np.stack([cx, cy], axis=1), sig_uv, good


def _disc(size: int, c: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Squared distances (M, S, S) from centres ``c (M, 2)`` and the disc mask ``d <= h``."""
    x, y = _grid(size)
    d2 = (x - c[:, 0, None, None]) ** 2 + (y - c[:, 1, None, None]) ** 2
    return d2, d2 <= h * h


def intensity_centroid(sig, g, radius, h: int, noise):
    """Eq. 4.1: intensity-weighted centre of gravity in the disc of radius ``h`` about ``g``.

    Returns ``(offset (M, 2), sigma (M, 2), status (M,), iterations (M,))``.
    """
    _, mask = _disc(sig.shape[-1], g, h)
    pos = np.clip(sig, 0.0, None)
    c, s, good = _weighted(pos, mask.astype(np.float64), noise)
    status = np.where(good, STATUS["ok"], STATUS["flat"]).astype(np.int8)
    return c, s, status, np.ones(len(sig), np.int32)


def gaussian_centroid(sig, g, radius, h: int, noise):
    """Eq. 4.2/4.3: Gaussian-weighted centre of gravity, weights centred on the guess ``g``."""
    d2, mask = _disc(sig.shape[-1], g, h)
    s2 = gaussian_sigma(radius)[:, None, None] ** 2
    w = np.exp(-d2 / s2) * mask
    c, s, good = _weighted(np.clip(sig, 0.0, None), w, noise)
    status = np.where(good, STATUS["ok"], STATUS["flat"]).astype(np.int8)
    return c, s, status, np.ones(len(sig), np.int32)


def _iterate(sig, g, radius, h: int, noise, weight, tol: float, max_iter: int):
    """Re-centred weighted centroid (4.2.3 / 4.2.4) on the active set until the shift < tol."""
    M, S = len(sig), sig.shape[-1]
    H = S // 2
    pos = np.clip(sig, 0.0, None)
    c = np.array(g, dtype=np.float64, copy=True)
    sigma = np.full((M, 2), np.nan)
    status = np.full(M, STATUS["diverged"], np.int8)
    iters = np.zeros(M, np.int32)
    active = np.arange(M)
    for it in range(1, max_iter + 1):
        ca = c[active]
        d2, mask = _disc(S, ca, h)
        w = weight(d2, radius[active]) * mask
        new, sg, good = _weighted(pos[active], w, noise[active])
        shift = np.hypot(*(new - ca).T)
        iters[active] = it
        flat = ~good
        status[active[flat]] = STATUS["flat"]
        left = good & (np.abs(new).max(axis=1) > H - h)
        status[active[left]] = STATUS["diverged"]
        c[active[good]] = new[good]
        done = good & ~left & (shift < tol)
        status[active[done]] = STATUS["ok"]
        sigma[active[good]] = sg[good]
        active = active[good & ~left & ~done]
        if active.size == 0:
            break
    return c, sigma, status, iters


def iterative_gaussian(sig, g, radius, h: int, noise, *, tol: float = 0.01, max_iter: int = 100):
    """4.2.3: Gaussian-weighted centroid re-centred until the estimate moves < ``tol`` px.

    An estimate that leaves the window (``|offset| > H - h``) or needs more than ``max_iter``
    iterations is flagged ``"diverged"``.
    """
    def weight(d2, r):
        return np.exp(-d2 / gaussian_sigma(r)[:, None, None] ** 2)

    return _iterate(sig, g, radius, h, noise, weight, tol, max_iter)


def iterative_sigmoid(sig, g, radius, h: int, noise, *, beta: float = 1.5, tol: float = 0.01,
                      max_iter: int = 100):
    """4.2.4: sigmoid-weighted centroid (α = radius, β in 1/px) iterated like 4.2.3."""
    def weight(d2, r):
        return sigmoid_profile(np.sqrt(d2), r[:, None, None], beta)

    return _iterate(sig, g, radius, h, noise, weight, tol, max_iter)


def template_match(sig, g, radius, h: int, noise, *, template: str = "gaussian",
                   beta: float = 1.5, upsample: int = 100):
    """4.2.5 / 4.2.6: template matching with sub-pixel DFT registration (Guizar-Sicairos).

    The ``(2h+1)²`` patch centred on the window centre (the rounded guess) is registered to a
    template of the bead centred in the same patch; the bead centre is the patch centre plus the
    registered shift (precision ``1/upsample`` px). ``template`` is ``"gaussian"`` (Eq. 4.3) or
    ``"sigmoid"`` (Eq. 4.4).
    """
    if template not in ("gaussian", "sigmoid"):
        raise ValueError(f"template: expected 'gaussian' or 'sigmoid', got {template!r}")
    H = sig.shape[-1] // 2
    patch = sig[:, H - h : H + h + 1, H - h : H + h + 1]
    zero = np.zeros((len(sig), 2))
    d2, _ = _disc(2 * h + 1, zero, h)
    r = radius[:, None, None]
    if template == "gaussian":
        tpl = np.exp(-d2 / gaussian_sigma(r) ** 2)
    else:
        tpl = sigmoid_profile(np.sqrt(d2), r, beta)
    shift = register_translation(patch, tpl, upsample=upsample)  # (M, 2) as (dx, dy)
    # matched-filter bound on the position variance
    amp = (patch * tpl).sum(axis=(1, 2)) / (tpl * tpl).sum(axis=(1, 2))
    gy, gx = np.gradient(tpl, axis=(1, 2))
    with np.errstate(divide="ignore", invalid="ignore"):
        sx = noise / (np.abs(amp) * np.sqrt((gx * gx).sum(axis=(1, 2))))
        sy = noise / (np.abs(amp) * np.sqrt((gy * gy).sum(axis=(1, 2))))
    status = np.where(np.abs(shift).max(axis=1) > h, STATUS["diverged"], STATUS["ok"])
    status = np.where(amp > 0, status, STATUS["flat"]).astype(np.int8)
    return shift, np.stack([sx, sy], axis=1), status, np.ones(len(sig), np.int32)
