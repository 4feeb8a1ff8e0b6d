"""Covariance-weighted smoothing of a bone's tracked poses (Rauch–Tung–Striebel), its smoothing
chosen from the data.

Each frame's pose is estimated from that frame alone; its confidence σ
(:class:`~core.tracking.confidence.PoseConfidence`) says how well. :func:`smooth_poses` pools
neighbouring frames instead: per bone, the six pose coordinates — the path of ``center`` (mm) and
the rotation vector of ``R R_refᵀ`` (``R_ref`` the middle tracked frame's rotation) — each follow a
constant-velocity model (``model="velocity"``: white-noise acceleration, a cubic smoothing spline's
prior) or a constant-acceleration one (``"acceleration"``: white-noise jerk), measured once a frame
with variance ``k² σ_f²`` (``weigh="sigma"``: σ_f the frame's own σ on that coordinate, the
rotation's carried into the rotation vector's coordinates by the inverse left Jacobian;
``"equal"``, the default: the coordinate's median σ in every frame — the tracker's σ changes
from frame to frame more than its errors do). The Kalman filter runs forward and the Rauch–Tung–Striebel
smoother back: each frame's smoothed pose and covariance use every frame of the trial.

Nothing is tuned to a trial by hand: per coordinate the process noise ``q = k² λ`` and the
measurement scale ``k`` are the maximum of the innovations' likelihood (no truth needed) —
``k`` in closed form for each ``λ`` (the likelihood concentrated), ``λ`` over a log grid of
:data:`GRID` values, refined by a parabola through the best three. The tracker's σ is a scale, not
a calibrated standard error (its errors within 2σ far more often than 95 % on some bones): ``k``
takes its level from the data, ``σ_f`` only weighs the frames against each other.

Frames without a pose are not measured: they get the pose their neighbours imply, with its (larger)
covariance; so are frames flagged for review (``flagged``) with ``flagged_weight`` 0 (default 1:
measured as the others, the robust weights judging them).
``robust``: frames whose smoothed residual stands more than ``robust`` × their own scaled σ off
(RMS over the translation or the rotation coordinates) are down-weighted by ``(robust / d)²`` and
the fit repeated (at most :data:`MAX_ROUNDS` fits in all); None: no down-weighting. A known fault: a
frame far off its neighbours is followed, not pulled in, with the defaults — on a synthetic track (σ
0.05 mm) a frame flagged 1, 2 or 5 mm off came out 0.96-1.01, 1.97-2.02 or 4.92-4.99 mm off, its weight
1: the bursts (*Transients*) take its spike, out and back, for a transient, and beyond ~2 mm no process
noise keeps ``k`` within ``max_scale`` (*Scale*), so the least smoothing is taken and the smoother follows
the data; 0.5 mm is pulled in, and with ``flagged_weight`` 0 the flagged frame is (0.007-0.033 mm), but
skipping flagged frames cost the acceptance runs more (their end frames extrapolated: tibia up to 2.71×
its bound in mm, 11 frames over 4×, ``tracking_smoother_cpu.json``'s ``acceleration_skip_flagged``)
(``tests/core/tracking/test_smoothing_outliers.py``, a strict xfail until it is pulled in).

Scale
-----
Where the motion is too fast or irregular for the model at the trial's frame rate (a few frames
over a whole stance), the likelihood can explain it as measurement noise far above the tracker's
σ, and smooth the real motion away (a 12-frame stance of the demo trial: k up to 16, errors up to
1.4 mm against 0.02–0.07 mm per frame; bounded, 0.01–0.12 mm). ``max_scale`` (:data:`MAX_SCALE`)
bounds ``k``: the ``λ`` is the likeliest of those whose ``k`` is within it, else the largest tried
(hardly any smoothing). On the acceptance runs ``k`` was 0.15–1.24, the bound never met.

Transients
----------
One process noise for the whole trial smooths a real fast transient (an impact: a heel strike's
jerk) as if it were noise. ``transients``: first, before the robust weights (a frame a transient
moved is not to be down-weighted as if off), each of the :data:`BURST_CANDIDATES` frames whose
scaled residuals, summed over the coordinates and the frames within ±2, are largest is tried with a
burst of process noise (the step into it × each of :data:`BURSTS`) and the likelihood of the
innovations recomputed; where the gain summed over the six coordinates (each its best factor, a
coordinate counted where it gains) is over ``transients`` (:data:`TRANSIENT_GAIN`, a likelihood
ratio test: no truth), the burst is let in at that frame and the fit repeated, at most
:data:`MAX_BURSTS` times. On the acceptance runs it let in none; on their truth given a 1 mm / 1°
jerk it found the jerk's frames (``core.studies.tracking.smoother``). Trying only those frames keeps
the search linear in the trial's length (1000 frames: 1.3 s a bone on this 2-core x86_64 machine,
shared, against 12.7 s trying every frame).

This smoother uses neighbouring frames, so the single-frame Cramér–Rao bound
(:mod:`core.tracking.bound`) does not bound it: its errors can fall below that bound, and are a
separate figure from the per-frame goal. A real transient faster than the process noise allows
(an impact) is smoothed too; ``core.studies.tracking.smoother`` measures how much.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..geometry.transforms import matrix_to_rotvec, rotvec_to_matrix

__all__ = ["BURSTS", "BURST_CANDIDATES", "GRID", "MAX_BURSTS", "MAX_ROUNDS", "MAX_SCALE", "MODELS",
           "TRANSIENT_GAIN", "SmoothedPoses", "left_jacobian", "smooth_poses", "smooth_track"]

#: the motion models: state per coordinate (position, velocity[, acceleration])
MODELS = ("velocity", "acceleration")
#: λ = q / k² (per frame) tried: log-spaced, 4 a decade
GRID = np.logspace(-12.0, 4.0, 65)
#: the most refits (robust weights, bursts)
MAX_ROUNDS = 24
#: the most bursts let in
MAX_BURSTS = 6
#: a burst's process-noise factors tried, and the pooled log-likelihood gain that lets one in
BURSTS = (1e2, 1e4, 1e6)
TRANSIENT_GAIN = 15.0
#: the frames tried for a burst each time: those whose residuals, about them, are largest
BURST_CANDIDATES = 24
#: the largest scale ``k`` on the σ given (``max_scale``)
MAX_SCALE = 2.0


@dataclass(frozen=True, eq=False)
class SmoothedPoses:
    """:func:`smooth_poses`' result over the ``n`` frames given.

    Attributes
    ----------
    poses : (n, 4, 4) array
        Smoothed ``T_lab_from_bone``; NaN before the first and after the last frame with a pose
        (an unmeasured frame at either end gets the pose its neighbours extrapolate, with its
        growing covariance).
    sigma : (n, 6) array
        Smoothed σ, tx, ty, tz in mm and rx, ry, rz in degrees about ``center`` (the tracker's
        confidence's units and axes: a left perturbation of the pose).
    covariance : (n, 6, 6) array
        The smoothed covariance in those units.
    weights : (n,) array
        Each frame's measurement weight (1 plain; below 1 down-weighted by ``robust``; 0 not
        measured: no pose, flagged, or no σ).
    scale : (6,) array
        ``k`` per coordinate: the factor the σ given were scaled by (measurement σ = k σ_f).
    process_noise : (6,) array
        ``q`` per coordinate, (mm or rad)² per frame³ (velocity) or per frame⁵ (acceleration).
    model : str
    log_likelihood : (6,) array
        The innovations' concentrated log-likelihood per coordinate at the chosen ``λ``.
    bursts : list of int
        Frames (indices) where a burst of process noise was let in (``transients``).
    """

    poses: np.ndarray
    sigma: np.ndarray
    covariance: np.ndarray
    weights: np.ndarray
    scale: np.ndarray
    process_noise: np.ndarray
    model: str
    log_likelihood: np.ndarray = field(default_factory=lambda: np.zeros(6))
    bursts: list = field(default_factory=list)

    def to_dict(self) -> dict:
        """JSON-ready: per frame the pose (4×4 rows, None where NaN), σ, covariance and weight; the
        model, scale and process noise."""
        def rows(a, d):
            return [None if not np.all(np.isfinite(x)) else np.round(x, d).tolist() for x in a]

        return {"model": self.model, "scale": np.round(self.scale, 5).tolist(), "bursts": list(self.bursts),
                "process_noise": [float(f"{q:.4g}") for q in self.process_noise],
                "poses": rows(self.poses, 6), "sigma": rows(self.sigma, 6),
                "covariance": rows(self.covariance, 8), "weights": np.round(self.weights, 4).tolist()}


def _skew(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, float)
    S = np.zeros((*v.shape[:-1], 3, 3))
    S[..., 0, 1], S[..., 0, 2], S[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    S[..., 1, 0], S[..., 2, 0], S[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return S


def left_jacobian(phi, *, inverse: bool = False) -> np.ndarray:
    """``(..., 3, 3)`` left Jacobian ``J_l(φ)`` of SO(3) (or its inverse): ``exp(J_l δ) exp(φ) ≈
    exp(φ + δ)``, so a left perturbation ``e`` of ``exp(φ)`` moves the rotation vector by
    ``J_l⁻¹ e``. ``phi``: ``(..., 3)`` rotation vectors, radians."""
    phi = np.asarray(phi, float)
    th = np.linalg.norm(phi, axis=-1)[..., None, None]
    S = _skew(phi)
    S2 = S @ S
    small = th < 1e-6
    t = np.where(small, 1.0, th)
    eye = np.broadcast_to(np.eye(3), S.shape)
    if inverse:
        c = np.where(small, 1.0 / 12.0, 1.0 / t ** 2 - (1 + np.cos(t)) / (2 * t * np.sin(t)))
        return eye - 0.5 * S + c * S2
    a = np.where(small, 0.5, (1 - np.cos(t)) / t ** 2)
    b = np.where(small, 1.0 / 6.0, (t - np.sin(t)) / t ** 3)
    return eye + a * S + b * S2


def _model(model: str) -> tuple[np.ndarray, np.ndarray]:
    """Transition ``F`` and unit process covariance ``Q0`` of one frame (continuous white noise)."""
    if model == "velocity":
        return np.array([[1.0, 1.0], [0.0, 1.0]]), np.array([[1 / 3, 1 / 2], [1 / 2, 1.0]])
    if model == "acceleration":
        F = np.array([[1.0, 1.0, 0.5], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0]])
        Q = np.array([[1 / 20, 1 / 8, 1 / 6], [1 / 8, 1 / 3, 1 / 2], [1 / 6, 1 / 2, 1.0]])
        return F, Q
    raise ValueError(f"model: expected one of {MODELS}, got {model!r}")


def _kalman(z, r, lam, model: str, *, keep: bool = False, boost=None):
    """Forward filter of ``C`` independent coordinates, each with ``G`` process-noise ratios.

    ``z``, ``r``: ``(n, C)`` measurements and their variances (unit scale; ``inf`` or a NaN ``z``: no
    measurement); ``lam``: ``(C, G)``. Returns the concentrated log-likelihood ``(C, G)``, the scale
    ``k² (C, G)``, and with ``keep`` the predicted and filtered states and covariances
    ``(n, C, G, d[, d])`` for the smoother. ``boost``: ``(n, C, 1 or G)`` factors on the process
    noise of the step into each frame (a burst, :func:`_burst`; default none)."""
    F, Q0 = _model(model)
    d = len(F)
    n, C = z.shape
    G = lam.shape[1]
    meas = np.isfinite(z) & np.isfinite(r) & (r > 0)
    z0 = np.array([z[meas[:, c], c][0] if meas[:, c].any() else 0.0 for c in range(C)])
    zc = np.where(meas, z - z0, 0.0)
    span = np.array([np.ptp(zc[meas[:, c], c]) if meas[:, c].any() else 1.0 for c in range(C)])
    big = (1e3 * (span + 1.0)) ** 2  # a diffuse start: the first d measurements set the state
    x = np.zeros((C, G, d))
    P = np.broadcast_to(np.eye(d), (C, G, d, d)) * big[:, None, None, None]
    Q = lam[..., None, None] * Q0
    ssum = np.zeros((C, G))
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
            S = P[..., 0, 0] + np.where(m, r[t], 1.0)[:, None]
            K = P[..., :, 0] / S[..., None]
            v = zc[t][:, None] - x[..., 0]
            mk = m[:, None, None]
            x = np.where(mk, x + K * v[..., None], x)
            P = np.where(mk[..., None], P - K[..., :, None] * K[..., None, :] * S[..., None, None], P)
            use = m & (seen >= d)  # the diffuse start's first d innovations left out
            ssum += np.where(use[:, None], v ** 2 / S, 0.0)
            logs += np.where(use[:, None], np.log(S), 0.0)
            count += use
            seen += m
        if keep:
            store["xf"][t], store["Pf"][t] = x, P
    cnt = np.maximum(count, 1)[:, None]
    k2 = ssum / cnt
    ll = -0.5 * (cnt * np.log(np.maximum(k2, 1e-300)) + logs + cnt * (1 + math.log(2 * math.pi)))
    if keep:
        return ll, k2, store, z0
    return ll, k2


def _rts(store, model: str):
    """Rauch–Tung–Striebel pass over :func:`_kalman`'s stored states: smoothed states and
    covariances ``(n, C, G, d[, d])`` (unit scale)."""
    F, _ = _model(model)
    xs, Ps = store["xf"].copy(), store["Pf"].copy()
    for t in range(len(xs) - 2, -1, -1):
        A = np.linalg.solve(store["Pp"][t + 1], (store["Pf"][t] @ F.T).swapaxes(-1, -2)).swapaxes(-1, -2)
        xs[t] = store["xf"][t] + (A @ (xs[t + 1] - store["xp"][t + 1])[..., None])[..., 0]
        Ps[t] = store["Pf"][t] + A @ (Ps[t + 1] - store["Pp"][t + 1]) @ A.swapaxes(-1, -2)
    return xs, Ps


def _burst(z, r, lam, model: str, boost, base, gain: float, frames):
    """Of ``frames`` (candidate indices, none 0), the frame where a burst of process noise raises
    the likelihood most, pooled over the six coordinates (each its best factor of :data:`BURSTS`, a
    coordinate counted where it gains), and each coordinate's factor there (1 where it gains under 1);
    ``(None, None)`` where the pooled gain is not over ``gain``. ``base``: ``(C,)`` the
    log-likelihood without it."""
    frames = np.asarray(frames, dtype=int)
    m, nb = len(frames), len(BURSTS)
    if not m:
        return None, None
    cand = np.repeat(boost, m * nb, axis=2)  # candidate (factor b, frame frames[j]) at column b m + j
    for b, f in enumerate(BURSTS):
        cand[frames, :, b * m + np.arange(m)] *= f
    ll, _ = _kalman(z, r, np.broadcast_to(lam[:, None], (len(lam), m * nb)), model, boost=cand)
    g = (ll - base[:, None]).reshape(len(lam), nb, m)
    best, which = g.max(axis=1), g.argmax(axis=1)
    pooled = np.clip(best, 0.0, None).sum(axis=0)
    j = int(np.argmax(pooled))
    if not pooled[j] > gain:
        return None, None
    return int(frames[j]), np.where(best[:, j] > 1.0, np.asarray(BURSTS)[which[:, j]], 1.0)


def _burst_frames(res: np.ndarray, count: int) -> np.ndarray:
    """The ``count`` frames (never the first) whose scaled residuals ``res (n, C)``, squared and
    summed over the coordinates and the frames within ±2, are largest: where a transient the model
    lags leaves its mark (the candidates :func:`_burst` tries)."""
    e = np.nansum(np.where(np.isfinite(res), res, 0.0) ** 2, axis=1)
    w = np.convolve(e, np.ones(5), mode="same")
    w[0] = -np.inf
    order = np.argsort(-w, kind="stable")[:min(count, len(w) - 1)]
    return np.sort(order)


def _best_lambda(ll: np.ndarray, grid: np.ndarray) -> np.ndarray:
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


def _row_mean(a: np.ndarray) -> np.ndarray:
    """Mean of each row's finite values (NaN where none)."""
    f = np.isfinite(a)
    return np.where(f.any(axis=1), np.where(f, a, 0.0).sum(axis=1) / np.maximum(f.sum(axis=1), 1), np.nan)


def _chart(P: np.ndarray, center: np.ndarray):
    """The poses' coordinates: the path of ``center`` and the rotation vector about the middle
    tracked frame's rotation (NaN where no pose); and that reference rotation."""
    ok = np.all(np.isfinite(P), axis=(1, 2))
    idx = np.flatnonzero(ok)
    ref = P[idx[len(idx) // 2], :3, :3]
    z = np.full((len(P), 6), np.nan)
    z[ok, :3] = P[ok, :3, :3] @ center + P[ok, :3, 3]
    z[ok, 3:] = matrix_to_rotvec(P[ok, :3, :3] @ ref.T)
    return z, ref, ok


def _chart_sigma(z, sigma, ok, weigh):
    """Per frame and coordinate the measurement σ in the chart's units (mm, rad): the translation's
    as given, the rotation's (degrees, a left perturbation) through ``J_l⁻¹`` of the frame's
    rotation vector (the diagonal of the carried covariance); inf where a group has no finite σ."""
    s = np.array(sigma, dtype=float)  # copy: NaN rows filled below
    s = np.where(np.isfinite(s) | np.isinf(s), s, np.nan)
    med = np.array([np.nanmedian(col[np.isfinite(col)]) if np.isfinite(col).any() else np.nan for col in s.T])
    if weigh == "equal":
        s = np.where(np.isfinite(s), med, s)
    s = np.where(np.isnan(s), med, s)  # a frame without σ: the coordinate's median
    out = np.full_like(s, np.inf)
    out[:, :3] = s[:, :3]
    Ji = left_jacobian(np.where(ok[:, None], z[:, 3:], 0.0), inverse=True)
    Sr = np.radians(s[:, 3:])
    fin = np.isfinite(Sr).all(axis=1)
    C = Ji[fin] * Sr[fin, None, :] ** 2 @ Ji[fin].swapaxes(-1, -2)
    out[fin, 3:] = np.sqrt(np.einsum("nii->ni", C))
    out[~np.isfinite(out[:, :3]).all(axis=1), :3] = np.inf
    return out


def smooth_poses(poses, sigma, *, center, flagged=None, model: str = "acceleration", weigh: str = "equal",
                 robust: float | None = 2.5, flagged_weight: float = 1.0,
                 transients: float | None = TRANSIENT_GAIN,
                 max_scale: float | None = MAX_SCALE) -> SmoothedPoses:
    """Smooth one bone's tracked poses with the covariance-weighted RTS smoother (module docs).

    Parameters
    ----------
    poses : (n, 4, 4) array
        ``T_lab_from_bone`` of consecutive frames (NaN where none).
    sigma : (n, 6) array
        Each frame's confidence σ (tx, ty, tz mm; rx, ry, rz degrees, as
        :class:`~core.tracking.confidence.PoseConfidence`); NaN where a frame has none (the
        coordinate's median used), ``inf`` on an unbounded axis (that group not measured).
    center : (3,) array
        Bone-frame point (mm) whose path is smoothed, the σ's rotation centre (the centroid).
    flagged : (n,) bool array, optional
        Frames flagged for review: measured with ``flagged_weight`` (0: not at all).
    model : {"acceleration", "velocity"}
        The motion model (default constant acceleration: on the acceptance runs constant velocity
        did worse, × the bound 0.77–1.39 / 0.48–1.26 against 0.55–1.13 / 0.42–1.21 mm / °, and far
        worse with the flagged frames skipped: the heel strike's acceleration at a trial's start;
        ``core.studies.tracking.smoother``).
    weigh : {"equal", "sigma"}
        Every frame of a coordinate alike (its median σ; the default), or each frame by its own σ
        (on the acceptance runs its frame-to-frame changes weighed the frames worse than none:
        × the bound 0.85 / 0.71 against 0.80 / 0.66 on average, ``core.studies.tracking.smoother``).
    robust : float or None
        Down-weighting threshold on a frame's scaled residual (module docs); None: off.
    max_scale : float or None
        The largest ``k`` allowed (module docs, *Scale*); None: any.
    transients : float or None
        The log-likelihood gain over which a burst of process noise is let in at a frame (module
        docs, *Transients*); None: never.
    flagged_weight : float
        The weight of a flagged frame's measurement, in [0, 1] (default 1: most flagged frames of
        the acceptance trial are good, and ``robust`` weighs down those off their neighbours;
        skipping them left the ones at a trial's ends to extrapolation, ``core.studies.tracking.smoother``).

    Returns
    -------
    SmoothedPoses
    """
    P = np.asarray(poses, dtype=float)
    if P.ndim != 3 or P.shape[1:] != (4, 4):
        raise ValueError(f"poses: expected shape (n, 4, 4), got {P.shape}")
    n = len(P)
    S = np.asarray(sigma, dtype=float)
    if S.shape != (n, 6):
        raise ValueError(f"sigma: expected shape ({n}, 6), got {S.shape}")
    c = np.asarray(center, dtype=float).reshape(3)
    fl = np.zeros(n, bool) if flagged is None else np.asarray(flagged, bool).reshape(n)
    _model(model)
    if weigh not in ("sigma", "equal"):
        raise ValueError(f"weigh: expected 'sigma' or 'equal', got {weigh!r}")
    if robust is not None and not robust > 0:
        raise ValueError(f"robust: expected a positive threshold or None, got {robust!r}")
    if not 0.0 <= flagged_weight <= 1.0:
        raise ValueError(f"flagged_weight: expected a weight in [0, 1], got {flagged_weight!r}")
    if max_scale is not None and not max_scale > 0:
        raise ValueError(f"max_scale: expected a positive scale or None, got {max_scale!r}")
    if transients is not None and not transients > 0:
        raise ValueError(f"transients: expected a positive log-likelihood gain or None, got {transients!r}")
    d = len(_model(model)[0])
    ok = np.all(np.isfinite(P), axis=(1, 2))
    w = np.where(ok, np.where(fl, flagged_weight, 1.0), 0.0)
    if (w > 0).sum() < d + 2:
        raise ValueError(f"poses: expected at least {d + 2} measured (posed, unflagged) frames, "
                         f"got {(w > 0).sum()}")
    z, ref, ok = _chart(np.where(w[:, None, None] > 0, P, np.nan), c)
    s = _chart_sigma(z, S, ok, weigh)
    rob, boost, jumps = np.ones(n), np.ones((n, 6, 1)), []
    bursts_done = transients is None
    for _ in range(MAX_ROUNDS + 1):
        wt = w * rob
        r = np.where(wt[:, None] > 0, s ** 2 / np.maximum(wt, 1e-12)[:, None], np.inf)
        ll, kg = _kalman(z, r, np.broadcast_to(GRID, (6, len(GRID))), model, boost=boost)
        if max_scale is not None:  # the frames no noisier than max_scale x their sigma say
            ll = np.where(kg <= max_scale ** 2, ll, -np.inf)
            ll[np.isinf(ll).all(axis=1), -1] = 0.0  # none: the least smoothing tried
        lam = _best_lambda(ll, GRID)
        llb, k2, store, z0 = _kalman(z, r, lam[:, None], model, keep=True, boost=boost)
        xs, Ps = _rts(store, model)
        xs, Ps, k2 = xs[:, :, 0], Ps[:, :, 0], k2[:, 0]
        if not bursts_done:  # first the bursts, every frame at its plain weight
            res = (z - z0 - xs[..., 0]) / np.sqrt(k2 * s ** 2)
            t, factors = _burst(z, r, lam, model, boost, llb[:, 0], transients,
                                _burst_frames(res, BURST_CANDIDATES))
            if t is not None:
                boost[t, :, 0] *= factors
                jumps.append(t)
            bursts_done = t is None or len(jumps) >= MAX_BURSTS
            continue
        if robust is None:
            break
        res = (z - z0 - xs[..., 0]) / np.sqrt(k2 * s ** 2)
        with np.errstate(invalid="ignore"):
            dd = np.sqrt(np.fmax(_row_mean(res[:, :3] ** 2), _row_mean(res[:, 3:] ** 2)))
        far = np.isfinite(dd) & (dd > robust)
        new = np.where(far, (robust / np.where(far, dd, 1.0)) ** 2, 1.0)
        if np.allclose(new, rob, atol=1e-3):
            break
        rob = new
    x = xs[..., 0] + z0
    var = Ps[..., 0, 0] * k2
    posed = np.flatnonzero(np.all(np.isfinite(P), axis=(1, 2)))
    inside = np.zeros(n, bool)
    inside[posed[0]:posed[-1] + 1] = True
    out = np.full((n, 4, 4), np.nan)
    R = rotvec_to_matrix(x[inside, 3:]) @ ref
    out[inside, :3, :3] = R
    out[inside, :3, 3] = x[inside, :3] - R @ c
    out[inside, 3] = [0.0, 0.0, 0.0, 1.0]
    cov = np.full((n, 6, 6), np.nan)
    cov[inside] = 0.0
    cov[inside, :3, :3] = np.eye(3) * var[inside, None, :3]
    J = left_jacobian(x[inside, 3:])
    Cr = J * var[inside, None, 3:] @ J.swapaxes(-1, -2)
    cov[inside, 3:, 3:] = np.degrees(np.degrees(Cr))
    sig = np.sqrt(np.einsum("nii->ni", cov))
    return SmoothedPoses(out, sig, cov, wt, np.sqrt(k2), k2 * lam, model, llb[:, 0], sorted(jumps))


def smooth_track(result, bone: str, *, center, **options) -> SmoothedPoses:
    """:func:`smooth_poses` of ``bone``'s poses in ``result`` (a
    :class:`~core.tracking.results.TrackingResult` over consecutive frames), with each frame's
    confidence σ and flags; ``options``: :func:`smooth_poses`' keywords."""
    P = result.poses(bone)
    S = np.full((len(P), 6), np.nan)
    fl = np.zeros(len(P), bool)
    for k, f in enumerate(result.frames):
        r = result.results.get((bone, f))
        if r is None:
            continue
        fl[k] = bool(r.flags)
        sg = (r.confidence or {}).get("sigma")
        if sg is not None:
            S[k] = [np.inf if v is None else v for v in sg]
    return smooth_poses(P, S, center=center, flagged=fl, **options)
