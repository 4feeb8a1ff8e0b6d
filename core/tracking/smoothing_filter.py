"""The Kalman filter, Rauch–Tung–Striebel smoother and intervention search behind
:func:`core.tracking.smoothing.smooth_poses` (its module docs say what they are for).

Each of ``C`` coordinates is an independent linear Gaussian state-space model — constant velocity or
constant acceleration, measured once a frame — run for ``G`` process-noise ratios ``λ`` at once; the
measurement scale ``k`` is concentrated out of the innovations' likelihood. An *intervention* at a
frame changes the model there: a burst of process noise in the step into it (a real transient the
model lags) or its measurement's variance multiplied (an outlier: the frame off its neighbours).
:func:`interventions` tries both at candidate frames and keeps the one the likelihood favours most —
a spike out and back is one outlier better than two bursts, a step one burst better than a run of
outliers. At a trial's ends a run of flagged frames off alike agrees with itself (a step there): no one of
them is off its neighbours, so :func:`group_outliers` tries the run as one outlier (:func:`end_runs`).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["CHI2_1_MEDIAN", "best_lambda", "candidate_frames", "end_runs", "group_outliers", "interventions",
           "kalman", "model_matrices", "rts"]

#: the median of χ² with one degree of freedom (a squared standard normal)
CHI2_1_MEDIAN = 0.454936


def model_matrices(model: str) -> tuple[np.ndarray, np.ndarray]:
    """Transition ``F`` and unit process covariance ``Q0`` of one frame (continuous white noise)."""
    if model == "velocity":
        return np.array([[1.0, 1.0], [0.0, 1.0]]), np.array([[1 / 3, 1 / 2], [1 / 2, 1.0]])
    if model == "acceleration":
        F = np.array([[1.0, 1.0, 0.5], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0]])
        Q = np.array([[1 / 20, 1 / 8, 1 / 6], [1 / 8, 1 / 3, 1 / 2], [1 / 6, 1 / 2, 1.0]])
        return F, Q
    raise ValueError(f"model: expected 'velocity' or 'acceleration', got {model!r}")


def kalman(z, r, lam, model: str, *, keep: bool = False, boost=None, inflate=None, ar=None):
    """Forward filter of ``C`` independent coordinates, each with ``G`` process-noise ratios.

    ``z``, ``r``: ``(n, C)`` measurements and their variances (unit scale; ``inf`` or a NaN ``z``: no
    measurement); ``lam``: ``(C, G)``. ``boost``: ``(n, C, 1 or G)`` factors on the process noise of
    the step into each frame (a burst); ``inflate``: ``(n, 1 or C, 1 or G)`` factors on each
    measurement's variance (an outlier); default none. Returns the concentrated log-likelihood
    ``(C, G)``, the scale ``k²`` it concentrates (the mean squared normalised innovation), the robust
    scale (their median over :data:`CHI2_1_MEDIAN`: a few outliers do not move it), and with ``keep``
    the predicted and filtered states and covariances ``(n, C, G, d[, d])`` and the coordinates'
    offsets ``z0`` for :func:`rts`.

    ``ar``: ``(phi, base)``, the measurement errors correlated from frame to frame: each coordinate's
    error is an AR(1) process with coefficient ``phi`` ``(C, G)`` and variance ``base`` ``(n, C)``
    (a frame's plain variance), one more state; what ``r`` (times ``inflate``) adds over ``base`` is
    white. The states are then ``d + 1`` long, the last the error (:func:`_kalman_ar`)."""
    if ar is not None:
        return _kalman_ar(z, r, lam, model, keep, boost, inflate, *ar)
    F, Q0 = model_matrices(model)
    d = len(F)
    n, C = z.shape
    G = lam.shape[1]
    meas, z0, zc, big = _start(z, r)  # a diffuse start: the first d measurements set the state
    x = np.zeros((C, G, d))
    P = np.broadcast_to(np.eye(d), (C, G, d, d)) * big[:, None, None, None]
    Q = lam[..., None, None] * Q0
    u2 = np.full((n, C, G), np.nan)  # each used innovation, squared and normalised
    logs = np.zeros((C, G))
    count = np.zeros(C, dtype=int)
    seen = np.zeros(C, dtype=int)
    store = {k: np.empty((n, C, G, d) + ((d,) if k[0] == "P" else ())) for k in ("xp", "Pp", "xf", "Pf")} \
        if keep else None
    for t in range(n):
        if t:
            x = x @ F.T
            P = F @ P @ F.T + (Q if boost is None else Q * boost[t][..., None, None])
        if keep:
            store["xp"][t], store["Pp"][t] = x, P
        m = meas[t]
        if m.any():
            rt = np.where(m, r[t], 1.0)[:, None]
            S = P[..., 0, 0] + (rt if inflate is None else rt * inflate[t])
            K = P[..., :, 0] / S[..., None]
            v = zc[t][:, None] - x[..., 0]
            mk = m[:, None, None]
            x = np.where(mk, x + K * v[..., None], x)
            P = np.where(mk[..., None], P - K[..., :, None] * K[..., None, :] * S[..., None, None], P)
            use = m & (seen >= d)  # the diffuse start's first d innovations left out
            u2[t] = np.where(use[:, None], v ** 2 / S, np.nan)
            logs += np.where(use[:, None], np.log(S), 0.0)
            count += use
            seen += m
        if keep:
            store["xf"][t], store["Pf"][t] = x, P
    ll, k2, k2r = _summary(u2, logs, count)
    if keep:
        return ll, k2, k2r, store, z0
    return ll, k2, k2r


def _summary(u2, logs, count):
    """A pass's log-likelihood, the scale's ML estimate (mean squared normalised innovation) and its
    robust one (their median over χ²₁'s) from the innovations ``u2``, ``logs`` and ``count``."""
    cnt = np.maximum(count, 1)[:, None]
    k2 = np.nansum(u2, axis=0) / cnt
    with np.errstate(all="ignore"):
        k2r = np.where(count[:, None] > 0, np.nanmedian(np.where(count[None, :, None] > 0, u2, 0.0), axis=0),
                       0.0) / CHI2_1_MEDIAN
    ll = -0.5 * (cnt * np.log(np.maximum(k2, 1e-300)) + logs + cnt * (1 + math.log(2 * math.pi)))
    return ll, k2, k2r


def _start(z, r):
    """The measured entries, each coordinate's first measurement, the measurements less it and the
    diffuse start's variance."""
    C = z.shape[1]
    meas = np.isfinite(z) & np.isfinite(r) & (r > 0)
    z0 = np.array([z[meas[:, c], c][0] if meas[:, c].any() else 0.0 for c in range(C)])
    zc = np.where(meas, z - z0, 0.0)
    span = np.array([np.ptp(zc[meas[:, c], c]) if meas[:, c].any() else 1.0 for c in range(C)])
    return meas, z0, zc, (1e3 * (span + 1.0)) ** 2


def _kalman_ar(z, r, lam, model, keep, boost, inflate, phi, base):
    """:func:`kalman` with AR(1) measurement errors (its ``ar``): the state is the motion's and the
    error's, measured as their sum."""
    F0, Q0 = model_matrices(model)
    d = len(F0)
    n, C = z.shape
    G = lam.shape[1]
    a = d + 1
    meas, z0, zc, big = _start(z, r)
    F = np.zeros((C, G, a, a))
    F[..., :d, :d] = F0
    F[..., d, d] = phi
    Ft = F.swapaxes(-1, -2)
    Qm = lam[..., None, None] * Q0
    b = np.where(np.isfinite(base) & (base > 0), base, np.nan)
    b0 = np.array([np.nanmedian(b[:, c]) if np.isfinite(b[:, c]).any() else 1.0 for c in range(C)])
    b = np.where(np.isfinite(b), b, b0)
    x = np.zeros((C, G, a))
    P = np.zeros((C, G, a, a))
    P[..., :d, :d] = np.eye(d) * big[:, None, None, None]
    P[..., d, d] = b[0][:, None]
    u2 = np.full((n, C, G), np.nan)
    logs = np.zeros((C, G))
    count = np.zeros(C, dtype=int)
    seen = np.zeros(C, dtype=int)
    store = {k: np.empty((n, C, G, a) + ((a,) if k[0] == "P" else ())) for k in ("xp", "Pp", "xf", "Pf")} \
        if keep else None
    for t in range(n):
        if t:
            x = (F @ x[..., None])[..., 0]
            P = F @ P @ Ft
            P[..., :d, :d] += Qm if boost is None else Qm * boost[t][..., None, None]
            P[..., d, d] += (1.0 - phi ** 2) * b[t][:, None]
        if keep:
            store["xp"][t], store["Pp"][t] = x, P
        m = meas[t]
        if m.any():
            rt = np.where(m, r[t], 1.0)[:, None]
            white = np.maximum((rt if inflate is None else rt * inflate[t]) - b[t][:, None], 0.0)
            PH = P[..., :, 0] + P[..., :, d]
            S = PH[..., 0] + PH[..., d] + white
            K = PH / S[..., None]
            v = zc[t][:, None] - x[..., 0] - x[..., d]
            mk = m[:, None, None]
            x = np.where(mk, x + K * v[..., None], x)
            P = np.where(mk[..., None], P - K[..., :, None] * K[..., None, :] * S[..., None, None], P)
            use = m & (seen >= d)
            u2[t] = np.where(use[:, None], v ** 2 / S, np.nan)
            logs += np.where(use[:, None], np.log(S), 0.0)
            count += use
            seen += m
        if keep:
            store["xf"][t], store["Pf"][t] = x, P
    if keep:
        store["F"] = F
    ll, k2, k2r = _summary(u2, logs, count)
    if keep:
        return ll, k2, k2r, store, z0
    return ll, k2, k2r


def rts(store, model: str):
    """Rauch–Tung–Striebel pass over :func:`kalman`'s stored states: smoothed states and
    covariances ``(n, C, G, d[, d])`` (unit scale)."""
    F = store["F"] if "F" in store else model_matrices(model)[0]
    xs, Ps = store["xf"].copy(), store["Pf"].copy()
    for t in range(len(xs) - 2, -1, -1):
        A = np.linalg.solve(store["Pp"][t + 1], (store["Pf"][t] @ F.swapaxes(-1, -2)).swapaxes(-1, -2)
                            ).swapaxes(-1, -2)
        xs[t] = store["xf"][t] + (A @ (xs[t + 1] - store["xp"][t + 1])[..., None])[..., 0]
        Ps[t] = store["Pf"][t] + A @ (Ps[t + 1] - store["Pp"][t + 1]) @ A.swapaxes(-1, -2)
    return xs, Ps


def interventions(z, r, lam, model: str, boost, inflate, base, frames, *, bursts, outliers,
                  burst_gain: float | None, outlier_gain: float | None, credit=None, allowed=None):
    """Of ``frames`` (candidate indices, none 0), the intervention that raises the innovations'
    likelihood most: a burst (each coordinate its best factor of ``bursts`` on the process noise of
    the step into the frame) or an outlier (each coordinate its best factor of ``outliers`` on the
    frame's measurement variance); either's gain pooled over the coordinates, a coordinate counted
    (and changed) where it gains over 1. ``base``: ``(C,)``
    the log-likelihood without it; ``boost``, ``inflate``: those already let in. A burst is taken
    where its gain is over ``burst_gain``, an outlier where its gain plus its frame's ``credit``
    (``(n,)``, default 0: a prior log-odds of the frame being off) is over ``outlier_gain`` and over
    the best burst's (None: that kind not tried; ``allowed``: ``(n,)`` the frames that may be taken
    for outliers, default all). Returns ``(kind, frame, (C,) factors, gain)`` (kind ``"burst"`` or
    ``"outlier"``; the gain with the credit) or None."""
    frames = np.asarray(frames, dtype=int)
    m = len(frames)
    if not m:
        return None
    C = len(lam)
    nb = len(bursts) if burst_gain is not None else 0
    ofr = frames if allowed is None else frames[np.asarray(allowed, bool)[frames]]
    ofr = ofr if outlier_gain is not None else ofr[:0]
    cr = np.zeros(len(z)) if credit is None else np.asarray(credit, float)
    no = len(outliers) * len(ofr)
    cols = nb * m + no
    if not cols:
        return None
    cb = np.repeat(boost, cols, axis=2)  # burst (factor b, frame frames[j]) at column b m + j
    for b, f in enumerate(bursts[:nb]):
        cb[frames, :, b * m + np.arange(m)] *= f
    # outlier (factor o, frame ofr[j]) at column nb m + o len(ofr) + j
    ci = np.repeat(np.broadcast_to(inflate, (len(z), C, 1)), cols, axis=2)
    for o, f in enumerate(outliers if no else ()):
        ci[ofr, :, nb * m + o * len(ofr) + np.arange(len(ofr))] *= f
    ll, _, _ = kalman(z, r, np.broadcast_to(lam[:, None], (C, cols)), model, boost=cb, inflate=ci)
    g = ll - base[:, None]

    def pooled(block, factors, count):
        top, which = block.reshape(C, len(factors), count).max(axis=1), \
            block.reshape(C, len(factors), count).argmax(axis=1)
        return np.clip(top, 0.0, None).sum(axis=0), np.where(top > 1.0, np.asarray(factors)[which], 1.0)

    best = None
    if nb:
        gb, fb = pooled(g[:, :nb * m], bursts, m)
        j = int(np.argmax(gb))
        if gb[j] > burst_gain:
            best = ("burst", int(frames[j]), fb[:, j], float(gb[j]))
    if no:
        go, fo = pooled(g[:, nb * m:], outliers, len(ofr))
        score = np.where(go + cr[ofr] > outlier_gain, go + cr[ofr], -np.inf)
        j = int(np.argmax(score))
        if np.isfinite(score[j]) and (best is None or score[j] > best[3]):
            best = ("outlier", int(ofr[j]), fo[:, j], float(score[j]))
    return best


def end_runs(flagged, allowed, longest: int) -> tuple[list, list]:
    """The runs of ``flagged`` frames (``(n,)`` bool) that may be taken for outliers (``allowed``) at the
    series' ends: ``(start, end)`` groups — the first 2, 3, … (at most ``longest``) frames of the run that
    starts at frame 0, the last 2, 3, … of the run that ends at frame ``n - 1`` — each a sorted index
    array."""
    fl, ok = np.asarray(flagged, bool), np.asarray(allowed, bool)
    n = len(fl)
    out = []
    for order in (np.arange(n), np.arange(n)[::-1]):
        run = []
        for t in order:
            if not (fl[t] and ok[t]) or len(run) == longest:
                break
            run.append(int(t))
        out.append([np.sort(np.array(run[:k])) for k in range(2, len(run) + 1)])
    return out[0], out[1]


def group_outliers(z, r, lam, model: str, boost, inflate, base, groups, *, outliers, outlier_gain: float,
                   credit: float = 0.0):
    """Of ``groups`` (index arrays), the one whose frames' measurement variances multiplied together
    (each coordinate its best factor of ``outliers``, counted where it gains over 1, as
    :func:`interventions`) raise the innovations' likelihood most over ``base`` ``(C,)``: a run of frames
    taken as one outlier, credited ``credit`` (log prior odds of the run being off). Returns
    ``("outliers", frames, (C,) factors, gain)`` (the gain with the credit) where that is over
    ``outlier_gain``, else None."""
    if not len(groups):
        return None
    C, m = len(lam), len(groups)
    cols = len(outliers) * m
    ci = np.repeat(np.broadcast_to(inflate, (len(z), C, 1)), cols, axis=2).copy()
    for o, f in enumerate(outliers):
        for j, g in enumerate(groups):
            ci[g, :, o * m + j] *= f
    ll, _, _ = kalman(z, r, np.broadcast_to(lam[:, None], (C, cols)), model, boost=boost, inflate=ci)
    g = (ll - base[:, None]).reshape(C, len(outliers), m)
    top, which = g.max(axis=1), g.argmax(axis=1)
    gain = np.clip(top, 0.0, None).sum(axis=0) + credit
    j = int(np.argmax(gain))
    if not gain[j] > outlier_gain:
        return None
    factors = np.where(top[:, j] > 1.0, np.asarray(outliers)[which[:, j]], 1.0)
    return "outliers", [int(t) for t in groups[j]], factors, float(gain[j])


def candidate_frames(res: np.ndarray, count: int) -> np.ndarray:
    """The ``count`` frames (never the first) whose scaled residuals ``res (n, C)``, squared and
    summed over the coordinates and the frames within ±2, are largest: where a transient the model
    lags, or a frame off its neighbours, leaves its mark (the candidates :func:`interventions` tries)."""
    e = np.nansum(np.where(np.isfinite(res), res, 0.0) ** 2, axis=1)
    w = np.convolve(e, np.ones(5), mode="same")
    w[0] = -np.inf
    order = np.argsort(-w, kind="stable")[:min(count, len(w) - 1)]
    return np.sort(order)


def best_lambda(ll: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """Per row of ``ll (C, G)``, the grid's best ``λ`` refined by a parabola in ``log λ`` through it
    and its neighbours (the grid's end where it is best there)."""
    lg = np.log(grid)
    out = np.empty(len(ll))
    for c, row in enumerate(ll):
        i = int(np.nanargmax(row))
        out[c] = lg[i]
        if 0 < i < len(row) - 1 and np.isfinite(row[i - 1:i + 2]).all():
            a, b, e = row[i - 1], row[i], row[i + 1]
            den = a - 2 * b + e
            if den < 0:
                out[c] = lg[i] + 0.5 * (lg[1] - lg[0]) * (a - e) / den
    return np.exp(out)
