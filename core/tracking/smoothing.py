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
measured as the others, the outlier search and the robust weights judging them).

Outliers
--------
A frame far off its neighbours (a tracking failure, flagged or not) is judged by the same likelihood
as a transient (*Transients*): with the bursts, each candidate frame is tried as an *outlier*, its
measurement's variance multiplied (per coordinate, the best of :data:`OUTLIERS`, a coordinate changed
where it gains), and the intervention that raises the innovations' likelihood most is taken where its
gain is over ``outliers`` (:data:`OUTLIER_GAIN`) — a spike out and back is one outlier better than two
bursts, a step one burst better than a run of outliers — and the fit repeated (at most
:data:`MAX_OUTLIERS`). A flagged frame's gain is credited ``flagged_prior`` (:data:`FLAGGED_PRIOR`, log
prior odds): the tracker's flag makes it suspect, so where an outlier and a burst explain a frame alike
(at a trial's last frame a spike and a step look the same) the flagged one is taken for an outlier. The
first frames, whose innovations the filter's diffuse start leaves out of the likelihood, are judged on
the frames reversed in time. Before, with the bursts alone, a frame flagged 1, 2 or 5 mm off on a
synthetic track (σ 0.05 mm) came out 0.96-1.01, 1.97-2.02 or 4.92-4.99 mm off (its spike taken for a
transient, or beyond ~2 mm no process noise keeping ``k`` within ``max_scale``); now it is pulled in
(0.007-0.033 mm, as with ``flagged_weight`` 0), at either end of the trial and three in a row too
(``tests/core/tracking/test_smoothing_outliers.py``); on the acceptance runs a flagged frame moved 1, 2
or 5 mm came out 0.012-0.043 mm off in all 18 bone-runs (up to 1.06 / 2.06 / 5.06 mm without the search;
``core.studies.tracking.smoother``), and of their own flagged frames 11 of 18 runs' were taken (the
figures within noise of not taking them). Two or more frames off alike at a trial's very end agree with
each other, a step there, and no one of them is off its neighbours: a run of flagged frames at either end
(up to :data:`END_RUN`, the first or last 2, 3, … of it) is also tried as one outlier, credited the flag's
prior once (the start's judged reversed in time). Frames 0-2 or 77-79 of an 80-frame synthetic walk flagged
1, 2 or 5 mm off came out up to 1.17 / 3.49 / 10.53 mm off before (frame 1 of 0-2 at 2 mm: 3.49, 1.92 before
the outlier search), now 0.022-0.068 mm; good flagged runs there are not taken, and the stored acceptance
runs' smoothed poses (d262386 and f4f4b08, 18 bone-runs each, ``core.studies.tracking.smoother``) are the
same to the bit. An unflagged run off alike at an end is still followed. A frame taken may be taken again
(its variance multiplied further, at most by the largest of :data:`OUTLIERS`). The filter runs from the
first to the last frame with a pose. ``robust``: then frames whose smoothed
residual stands more than ``robust`` × their own scaled σ off (RMS over the translation or the rotation
coordinates) are down-weighted by ``(robust / d)²`` and the fit repeated (at most :data:`MAX_ROUNDS`
fits in all); None: no down-weighting.

Scale
-----
Where the motion is too fast or irregular for the model at the trial's frame rate (a few frames
over a whole stance), the likelihood can explain it as measurement noise far above the tracker's
σ, and smooth the real motion away (a 12-frame stance of the demo trial: k up to 16, errors up to
1.4 mm against 0.02–0.07 mm per frame; bounded, 0.01–0.12 mm). ``max_scale`` (:data:`MAX_SCALE`)
bounds ``k``: the ``λ`` is the likeliest of those whose ``k`` is within it, else the largest tried
(hardly any smoothing). While bursts and outliers are searched for, ``k`` is judged there by the median
normalised innovation (over that of χ² with one degree of freedom), which one frame far off does not
move — by the mean, a frame 5 mm off at σ 0.05 mm pushed every ``k`` over the bound, the least smoothing
was taken and the frame followed — and by the mean after (the median let a 12-frame stance's few frames
the model cannot follow be smoothed away). On the acceptance runs ``k`` was 0.15–1.24, the bound never
met. A coordinate with fewer than :data:`MIN_INNOVATIONS` innovations (frames taken for outliers
not counted) cannot tell its ``k`` from the data: the concentrated likelihood flattens as ``λ`` grows and
``k`` falls towards 0 with the smoothed σ (8 frames of a synthetic walk, σ 0.05 mm, a flagged frame 2 mm
off: ``k`` < 0.1 on 70 of 72 coordinates over 12 draws, 4 % of the errors within 2σ); its ``k`` is taken
as 1 there (the σ given; 93-96 % within 2σ for 8-12 frames) and its errors as independent.

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
shared, against 12.7 s trying every frame; with the outliers tried too and the AR(1) errors, 0.89 s on
a clean 1000-frame track, 4.6 s with five frames flagged 2 mm off, each a round of the search, against
0.57 / 1.29 s without the outlier search).

Coverage
--------
The smoothed σ is the posterior's. Taking the frames' errors as independent it covered 77–97 % of the
acceptance runs' translation and 71–98 % of their rotation errors within 2σ (means 88.5 / 86.0 %;
95.4 % if right), for two reasons their errors show (``core.studies.tracking.smoother``): part of each
run's error is common to all its frames — the run's mean error is 0–31 % of its mean square per axis,
5 % on average; no pooling of frames removes it and no trial's data can tell it from the pose (about
each run's mean error the coverage is 92.3 / 93.2 %) — and the rest is correlated from frame to frame
(lag-1 −0.16 to 0.50), so pooling neighbours removes less of it than independent errors would.
``correlated`` (the default) takes the second into account: once the bursts, outliers and weights are
settled, each coordinate's errors are modelled as an AR(1) process (one more state; a frame's variance
over its plain one, a weight's or an outlier's, white) whose coefficient is the likeliest of
:data:`PHIS`, the process noise kept (chosen with the coefficient, the errors' correlation took up part
of a real transient: the 1 mm / 1° jerk's added error 0.027 mm / 0.395°, against 0.023 / 0.140). The
coverage is then 77–98 / 73–98 % (means 90.6 / 87.2 %; about the run's mean error 93.6 / 94.3 %), the
errors × the bound and the jerk's within noise of independent errors'. The first reason is beyond the
smoother: it is the tracker's systematic error.

This smoother uses neighbouring frames, so the single-frame Cramér–Rao bound
(:mod:`core.tracking.bound`) does not bound it: its errors can fall below that bound, and are a
separate figure from the per-frame goal. A real transient faster than the process noise allows
(an impact) is smoothed too; ``core.studies.tracking.smoother`` measures how much.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..geometry.transforms import matrix_to_rotvec, rotvec_to_matrix
from .smoothing_filter import (
    best_lambda,
    candidate_frames,
    end_runs,
    group_outliers,
    interventions,
    kalman,
    model_matrices,
    rts,
)

__all__ = ["BURSTS", "BURST_CANDIDATES", "END_RUN", "FLAGGED_PRIOR", "GRID", "MAX_BURSTS", "MAX_OUTLIERS",
           "MAX_ROUNDS", "MAX_SCALE", "MIN_INNOVATIONS", "MODELS", "OUTLIERS", "OUTLIER_GAIN", "PHIS",
           "TRANSIENT_GAIN",
           "SmoothedPoses", "left_jacobian", "smooth_poses", "smooth_track"]

#: the motion models: state per coordinate (position, velocity[, acceleration])
MODELS = ("velocity", "acceleration")
#: λ = q / k² (per frame) tried: log-spaced, 4 a decade
GRID = np.logspace(-12.0, 4.0, 65)
#: the most refits (robust weights, bursts, outliers)
MAX_ROUNDS = 40
#: the most bursts let in
MAX_BURSTS = 6
#: a burst's process-noise factors tried, and the pooled log-likelihood gain that lets one in
BURSTS = (1e2, 1e4, 1e6)
TRANSIENT_GAIN = 15.0
#: the most frames taken for outliers
MAX_OUTLIERS = 16
#: an outlier's measurement-variance factors tried, and the log-likelihood gain that takes one
#: (``outliers``), and the log prior odds credited to a flagged frame's gain (``flagged_prior``)
OUTLIERS = (1e2, 1e4, 1e6)
OUTLIER_GAIN = 15.0
FLAGGED_PRIOR = 10.0
#: the frames tried for a burst or an outlier each time: those whose residuals, about them, are largest
BURST_CANDIDATES = 24
#: the longest run of flagged frames at a trial's end tried as one outlier (module docs, *Outliers*)
END_RUN = 8
#: the AR(1) coefficients of the frames' errors tried (``correlated``)
PHIS = np.linspace(0.0, 0.9, 10)
#: the largest scale ``k`` on the σ given (``max_scale``)
MAX_SCALE = 2.0
#: a coordinate with fewer innovations than this (frames taken for outliers not counted) keeps the σ given
#: (``k`` = 1) and the errors independent (:func:`_short`)
MIN_INNOVATIONS = 10


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
        Each frame's measurement weight (1 plain; below 1 down-weighted by ``robust``, or taken for
        an outlier: 1 / its largest variance factor; 0 not measured: no pose, flagged, or no σ).
    scale : (6,) array
        ``k`` per coordinate: the factor the σ given were scaled by (measurement σ = k σ_f).
    process_noise : (6,) array
        ``q`` per coordinate, (mm or rad)² per frame³ (velocity) or per frame⁵ (acceleration).
    model : str
    log_likelihood : (6,) array
        The innovations' concentrated log-likelihood per coordinate at the chosen ``λ``.
    bursts : list of int
        Frames (indices) where a burst of process noise was let in (``transients``).
    outliers : list of int
        Frames (indices) taken for outliers, their measurement's variance multiplied (``outliers``).
    correlation : (6,) array
        Per coordinate the AR(1) coefficient of the frames' errors (``correlated``; 0: independent).
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
    outliers: list = field(default_factory=list)
    correlation: np.ndarray = field(default_factory=lambda: np.zeros(6))

    def to_dict(self) -> dict:
        """JSON-ready: per frame the pose (4×4 rows, None where NaN), σ, covariance and weight; the
        model, scale and process noise."""
        def rows(a, d):
            return [None if not np.all(np.isfinite(x)) else np.round(x, d).tolist() for x in a]

        return {"model": self.model, "scale": np.round(self.scale, 5).tolist(), "bursts": list(self.bursts),
                "outliers": list(self.outliers), "correlation": np.round(self.correlation, 3).tolist(),
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


def _padded(sm: SmoothedPoses, lo: int, n: int) -> SmoothedPoses:
    """``sm`` over frames ``lo ..`` of ``n``: NaN poses, σ and covariance and weight 0 elsewhere."""
    def pad(a, fill):
        out = np.full((n, *a.shape[1:]), fill, dtype=float)
        out[lo:lo + len(a)] = a
        return out

    return SmoothedPoses(pad(sm.poses, np.nan), pad(sm.sigma, np.nan), pad(sm.covariance, np.nan),
                         pad(sm.weights, 0.0), sm.scale, sm.process_noise, sm.model, sm.log_likelihood,
                         [int(t + lo) for t in sm.bursts], [int(t + lo) for t in sm.outliers], sm.correlation)


def _fit(z, r, model, boost, inflate, max_scale, robust: bool):
    """Per coordinate the likeliest ``λ`` of :data:`GRID` (refined, :func:`best_lambda`) whose scale
    is within ``max_scale`` (module docs, *Scale*), judged by the mean normalised innovation or with
    ``robust`` by the median (a frame far off does not move it)."""
    grid = np.broadcast_to(GRID, (z.shape[1], len(GRID)))
    ll, k2, kr = kalman(z, r, grid, model, boost=boost, inflate=inflate)
    if max_scale is not None:  # the frames no noisier than max_scale x their sigma say
        ll = np.where((kr if robust else k2) <= max_scale ** 2, ll, -np.inf)
        ll[np.isinf(ll).all(axis=1), -1] = 0.0  # none: the least smoothing tried
    return best_lambda(ll, GRID)


def _innovations(r, model: str, inflate=None) -> np.ndarray:
    """``(C,)`` the innovations the likelihood counts per coordinate (the measured frames but the diffuse
    start's first ``d``), less the frames taken for outliers where ``inflate`` is given."""
    d = len(model_matrices(model)[0])
    m = np.isfinite(r) & (r > 0)
    if inflate is not None:
        m = m & (np.broadcast_to(inflate[..., 0], r.shape) == 1.0)
    return np.maximum(m.sum(axis=0) - d, 0).astype(float)


def _short(r, model: str, inflate) -> np.ndarray:
    """``(C,)`` the coordinates with fewer than :data:`MIN_INNOVATIONS` innovations besides the outliers':
    too few to tell the scale ``k`` from the data (the concentrated likelihood flattens as ``λ`` grows,
    ``k`` falls towards 0 and the smoothed σ with it); their ``k`` is fixed at 1 (the σ given)."""
    return _innovations(r, model, inflate) < MIN_INNOVATIONS


def _fit_correlation(z, r, model, boost, inflate, max_scale, lam, base):
    """Per coordinate the likeliest of :data:`PHIS` for the AR(1) coefficient of the errors (variance
    ``base``), the process noise ``lam`` kept (module docs, *Coverage*)."""
    C, P = z.shape[1], len(PHIS)
    ll, _, kr = kalman(z, r, np.broadcast_to(lam[:, None], (C, P)), model, boost=boost, inflate=inflate,
                       ar=(np.broadcast_to(PHIS, (C, P)), base))
    if max_scale is not None:
        ll = np.where(kr <= max_scale ** 2, ll, -np.inf)
    ll[np.isinf(ll).all(axis=1), 0] = 0.0  # none: independent
    return PHIS[np.argmax(ll, axis=1)]


def _better(found, other):
    """``other`` where it gains more than ``found`` (or ``found`` is None), else ``found``."""
    return other if other is not None and (found is None or other[3] > found[3]) else found


def _intervention(z, r, lam, model, boost, inflate, base, res, d, transients, outliers, credit, allowed,
                  runs=((), ())):
    """The next burst or outlier (:func:`~core.tracking.smoothing_filter.interventions`) among the
    frames whose residuals ``res`` are largest, or an outlier among the first ``d + 1`` measured frames
    judged on the frames reversed in time (forwards the filter's diffuse start takes the first ``d``
    measurements as they are: their innovations are not in the likelihood), or a run of flagged frames at
    either end taken as one outlier (``runs``: :func:`~core.tracking.smoothing_filter.end_runs`' start and
    end groups; the start's judged reversed in time; credited the flag's prior once), whichever gains
    more."""
    cand = candidate_frames(res, BURST_CANDIDATES)
    found = interventions(z, r, lam, model, boost, inflate, base, cand, bursts=BURSTS, outliers=OUTLIERS,
                          burst_gain=transients, outlier_gain=outliers, credit=credit, allowed=allowed)
    if outliers is None:
        return found
    start, end = runs
    if end:
        found = _better(found, group_outliers(z, r, lam, model, boost, inflate, base, end, outliers=OUTLIERS,
                                              outlier_gain=outliers, credit=float(credit[end[0]].max())))
    n = len(z)
    first = np.flatnonzero(np.isfinite(r).any(axis=1))[:d + 1]  # the first d + 1 measured frames
    if not allowed[first].any() and not start:
        return found
    zr, rr = z[::-1], r[::-1]
    br = np.concatenate([boost[:1], boost[:0:-1]])  # the step into reversed frame t is the one into n - t
    ir = inflate[::-1]
    llr, _, _ = kalman(zr, rr, lam[:, None], model, boost=br, inflate=ir)
    if allowed[first].any():
        back = interventions(zr, rr, lam, model, br, ir, llr[:, 0], n - 1 - first[::-1], bursts=BURSTS,
                             outliers=OUTLIERS, burst_gain=None, outlier_gain=outliers, credit=credit[::-1],
                             allowed=allowed[::-1])
        if back is not None:
            found = _better(found, (back[0], n - 1 - back[1], back[2], back[3]))
    if start:
        back = group_outliers(zr, rr, lam, model, br, ir, llr[:, 0], [n - 1 - g for g in start],
                              outliers=OUTLIERS, outlier_gain=outliers, credit=float(credit[start[0]].max()))
        if back is not None:
            found = _better(found, (back[0], sorted(n - 1 - t for t in back[1]), back[2], back[3]))
    return found


def smooth_poses(poses, sigma, *, center, flagged=None, model: str = "acceleration", weigh: str = "equal",
                 robust: float | None = 2.5, flagged_weight: float = 1.0,
                 transients: float | None = TRANSIENT_GAIN, outliers: float | None = OUTLIER_GAIN,
                 flagged_prior: float = FLAGGED_PRIOR, correlated: bool = True,
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
    outliers : float or None
        The log-likelihood gain over which a frame is taken for an outlier, its measurement's
        variance multiplied (module docs, *Outliers*); None: never.
    flagged_prior : float
        Log prior odds credited to a flagged frame's gain as an outlier (module docs, *Outliers*).
    correlated : bool
        Fit the frames' errors as correlated from frame to frame (AR(1), module docs, *Coverage*);
        False: independent.
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
    model_matrices(model)
    if weigh not in ("sigma", "equal"):
        raise ValueError(f"weigh: expected 'sigma' or 'equal', got {weigh!r}")
    if robust is not None and not robust > 0:
        raise ValueError(f"robust: expected a positive threshold or None, got {robust!r}")
    if not 0.0 <= flagged_weight <= 1.0:
        raise ValueError(f"flagged_weight: expected a weight in [0, 1], got {flagged_weight!r}")
    if max_scale is not None and not max_scale > 0:
        raise ValueError(f"max_scale: expected a positive scale or None, got {max_scale!r}")
    for name, g in (("transients", transients), ("outliers", outliers)):
        if g is not None and not g > 0:
            raise ValueError(f"{name}: expected a positive log-likelihood gain or None, got {g!r}")
    if not flagged_prior >= 0:
        raise ValueError(f"flagged_prior: expected a log prior odds >= 0, got {flagged_prior!r}")
    d = len(model_matrices(model)[0])
    ok = np.all(np.isfinite(P), axis=(1, 2))
    w = np.where(ok, np.where(fl, flagged_weight, 1.0), 0.0)
    if (w > 0).sum() < d + 2:
        raise ValueError(f"poses: expected at least {d + 2} measured (posed, unflagged) frames, "
                         f"got {(w > 0).sum()}")
    posed = np.flatnonzero(ok)
    if posed[0] > 0 or posed[-1] < n - 1:  # the filter over the posed frames' span only (its diffuse start
        lo, hi = posed[0], posed[-1] + 1  # carried over leading frames without a pose lost precision)
        sub = smooth_poses(P[lo:hi], S[lo:hi], center=c, flagged=fl[lo:hi], model=model, weigh=weigh,
                           robust=robust, flagged_weight=flagged_weight, transients=transients,
                           outliers=outliers, flagged_prior=flagged_prior, correlated=correlated,
                           max_scale=max_scale)
        return _padded(sub, lo, n)
    z, ref, ok = _chart(np.where(w[:, None, None] > 0, P, np.nan), c)
    s = _chart_sigma(z, S, ok, weigh)
    rob, boost, inflate, jumps, outl = np.ones(n), np.ones((n, 6, 1)), np.ones((n, 6, 1)), [], []
    credit = np.where(fl, flagged_prior, 0.0)
    search = transients is not None or outliers is not None
    for _ in range(MAX_ROUNDS + 1):
        wt = w * rob
        r = np.where(wt[:, None] > 0, s ** 2 / np.maximum(wt, 1e-12)[:, None], np.inf)
        lam = _fit(z, r, model, boost, inflate, max_scale, search)
        llb, k2, _, store, z0 = kalman(z, r, lam[:, None], model, keep=True, boost=boost, inflate=inflate)
        xs, Ps = rts(store, model)
        xs, Ps, k2 = xs[:, :, 0], Ps[:, :, 0], k2[:, 0]
        if search:  # first the bursts and outliers, every other frame at its plain weight
            res = (z - z0 - xs[..., 0]) / np.sqrt(k2 * s ** 2)
            allowed = (w > 0) & (inflate[:, :, 0].max(axis=1) < max(OUTLIERS))
            found = _intervention(z, r, lam, model, boost, inflate, llb[:, 0], res, d,
                                  transients if len(jumps) < MAX_BURSTS else None,
                                  outliers if len(outl) < MAX_OUTLIERS else None, credit, allowed,
                                  end_runs(fl, allowed, END_RUN))
            if found is not None and found[0] == "burst":
                boost[found[1], :, 0] *= found[2]
                jumps.append(found[1])
            elif found is not None and found[0] == "outliers":  # a run at an end, as one
                for t in found[1]:
                    inflate[t, :, 0] = np.minimum(inflate[t, :, 0] * found[2], max(OUTLIERS))
                outl += [t for t in found[1] if t not in outl]
            elif found is not None:
                inflate[found[1], :, 0] = np.minimum(inflate[found[1], :, 0] * found[2], max(OUTLIERS))
                outl += [] if found[1] in outl else [found[1]]
            search = found is not None
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
    phi = np.zeros(6)
    short = _short(r, model, inflate)
    if correlated:  # the last fit again, the errors' AR(1) coefficient chosen, its process noise kept
        phi = np.where(short, 0.0, _fit_correlation(z, r, model, boost, inflate, max_scale, lam, s ** 2))
        llb, k2, _, store, z0 = kalman(z, r, lam[:, None], model, keep=True, boost=boost, inflate=inflate,
                                       ar=(phi[:, None], s ** 2))
        xs, Ps = rts(store, model)
        xs, Ps, k2 = xs[:, :, 0], Ps[:, :, 0], k2[:, 0]
    k2 = np.where(short, 1.0, k2)  # (too few innovations to tell the scale: the σ given)
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
    return SmoothedPoses(out, sig, cov, wt / inflate[:, :, 0].max(axis=1), np.sqrt(k2), k2 * lam, model,
                         llb[:, 0], sorted(jumps), sorted(outl), phi)


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
