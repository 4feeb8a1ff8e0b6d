"""The recommended localizer: a robust seed, then a least-squares bead-model fit (vectorised).

Thesis §4.3 found no algorithm that is both robust to a poor initial guess (the intensity
centroid) and precise under quantum noise (the iterative Gaussian). This localizer is both:

1. **Seed** (robust): the bead signal is filtered with a centre-surround box filter matched to
   the bead (mean over a ``(2a+1)²`` box minus the mean of the rest of a ``(2b+1)²`` box, ``a ≈ 0.6 r``,
   ``b = ceil(r) + 3``; OpenCV box filters, O(1) per pixel) and the seed is the strongest response within
   ``search_radius`` pixels of the guess. Broad structures (bone edges, large faint circles)
   cancel in the centre-surround difference; the seed is within a pixel of the bead centre for
   any guess inside the search disc (default 3.5 bead radii, i.e. beyond the 300 % of the
   thesis's Fig. 4.4).
2. **Fit** (precise): a bead model on a background plane is fitted by Levenberg–Marquardt
   (batched normal equations) to the ``(2k+1)²`` patch centred on the seed,
   ``k = ceil(r) + 3``; the patch is re-centred once when the fit moves by more than half a
   pixel. The default model is a sigmoid-edged disc (Borlin's profile, smooth in ρ²),
   ``f = b₀ + b_x x + b_y y + A / (1 + exp((ρ² - α²) / (2 α w)))``, ``ρ² = (x-u)² + (y-v)²``,
   with half-maximum radius α and edge width w — it matches the blurred chord profile of a
   sphere closely, so the residuals are noise and the covariance is honest; ``"gaussian"``
   (``A exp(-ρ²/2σ²)``) is the alternative. Both are rotationally symmetric, so the centre is
   unbiased; the plane absorbs background gradients that bias weighted centroids.
3. **Uncertainty**: the least-squares covariance ``σ̂² (JᵀJ)⁻¹`` assumes white noise; fluoroscope
   noise is blurred by the intensifier's PSF, so the variance of the linear estimator
   ``w = (JᵀJ)⁻¹Jᵀ`` is evaluated with the residuals' own spatial autocorrelation up to lag 2
   (a sandwich estimate). The harness (:mod:`core.studies.markers.study`) compares it with the observed
   scatter.

Failures: ``"flat"`` when the seed's matched-filter response is below ``min_snr`` times its
noise; ``"bad_fit"`` for a non-positive amplitude, a singular system or a width out of range
(Gaussian σ outside ``[0.25 r, 3 r]``; sigmoid α > 3 r, w > 2 r or α + w < 0.25 r);
``"diverged"`` when the fitted centre leaves the search disc (plus one pixel) or the fit did
not converge.
"""

from __future__ import annotations

import cv2
import numpy as np

from .results import STATUS

__all__ = ["fit_half_size", "robust_fit", "seed_by_matched_filter", "seed_margin"]

_MAX_ITER = 30
_STEP_TOL = 2e-3  # px: a fit stops when the centre moves less than this (next step ~1e-5)


def fit_half_size(radius_px: float) -> int:
    """Half-size ``k`` of the fitted patch: ``ceil(r) + 3`` pixels."""
    return int(np.ceil(float(radius_px))) + 3


def _box_means(sig: np.ndarray, a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
    """Means over ``(2a+1)²`` and ``(2b+1)²`` boxes centred on the pixels ``b..S-1-b`` of each
    window (``(M, S-2b, S-2b)`` each).

    The windows are stacked into one tall image for OpenCV's box filter; boxes centred at least
    ``b`` pixels inside a window never reach its neighbours in the stack, so the cropped result
    is exact.
    """
    M, S, _ = sig.shape
    tall = np.ascontiguousarray(sig, dtype=np.float32).reshape(M * S, S)
    out = []
    for h in (a, b):
        m = cv2.boxFilter(tall, cv2.CV_32F, (2 * h + 1, 2 * h + 1), normalize=True,
                          borderType=cv2.BORDER_REPLICATE)
        out.append(m.reshape(M, S, S)[:, b : S - b, b : S - b])
    return out[0], out[1]


def _boxes(radius: float) -> tuple[int, int]:
    """Half-sizes of the seed's centre and surround boxes: ``round(0.6 r)``, ``ceil(r) + 3``."""
    a = max(1, round(0.6 * radius))
    return a, max(a + 2, int(np.ceil(radius)) + 3)


def seed_margin(radius: float) -> int:
    """Pixels a window needs beyond the search disc for the seed and the fit."""
    return max(_boxes(radius)[1], fit_half_size(radius)) + 1


def seed_by_matched_filter(sig: np.ndarray, g: np.ndarray, radius: float, search
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Seed of each window: integer ``(M, 2)`` offsets, sub-pixel part ``(M, 2)``, response and noise.

    Centre-surround box filter (see the module docs); the noise is the robust (MAD) spread of
    the response over the window, which includes the noise's spatial correlation.
    """
    M, S, _ = sig.shape
    a, b = _boxes(radius)
    inner, outer = _box_means(sig, a, b)
    n_out = (2 * b + 1) ** 2
    n_in = (2 * a + 1) ** 2
    # surround mean = (outer box sum - inner box sum) / (n_out - n_in)
    resp = inner - (outer * n_out - inner * n_in) / (n_out - n_in)
    n = S - 2 * b
    off = np.arange(n) - (n // 2)  # response pixel offsets from the window centre
    d2 = (off[None, None, :] - g[:, 0, None, None]) ** 2 + (off[None, :, None] - g[:, 1, None, None]) ** 2
    flat = resp.reshape(M, -1)
    sub = resp[:, ::3, ::3].reshape(M, -1)  # the noise from every third pixel is plenty
    med = np.median(sub, axis=1)
    noise = 1.4826 * np.median(np.abs(sub - med[:, None]), axis=1)
    s2 = np.broadcast_to(np.asarray(search, dtype=np.float64), (M,))[:, None, None] ** 2
    cand = np.where((d2 <= s2).reshape(M, -1), flat, -np.inf)
    idx = np.argmax(cand, axis=1)
    peak = np.take_along_axis(flat, idx[:, None], axis=1)[:, 0] - med
    iy, ix = idx // n, idx % n
    seed = np.stack([off[ix], off[iy]], axis=1).astype(np.int64)
    # parabolic sub-pixel refinement of the peak (start of the fit)
    m = np.arange(M)
    frac = np.zeros((M, 2))
    for ax, (i0, lo, hi) in enumerate(((ix, (iy, np.maximum(ix - 1, 0)), (iy, np.minimum(ix + 1, n - 1))),
                                       (iy, (np.maximum(iy - 1, 0), ix), (np.minimum(iy + 1, n - 1), ix)))):
        c0 = resp[m, iy, ix]
        cl, ch = resp[m, lo[0], lo[1]], resp[m, hi[0], hi[1]]
        den = cl - 2.0 * c0 + ch
        with np.errstate(divide="ignore", invalid="ignore"):
            f = np.where(den < 0, 0.5 * (cl - ch) / den, 0.0)
        inner = (i0 > 0) & (i0 < n - 1)
        frac[:, ax] = np.where(inner, np.clip(f, -0.5, 0.5), 0.0)
    return seed, frac, peak, noise


def _gaussian(p: np.ndarray, x: np.ndarray, y: np.ndarray):
    """Gaussian on a plane; ``p (M, 7)`` = (u, v, A, σ, b₀, b_x, b_y) -> f (M, P), J (M, 7, P).

    Evaluated in ``x.dtype`` (float32 in the hot path: half the memory traffic; the normal
    equations are solved in float64).
    """
    q = p.astype(x.dtype)
    u, v, A, s, b0, bx, by = (q[:, i, None] for i in range(7))
    dx, dy = x[None] - u, y[None] - v
    r2 = dx * dx + dy * dy
    inv = 1.0 / (s * s)
    e = np.exp(-0.5 * r2 * inv)
    Ae = A * e
    f = b0 + bx * x[None] + by * y[None] + Ae
    J = np.empty((f.shape[0], 7, f.shape[1]), x.dtype)
    J[:, 0] = Ae * dx * inv
    J[:, 1] = Ae * dy * inv
    J[:, 2] = e
    J[:, 3] = Ae * r2 * inv / s
    J[:, 4] = 1.0
    J[:, 5] = x[None]
    J[:, 6] = y[None]
    return f, J


def _sigmoid(p: np.ndarray, x: np.ndarray, y: np.ndarray):
    """Sigmoid-edged disc on a plane, ``A / (1 + exp((ρ² - α²) / (2 α w)))``, in ``x.dtype``.

    ``p (M, 8)`` = (u, v, A, α, w, b₀, b_x, b_y): half-maximum radius α and edge width w (px).
    """
    q = p.astype(x.dtype)
    u, v, A, a, w, b0, bx, by = (q[:, i, None] for i in range(8))
    dx, dy = x[None] - u, y[None] - v
    r2 = dx * dx + dy * dy
    z = np.clip((r2 - a * a) / (2.0 * a * w), -60.0, 60.0)
    g = 1.0 / (1.0 + np.exp(z))
    Agg = A * g * (1.0 - g)
    f = b0 + bx * x[None] + by * y[None] + A * g
    J = np.empty((f.shape[0], 8, f.shape[1]), x.dtype)
    t = Agg / (a * w)
    J[:, 0] = t * dx
    J[:, 1] = t * dy
    J[:, 2] = g
    J[:, 3] = t * (r2 + a * a) / (2.0 * a)
    J[:, 4] = Agg * z / w
    J[:, 5] = 1.0
    J[:, 6] = x[None]
    J[:, 7] = y[None]
    return f, J


_MODELS = {"gaussian": (_gaussian, 7), "sigmoid": (_sigmoid, 8)}


def _solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Batched solve of ``A x = b``; singular systems give NaN rows."""
    try:
        return np.linalg.solve(A, b[..., None])[..., 0]
    except np.linalg.LinAlgError:
        out = np.full(b.shape, np.nan)
        for i in range(len(A)):  # rare: isolate the singular systems
            try:
                out[i] = np.linalg.solve(A[i], b[i])
            except np.linalg.LinAlgError:
                pass
        return out


def _lm(data: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray, model):
    """Batched Levenberg–Marquardt; returns params, J, residuals, converged, singular, iterations.

    Works on whole arrays (views) while most items are still iterating and compacts the active
    set only once fewer than half remain, so that the common case copies nothing.
    """
    M, n = p.shape
    lam = np.full(M, 1e-3)
    f, J = model(p, x, y)
    res = f - data
    cost = np.einsum("mp,mp->m", res, res).astype(np.float64)
    conv = np.zeros(M, bool)
    sing = np.zeros(M, bool)
    iters = np.zeros(M, np.int32)
    act = np.arange(M)
    eye = np.eye(n)[None]
    for it in range(1, _MAX_ITER + 1):
        # whole arrays (views, no copies) while at least half the items iterate; then compact
        full = 2 * act.size >= M
        sel = slice(None) if full else act
        live = np.zeros(M, bool)
        live[act] = True
        live = live[sel]
        Ja, ra = J[sel], res[sel]
        JtJ = (Ja @ Ja.transpose(0, 2, 1)).astype(np.float64)
        Jtr = np.einsum("mip,mp->mi", Ja, ra).astype(np.float64)
        diag = np.einsum("mii->mi", JtJ)
        step = -_solve(JtJ + (lam[sel, None] * np.maximum(diag, 1e-12))[:, :, None] * eye, Jtr)
        bad = ~np.all(np.isfinite(step), axis=1) & live
        step[~np.all(np.isfinite(step), axis=1) | ~live] = 0.0
        pn = p[sel] + step
        pn[:, 3 : n - 3] = np.abs(pn[:, 3 : n - 3])
        fn, Jn = model(pn, x, y)
        rn = fn - data[sel]
        cn = np.einsum("mp,mp->m", rn, rn).astype(np.float64)
        ca = cost[sel]
        better = (cn <= ca) & ~bad & live
        small = np.abs(step[:, :2]).max(axis=1) < _STEP_TOL
        rel = np.abs(ca - cn) <= 1e-10 * np.maximum(ca, 1e-300)
        ids = np.arange(M)[sel]
        if full and better.all():
            p, J, res = pn, Jn, rn
        else:
            idx = ids[better]
            p[idx], J[idx], res[idx] = pn[better], Jn[better], rn[better]
        cost[ids[better]] = cn[better]
        la = lam[sel]
        lam[ids[live]] = np.where(better, np.maximum(la / 10.0, 1e-9), la * 10.0)[live]
        iters[ids[live]] = it
        sing[ids[bad]] = True
        stop = lam[sel] > 1e8
        done = live & ((better & small) | (rel & small) | bad | stop)
        conv[ids[done & ~bad & ~stop]] = True
        act = ids[live & ~done]
        if act.size == 0:
            break
    return p, J, res, conv, sing, iters


def _autocorr(res: np.ndarray, S: int, lag: int = 2) -> list[tuple[int, int, np.ndarray]]:
    """Residual autocorrelation ρ(dy, dx) per patch for the half-plane of lags up to ``lag``."""
    r = res.reshape(len(res), S, S)
    r = r - r.mean(axis=(1, 2), keepdims=True)
    var = np.einsum("mij,mij->m", r, r) / (S * S)
    out = []
    for dy in range(0, lag + 1):
        for dx in range(-lag, lag + 1):
            if dy == 0 and dx <= 0:
                continue
            a = r[:, dy:, max(dx, 0) : S + min(dx, 0)]
            b = r[:, : S - dy, max(-dx, 0) : S - max(dx, 0)]
            c = np.einsum("mij,mij->m", a, b) / a[0].size
            with np.errstate(invalid="ignore", divide="ignore"):
                out.append((dy, dx, np.where(var > 0, c / var, 0.0)))
    return out


def _sandwich_sigma(J: np.ndarray, res: np.ndarray, S: int) -> np.ndarray:
    """(M, 2) σ of (u, v) from the linearised estimator and the residual autocorrelation."""
    J = J.astype(np.float64)
    res = res.astype(np.float64)
    M, n, P = J.shape
    JtJ = J @ J.transpose(0, 2, 1)
    with np.errstate(invalid="ignore"):
        try:
            inv = np.linalg.inv(JtJ)
        except np.linalg.LinAlgError:
            inv = np.linalg.pinv(JtJ)
    W = (inv[:, :2, :] @ J).reshape(M, 2, S, S)  # estimator weights
    s2 = np.einsum("mp,mp->m", res, res) / max(P - n, 1)
    var = np.einsum("mkij,mkij->mk", W, W)
    for dy, dx, rho in _autocorr(res, S):
        a = W[:, :, dy:, max(dx, 0) : S + min(dx, 0)]
        b = W[:, :, : S - dy, max(-dx, 0) : S - max(dx, 0)]
        var += 2.0 * np.clip(rho, -1.0, 1.0)[:, None] * np.einsum("mkij,mkij->mk", a, b)
    return np.sqrt(np.maximum(var, 0.0) * s2[:, None])


def _cut(sig: np.ndarray, centre: np.ndarray, k: int) -> np.ndarray:
    """(M, (2k+1)²) patches of ``sig`` centred at window offsets ``centre (M, 2)``."""
    H = sig.shape[-1] // 2
    off = np.arange(-k, k + 1)
    rows = H + centre[:, 1:2] + off
    cols = H + centre[:, 0:1] + off
    m = np.arange(len(sig))[:, None, None]
    return sig[m, rows[:, :, None], cols[:, None, :]].reshape(len(sig), -1)


def robust_fit(sig: np.ndarray, g: np.ndarray, radius: np.ndarray, *, search,
               min_snr: float, model: str = "sigmoid"):
    """Seed + Gaussian-on-plane fit on windows of bead signal (see the module docs).

    Parameters
    ----------
    sig : (M, S, S) float64
        Bead signal (background minus image), windows centred on the rounded guesses; ``S``
        must be at least ``2 (max(search) + seed_margin(r)) + 1``.
    g : (M, 2)
        Guesses relative to the window centre pixel (x = column, y = row offset).
    radius : (M,)
        Projected bead radii, px.
    search : float or (M,) array
        Search radius about each guess, px.
    min_snr : float
        Minimum matched-filter signal-to-noise ratio of a bead.
    model : {"sigmoid", "gaussian"}
        Fitted bead profile (see the module docs).

    Returns
    -------
    offset (M, 2), sigma (M, 2), status (M,), iterations (M,), contrast (M,), snr (M,)
    """
    if model not in _MODELS:
        raise ValueError(f"model: expected one of {sorted(_MODELS)}, got {model!r}")
    fn, n = _MODELS[model]
    M, S, _ = sig.shape
    r_med = float(np.median(radius))
    k = fit_half_size(float(np.max(radius)))
    H = S // 2
    seed, frac, peak, rnoise = seed_by_matched_filter(sig, g, r_med, search)
    with np.errstate(divide="ignore", invalid="ignore"):
        snr = np.where(rnoise > 0, peak / rnoise, np.where(peak > 0, np.inf, 0.0))
    status = np.full(M, STATUS["ok"], np.int8)
    status[~(snr >= min_snr)] = STATUS["flat"]
    off = np.arange(-k, k + 1, dtype=sig.dtype if sig.dtype == np.float32 else np.float64)
    xs = np.tile(off, 2 * k + 1)
    ys = np.repeat(off, 2 * k + 1)
    centre = seed.copy()
    p = np.zeros((M, n))
    sigma = np.full((M, 2), np.nan)
    iters = np.zeros(M, np.int32)
    conv = np.zeros(M, bool)
    sing = np.zeros(M, bool)
    todo = np.flatnonzero(status == STATUS["ok"])
    for attempt in range(2):
        if todo.size == 0:
            break
        data = _cut(sig[todo], centre[todo], k)
        if attempt == 0:
            bg = np.median(data.reshape(-1, 2 * k + 1, 2 * k + 1)[:, [0, -1], :].reshape(len(todo), -1),
                           axis=1)
            c0 = data.reshape(-1, 2 * k + 1, 2 * k + 1)[:, k - 1 : k + 2, k - 1 : k + 2].mean(axis=(1, 2))
            shape = ([radius[todo] / 1.1774] if model == "gaussian"
                     else [radius[todo], np.full(len(todo), 0.6)])
            p[todo] = np.column_stack([frac[todo], c0 - bg, *shape, bg,
                                       np.zeros((len(todo), 2))])
        pt, J, res, cv, sg, it = _lm(data, xs, ys, p[todo].copy(), fn)
        p[todo], conv[todo], sing[todo] = pt, cv, sg
        iters[todo] += it
        sigma[todo] = _sandwich_sigma(J, res, 2 * k + 1)
        shift = np.rint(pt[:, :2]).astype(np.int64)
        move = np.any(shift != 0, axis=1) & np.all(np.isfinite(pt[:, :2]), axis=1)
        move &= np.all(np.abs(centre[todo] + shift) <= H - k, axis=1)
        redo = todo[move]
        centre[redo] += shift[move]
        p[redo, :2] -= shift[move]
        # the plane's offset moves with the patch centre
        p[redo, n - 3] += p[redo, n - 2] * shift[move, 0] + p[redo, n - 1] * shift[move, 1]
        todo = redo
    offset = centre + p[:, :2]
    ok = status == STATUS["ok"]
    if model == "gaussian":
        width_bad = (p[:, 3] < 0.25 * radius) | (p[:, 3] > 3.0 * radius)
    else:
        width_bad = (p[:, 3] + p[:, 4] < 0.25 * radius) | (p[:, 3] > 3.0 * radius) | (p[:, 4] > 2.0 * radius)
    status[ok & (sing | (p[:, 2] <= 0) | width_bad | ~np.all(np.isfinite(p), axis=1))] = STATUS["bad_fit"]
    ok = status == STATUS["ok"]
    far = np.hypot(*(offset - g).T) > np.asarray(search, dtype=np.float64) + 1.0
    status[ok & (far | ~conv)] = STATUS["diverged"]
    contrast = np.where(status != STATUS["flat"], p[:, 2], peak)
    return offset, sigma, status, iters, contrast, snr
