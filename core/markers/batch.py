"""Vectorised localisation of many beads over many frames with any of the seven localizers.

:func:`localize` is the one entry point: it validates the frames and guesses, flags guesses that
cannot be localised (NaN, outside the image), cuts windows of every (frame, bead) item in chunks
(no per-bead Python loop), turns them into bead signal (background − image for dark beads), runs
the chosen algorithm on the whole chunk and checks that the pixels it used lie in the image.

Pixel convention: ``(u, v) = (column, row)``, origin at the centre of the top-left pixel; frames
are indexed ``[frame, row, col]``.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from . import localizers as _loc
from ._windows import border_median, extract, noise_sigma, smoothed_contrast, snr_of
from .fit import fit_half_size, robust_fit, seed_margin
from .profiles import radius_array, window_half_size
from .results import STATUS, Localization

__all__ = ["METHODS", "RECOMMENDED", "localize"]

#: Localizer names → thesis section (``"robust"`` is the recommended one, :mod:`core.markers.fit`).
METHODS: dict[str, str] = {
    "intensity_centroid": "4.2.1 intensity-weighted centroid",
    "gaussian_centroid": "4.2.2 Gaussian-weighted centroid",
    "iterative_gaussian": "4.2.3 iterative Gaussian",
    "iterative_sigmoid": "4.2.4 iterative sigmoid",
    "template_gaussian": "4.2.5 template matching, Gaussian",
    "template_sigmoid": "4.2.6 template matching, sigmoid",
    "robust": "recommended: matched-filter seed + Gaussian/plane least squares",
}
RECOMMENDED = "robust"

_OPTIONS = {
    "intensity_centroid": set(),
    "gaussian_centroid": set(),
    "iterative_gaussian": {"tol", "max_iter"},
    "iterative_sigmoid": {"tol", "max_iter", "beta"},
    "template_gaussian": {"upsample"},
    "template_sigmoid": {"upsample", "beta"},
    "robust": {"model"},
}


def _frames(frames) -> np.ndarray:
    arr = np.asarray(frames)
    if arr.dtype.kind not in "uif" or arr.ndim not in (2, 3):
        raise ValueError(f"frames: expected a real (H, W) image or (F, H, W) stack, got "
                         f"{arr.dtype} array of shape {arr.shape}")
    if arr.ndim == 2:
        arr = arr[None]
    if min(arr.shape[1:]) < 3 or arr.shape[0] < 1:
        raise ValueError(f"frames: image too small, got shape {arr.shape}")
    return arr


def _guesses(guesses, n_frames: int, single: bool) -> tuple[np.ndarray, tuple[int, ...]]:
    try:
        g = np.asarray(guesses, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError("guesses: expected a numeric (N, 2) or (F, N, 2) array") from exc
    if g.ndim == 2 and g.shape[1] == 2:
        if single:
            return g[None], (len(g),)
        return np.broadcast_to(g[None], (n_frames, *g.shape)), (n_frames, len(g))
    if g.ndim == 3 and g.shape[2] == 2 and g.shape[0] == n_frames and not single:
        return g, g.shape[:2]
    want = "(N, 2)" if single else f"(N, 2) or ({n_frames}, N, 2)"
    raise ValueError(f"guesses: expected shape {want}, got {g.shape}")


def _method(method: str, options: dict) -> Callable:
    if method not in METHODS:
        raise ValueError(f"method: expected one of {sorted(METHODS)}, got {method!r}")
    extra = set(options) - _OPTIONS[method]
    if extra:
        raise ValueError(f"{sorted(extra)[0]}: not an option of method {method!r} "
                         f"(options: {sorted(_OPTIONS[method]) or 'none'})")
    for key, val in options.items():
        if key in ("max_iter", "upsample") and (int(val) != val or val < 1):
            raise ValueError(f"{key}: expected a positive integer, got {val!r}")
        if key in ("tol", "beta") and not (np.isfinite(val) and val > 0):
            raise ValueError(f"{key}: expected a positive number, got {val!r}")
        if key == "model" and val not in ("sigmoid", "gaussian"):
            raise ValueError(f"model: expected 'sigmoid' or 'gaussian', got {val!r}")
    table = {
        "intensity_centroid": _loc.intensity_centroid,
        "gaussian_centroid": _loc.gaussian_centroid,
        "iterative_gaussian": _loc.iterative_gaussian,
        "iterative_sigmoid": _loc.iterative_sigmoid,
        "template_gaussian": lambda *a, **k: _loc.template_match(*a, template="gaussian", **k),
        "template_sigmoid": lambda *a, **k: _loc.template_match(*a, template="sigmoid", **k),
    }
    fn = table.get(method)
    return (lambda *a: fn(*a, **options)) if fn is not None else None


def localize(frames, guesses, *, diameter_px, method: str = RECOMMENDED, polarity: str = "dark",
             search_radius: float | None = None, min_snr: float = 4.0, chunk: int = 256,
             workers: int | None = None, **options) -> Localization:
    """Sub-pixel bead centres near ``guesses`` in one image or a stack of frames.

    Parameters
    ----------
    frames : (H, W) or (F, H, W) array
        Flatfield-corrected images (any real dtype; beads darker than the background unless
        ``polarity="bright"``).
    guesses : (N, 2) or (F, N, 2) array
        Initial guesses ``(u, v) = (column, row)`` in pixels, origin at the centre of the
        top-left pixel. With a stack, an ``(N, 2)`` array is used in every frame. NaN marks a
        missing bead (status ``"invalid"``).
    diameter_px : float or (N,) array
        Projected bead diameter(s) in pixels (:mod:`core.markers.profiles`).
    method : str
        One of :data:`METHODS` (default the recommended ``"robust"``).
    polarity : {"dark", "bright"}
        Beads darker (X-ray attenuation images) or brighter than the background.
    search_radius : float, optional
        ``"robust"`` only: how far (px) from the guess the bead may lie; default 3.5 radii of
        each bead.
    min_snr : float
        Minimum bead contrast over its noise (matched-filter SNR); weaker → ``"flat"``.
    chunk : int
        Items processed per vectorised batch (a few hundred keep the arrays in the CPU cache).
    workers : int, optional
        Threads that process chunks in parallel (default: the CPU count, at most 8; 1 = serial).
    **options
        Per-method options: ``tol`` (px) and ``max_iter`` of the iterative centroids, ``beta``
        (1/px) of the sigmoid, ``upsample`` of the DFT registration, ``model`` (``"sigmoid"``
        or ``"gaussian"``) of the recommended localizer.

    Returns
    -------
    Localization
        Leading shape ``(N,)`` for one image, ``(F, N)`` for a stack.
    """
    if polarity not in ("dark", "bright"):
        raise ValueError(f"polarity: expected 'dark' or 'bright', got {polarity!r}")
    if not (np.isfinite(min_snr) and min_snr >= 0):
        raise ValueError(f"min_snr: expected a number >= 0, got {min_snr!r}")
    if int(chunk) != chunk or chunk < 1:
        raise ValueError(f"chunk: expected a positive integer, got {chunk!r}")
    if workers is not None and (int(workers) != workers or workers < 1):
        raise ValueError(f"workers: expected a positive integer or None, got {workers!r}")
    algo = _method(method, options)
    single = np.ndim(frames) == 2
    stack = _frames(frames)
    F, Hh, Ww = stack.shape
    g, lead = _guesses(guesses, F, single)
    n_beads = g.shape[1]
    radius = np.broadcast_to(radius_array(diameter_px, n_beads)[None], (g.shape[0], n_beads)).ravel()
    fidx = np.repeat(np.arange(g.shape[0]), n_beads)
    uv = g.reshape(-1, 2)
    if search_radius is None:
        search = 3.5 * radius  # per bead
    else:
        s = float(search_radius)
        if not (np.isfinite(s) and s >= 0):
            raise ValueError(f"search_radius: expected a distance >= 0 in pixels, got {search_radius!r}")
        search = np.full(radius.shape, s)
    out = Localization.empty(len(uv), method)
    finite = np.all(np.isfinite(uv), axis=1)
    inside = finite & np.all((uv >= -0.5) & (uv <= np.array([Ww, Hh]) - 0.5), axis=1)
    out.status[finite & ~inside] = STATUS["outside"]
    todo = np.flatnonzero(inside)
    todo = todo[np.argsort(radius[todo], kind="stable")]  # chunks of similar window sizes
    sign = 1.0 if polarity == "dark" else -1.0

    def run(idx: np.ndarray) -> None:
        r = radius[idx]
        rmax = float(r.max())
        h = window_half_size(rmax)
        if method == RECOMMENDED:
            k = fit_half_size(rmax)
            H = int(np.ceil(search[idx].max())) + max(seed_margin(float(np.median(r))), k + 1)
            support = k
        elif method.startswith("iterative"):
            H, support = h + int(np.ceil(3.5 * rmax)), h
        else:
            H, support = h, h
        centre = np.rint(uv[idx]).astype(np.int64)
        win = extract(stack, fidx[idx], centre, H, np.float32 if method == RECOMMENDED else np.float64)
        sig = sign * (border_median(win.data)[:, None, None] - win.data)
        g_rel = uv[idx] - centre
        if method == RECOMMENDED:
            off, sg, st, it, contrast, snr = robust_fit(sig, g_rel, r, search=search[idx], min_snr=min_snr,
                                                        **options)
        else:
            noise = noise_sigma(win.data)
            disc = _disc_mask(win.size, g_rel, h)
            contrast, cnoise, _ = smoothed_contrast(sig, r, disc)
            snr = snr_of(contrast, cnoise)
            off, sg, st, it = algo(sig, g_rel, r, h, noise)
            st = np.where(snr >= min_snr, st, STATUS["flat"]).astype(np.int8)
        est = centre + off
        # the pixels the estimate rests on must lie in the image; a failure next to the border
        # (the border cut the bead, so the fit or iteration broke) is reported as "border" too
        cut = _crosses_border(np.where(np.isfinite(est), est, uv[idx]), support, Ww, Hh)
        near = _crosses_border(uv[idx], support, Ww, Hh)
        failed = (st != STATUS["ok"]) & (st != STATUS["flat"])
        st = np.where(((st == STATUS["ok"]) & cut) | (failed & near), STATUS["border"], st).astype(np.int8)
        good = st == STATUS["ok"]
        out.uv[idx] = np.where(good[:, None], est, np.nan)
        out.sigma[idx] = np.where(good[:, None], sg, np.nan)
        out.status[idx] = st
        out.contrast[idx] = contrast
        out.snr[idx] = snr
        out.iterations[idx] = it

    chunks = [todo[s : s + int(chunk)] for s in range(0, todo.size, int(chunk))]
    n_workers = min(int(workers) if workers else min(os.cpu_count() or 1, 8), max(len(chunks), 1))
    if n_workers <= 1:
        for idx in chunks:
            run(idx)
    else:  # numpy releases the GIL in its kernels: chunks run in parallel on the cores
        with ThreadPoolExecutor(max_workers=n_workers) as pool:
            for fut in [pool.submit(run, idx) for idx in chunks]:
                fut.result()
    return out.reshape(*lead)


def _crosses_border(uv: np.ndarray, half: int, w: int, h: int) -> np.ndarray:
    """Whether the ``(2 half + 1)²`` pixels around ``uv (M, 2)`` reach outside a w × h image."""
    lo = np.floor(uv - half)
    hi = np.ceil(uv + half)
    return np.any(lo < 0, axis=1) | (hi[:, 0] > w - 1) | (hi[:, 1] > h - 1)


def _disc_mask(size: int, c: np.ndarray, h: float) -> np.ndarray:
    off = np.arange(size) - size // 2
    d2 = (off[None, None, :] - c[:, 0, None, None]) ** 2 + (off[None, :, None] - c[:, 1, None, None]) ** 2
    return d2 <= h * h
