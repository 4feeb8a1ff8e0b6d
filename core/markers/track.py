"""Frame-to-frame tracking of beads in one view: predict, re-localise, flag lost beads, fill gaps.

For each frame the position of every bead is **predicted** with a constant-velocity model from
its last two good estimates (the last estimate alone after a single one), **re-localised** with
a localizer (default the recommended one, vectorised over all beads of the frame), and accepted
when the localizer succeeds and the estimate lies within ``gate_px`` of the prediction. A bead
that fails is **lost** in that frame; it keeps being predicted from its last good estimates
(so it is re-acquired when it reappears). Afterwards, **gaps** of at most ``max_gap`` frames
between two good estimates are filled by cubic-Hermite (velocity-matched) interpolation and
marked ``FILLED``; longer gaps stay ``LOST`` (NaN).

Pixel convention: ``(u, v) = (column, row)``, origin at the centre of the top-left pixel.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from .batch import RECOMMENDED, localize

__all__ = ["FILLED", "LOST", "TRACKED", "BeadTracks", "track_beads"]

TRACKED, FILLED, LOST = 0, 1, 2


@dataclass(frozen=True, eq=False)
class BeadTracks:
    """2-D bead trajectories of one view.

    Attributes
    ----------
    uv : (F, N, 2)
        Positions in pixels; NaN where lost.
    sigma : (F, N, 2)
        Localisation uncertainty (px); NaN for filled and lost entries.
    state : (F, N) int8
        :data:`TRACKED`, :data:`FILLED` or :data:`LOST`.
    status : (F, N) int8
        The localizer's status code (:data:`core.markers.results.STATUS_NAMES`); a tracked bead
        may still be lost by the gate (status 0, state LOST).
    predicted : (F, N, 2)
        The prediction used as the initial guess in each frame.
    """

    uv: np.ndarray
    sigma: np.ndarray
    state: np.ndarray
    status: np.ndarray
    predicted: np.ndarray


def _predict(hist_uv: np.ndarray, hist_f: np.ndarray, f: int) -> np.ndarray:
    """Constant-velocity prediction at frame ``f`` from the last two good (frame, uv) per bead."""
    last, prev = hist_uv[:, 1], hist_uv[:, 0]
    fl, fp = hist_f[:, 1], hist_f[:, 0]
    with np.errstate(invalid="ignore", divide="ignore"):
        vel = (last - prev) / (fl - fp)[:, None]
    vel = np.where(np.isfinite(vel), vel, 0.0)
    return last + vel * (f - fl)[:, None]


def track_beads(frames, initial_uv, *, diameter_px, method: str = RECOMMENDED, gate_px: float | None = None,
                search_radius: float | None = None, max_gap: int = 5, polarity: str = "dark",
                min_snr: float = 4.0) -> BeadTracks:
    """Track beads through a stack of frames starting from ``initial_uv`` in frame 0.

    Parameters
    ----------
    frames : (F, H, W) array
        Corrected frames of one view.
    initial_uv : (N, 2) array
        Bead positions (or guesses) in frame 0, pixels.
    diameter_px : float or (N,) array
        Projected bead diameter(s), pixels.
    method : str
        Localizer (:data:`core.markers.batch.METHODS`).
    gate_px : float, optional
        Largest accepted distance between prediction and estimate (default 3 bead radii).
    search_radius : float, optional
        Passed to the recommended localizer (default 3.5 radii).
    max_gap : int
        Longest run of lost frames that is filled by interpolation.
    polarity, min_snr
        As in :func:`core.markers.batch.localize`.
    """
    stack = np.asarray(frames)
    if stack.ndim != 3 or stack.shape[0] < 1:
        raise ValueError(f"frames: expected an (F, H, W) stack, got shape {stack.shape}")
    uv0 = np.asarray(initial_uv, dtype=np.float64)
    if uv0.ndim != 2 or uv0.shape[1] != 2 or not np.all(np.isfinite(uv0)):
        raise ValueError(f"initial_uv: expected a finite (N, 2) array, got shape {uv0.shape}")
    if int(max_gap) != max_gap or max_gap < 0:
        raise ValueError(f"max_gap: expected an integer >= 0, got {max_gap!r}")
    F, N = stack.shape[0], len(uv0)
    r = np.broadcast_to(np.asarray(diameter_px, dtype=float) / 2.0, (N,))
    gate = 3.0 * float(r.max()) if gate_px is None else float(gate_px)
    if not (np.isfinite(gate) and gate > 0):
        raise ValueError(f"gate_px: expected a positive distance in pixels, got {gate_px!r}")
    opts = {"search_radius": search_radius} if method == RECOMMENDED else {}
    uv = np.full((F, N, 2), np.nan)
    sigma = np.full((F, N, 2), np.nan)
    state = np.full((F, N), LOST, np.int8)
    status = np.zeros((F, N), np.int8)
    pred = np.full((F, N, 2), np.nan)
    hist_uv = np.repeat(uv0[:, None], 2, axis=1)  # last two good positions
    hist_f = np.zeros((N, 2))  # equal frames: zero velocity until two estimates exist
    for f in range(F):
        p = uv0 if f == 0 else _predict(hist_uv, hist_f, f)
        pred[f] = p
        loc = localize(stack[f], p, diameter_px=diameter_px, method=method, polarity=polarity,
                       min_snr=min_snr, **opts)
        status[f] = loc.status
        good = loc.ok & (np.hypot(*(loc.uv - p).T) <= gate)
        uv[f, good], sigma[f, good] = loc.uv[good], loc.sigma[good]
        state[f, good] = TRACKED
        hist_uv[good, 0], hist_f[good, 0] = hist_uv[good, 1], hist_f[good, 1]
        hist_uv[good, 1], hist_f[good, 1] = loc.uv[good], f
    _fill_gaps(uv, state, int(max_gap))
    return BeadTracks(uv, sigma, state, status, pred)


def _fill_gaps(uv: np.ndarray, state: np.ndarray, max_gap: int) -> None:
    """Cubic-Hermite fill of interior gaps ≤ ``max_gap`` frames (in place)."""
    F, N = state.shape
    if max_gap == 0 or F < 3:
        return
    for n in range(N):  # per bead over its few gaps; not the per-frame hot path
        good = np.flatnonzero(state[:, n] == TRACKED)
        if good.size < 2:
            continue
        for a, b in itertools.pairwise(good):
            gap = b - a - 1
            if gap == 0 or gap > max_gap:
                continue
            # velocities from the neighbours outside the gap (finite differences), else the chord
            chord = (uv[b, n] - uv[a, n]) / (b - a)
            va = uv[a, n] - uv[a - 1, n] if a > 0 and state[a - 1, n] == TRACKED else chord
            vb = uv[b + 1, n] - uv[b, n] if b + 1 < F and state[b + 1, n] == TRACKED else chord
            t = (np.arange(a + 1, b) - a) / (b - a)
            h00, h10 = 2 * t**3 - 3 * t**2 + 1, t**3 - 2 * t**2 + t
            h01, h11 = -2 * t**3 + 3 * t**2, t**3 - t**2
            L = b - a
            uv[a + 1 : b, n] = (h00[:, None] * uv[a, n] + h10[:, None] * L * va
                                + h01[:, None] * uv[b, n] + h11[:, None] * L * vb)
            state[a + 1 : b, n] = FILLED
