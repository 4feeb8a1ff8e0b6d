"""The tracker's checks of a registration: failure reasons, same optimum, uncertainty.

:func:`failures` lists why a registration of :func:`core.tracking.trial.track` fails (not
converged, a score drop against the bone's recent good frames or below its first frame, a collapse
of the score, a jump from the initial guess, a pose off the bone's own motion
(:func:`motion_check`), a low score against a flagged first frame; :func:`confirmable` tells
which of them a confirmed optimum clears); :func:`same_optimum` tells whether two poses are the
same optimum (:data:`SAME_OPTIMUM`); :func:`uncertain` flags a confidence beyond the user's limits,
:func:`sigma_check` one far beyond the bone's own. See the
module docs of :mod:`core.tracking.trial` for how the tracker uses them.

The thresholds :data:`COLLAPSE_RATIO`, :data:`MOTION_LIMIT`, :data:`MOTION_FLOOR` and
:data:`SIGMA_LIMIT` are the defaults of the :class:`~core.tracking.options.TrackingOptions`
fields ``collapse_ratio``, ``motion_limit``, ``motion_floor`` and ``sigma_limit``, which the
tracker passes here (:func:`failures` reads the first three from its options ``o``).

Pose differences are taken in closed form (:func:`pose_delta`, :func:`step_pose`): the same
values as :func:`core.geometry.transforms.params_from_pose` and
:func:`~core.geometry.transforms.pose_from_params` (to rounding), without their input checks
and scipy's rotation objects — the tracker's own rigid poses, a few per frame.
"""

from __future__ import annotations

import math

import numpy as np

from ..geometry.transforms import params_from_pose, pose_from_params

__all__ = ["COLLAPSE_RATIO", "MOTION_FLOOR", "MOTION_LIMIT", "SAME_OPTIMUM", "SCORE_DROP", "SIGMA_LIMIT",
           "confirmable", "failures", "motion_check", "motion_limits", "motion_miss", "pose_delta",
           "same_optimum", "sigma_check", "step_pose", "uncertain"]

#: Poses closer than this (mm, degrees) are the same optimum (:func:`same_optimum`).
SAME_OPTIMUM = (0.5, 0.5)


def _norm(x: np.ndarray) -> float:
    """``float(np.linalg.norm(x))`` of a float64 vector: the same square root of ``x.dot(x)``
    without its argument handling."""
    return math.sqrt(float(x.dot(x)))


def _finite(*arrays) -> bool:
    """Whether every element of the arrays is finite."""
    return all(np.isfinite(a).all() for a in arrays)


def _rotvec(R: np.ndarray) -> np.ndarray | None:
    """Rotation vector (rad) of a rotation matrix, or None near a half turn (left to scipy)."""
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = R.tolist()  # (Python numbers: the same values)
    w = np.array([r21 - r12, r02 - r20, r10 - r01])
    s = 0.5 * _norm(w)  # sin(angle)
    c = 0.5 * ((r00 + r11 + r22) - 1.0)  # cos(angle); np.trace's order of the sum
    th = float(np.arctan2(s, c))
    if th > 3.0:  # near pi the antisymmetric part loses the axis
        return None
    k = 0.5 if s < 1e-12 else th / (2.0 * s)
    return k * w


def pose_delta(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Parameters (mm, rad) taking rigid pose ``a`` to pose ``b`` about centre ``c`` (bone frame):
    :func:`~core.geometry.transforms.params_from_pose` ``(b, center=c, base=a)``."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    c = np.asarray(c, dtype=float)
    Ra, Rb = a[:3, :3], b[:3, :3]
    rv = _rotvec(Rb @ Ra.T)
    if rv is None or not _finite(a, b):
        return params_from_pose(b, center=c, base=a)
    disp = Rb @ c + b[:3, 3] - Ra @ c - a[:3, 3]
    return np.concatenate((disp, rv))


def step_pose(p: np.ndarray, base: np.ndarray, c: np.ndarray) -> np.ndarray:
    """:func:`~core.geometry.transforms.pose_from_params` ``(p, center=c, base=base)`` of one
    parameter vector ``p`` (mm, rad) about a rigid ``base``."""
    p = np.asarray(p, dtype=float)
    base = np.asarray(base, dtype=float)
    c = np.asarray(c, dtype=float)
    if not _finite(p, base):
        return pose_from_params(p, center=c, base=base)
    r = p[3:]
    th = _norm(r)
    Rd = np.eye(3)
    if th > 0:
        k0, k1, k2 = (r / th).tolist()
        K = np.array([[0.0, -k2, k1], [k2, 0.0, -k0], [-k1, k0, 0.0]])
        Rd = Rd + np.sin(th) * K + (1.0 - np.cos(th)) * (K @ K)
    Rb, tb = base[:3, :3], base[:3, 3]
    R = Rd @ Rb
    out = np.eye(4)
    out[:3, :3] = R
    out[:3, 3] = Rb @ c + tb + p[:3] - R @ c
    return out


_DISTANCES: dict = {}  # _distance of the tracker's (4, 4) poses by their bytes


def _distance(a, b, c) -> tuple[float, float]:
    """``(mm, degrees)`` of :func:`pose_delta` ``(a, b, c)``; kept by the poses' bytes for the next
    call with the same poses (a frame's checks measure the registration from the guess and from the
    motion prediction, which is the guess when the tracker guessed by velocity)."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    c = np.asarray(c, dtype=float)
    key = None
    if a.shape == b.shape == (4, 4) and c.shape == (3,):
        key = (a.tobytes(), b.tobytes(), c.tobytes())
    hit = _DISTANCES.get(key) if key is not None else None
    if hit is None:
        d = pose_delta(a, b, c)
        hit = (_norm(d[:3]), float(np.degrees(_norm(d[3:]))))
        if key is not None:
            if len(_DISTANCES) >= 256:
                _DISTANCES.clear()
            _DISTANCES[key] = hit
    return hit


#: A score below this fraction of the median of the bone's recent good scores fails outright: a
#: collapse that no wider search or restart check clears (:func:`failures`; the default of
#: ``TrackingOptions.collapse_ratio``).
COLLAPSE_RATIO = 0.6
#: Flags that start with this are score drops the tracker may confirm rather than flag
#: (:func:`confirmable`).
SCORE_DROP = "score drop"


def failures(res, guess_pose, center, good_scores, o, *, start_score=None,
             jump_factor: float = 1.0, history=None, frame: int | None = None,
             reference: float | None = None, prediction=None) -> list[str]:
    """Why registration ``res`` fails under the tracking options ``o`` (module docs of
    :mod:`core.tracking.trial`): ``good_scores`` are the bone's good scores so far (in tracking
    order), ``start_score`` its first frame's; the jump limit from ``guess_pose`` is
    ``o.max_jump`` × ``jump_factor`` (the tracker widens it for first frames and retries).

    Scores
    ------
    A bone's score follows the image as well as the registration: on the foot demo the talus of a
    correct registration falls from 0.56-0.58 at frame 0 to 0.34-0.44 in the late stance (one
    H200, 512², ``resources/benchmarks/calibration_tracking_h200.json``), below any fixed fraction
    of the first frame's score that a false optimum would also cross. So a score is judged
    against the recent frames, and a drop is verified before it is flagged:

    * ``"score drop"`` — below ``o.min_score_ratio`` × the median of the last ``o.history`` good
      scores;
    * ``"score drop below the start"`` — below ``o.min_start_ratio`` × ``start_score`` (the floor
      a slow drift into a false optimum crosses) while every recent good score is above that
      floor: the first frame to cross it is verified; once a verified frame below the floor is
      among the recent good scores, the floor has been re-based by the image and later frames are
      judged by the recent median alone (until the recent scores are all above the floor again);
    * ``"score collapse"`` — below ``o.collapse_ratio`` (default :data:`COLLAPSE_RATIO`) × the
      recent median: flagged whatever a verification finds.

    The first two are *confirmable* (:func:`confirmable`): the tracker retries the frame wider
    and checks the result with restarts (:func:`core.tracking.verify.verify_start`), and when the
    searches agree on the optimum and no restart scores better or equally well elsewhere, the
    image changed, not the registration, and the frame is noted instead of flagged.

    Measured against the truth (:mod:`core.studies.tracking.flag_study`, one H100,
    ``resources/benchmarks/tracking_flags_h100.json``): on the talus tracked alone over the
    demo's stance (256², 60 frames), which is lost in the late stance, the fixed floor flagged
    frames 42-59 and this check 44-59 — every frame over 1 mm or 2° flagged either way (15 of
    15); frame 42 (0.12 mm, 0.79°) was confirmed instead, frame 43 then judged by the recent
    frames. Replayed on the demo's recorded late-stance scores (joint, tracked within 0.5 mm),
    the fixed floor flagged 9-15 frames per run, this check sends 0-3 of them to verification and
    flags none outright. Injected failures: the two views' images exchanged were flagged in 20 of
    20 frames (a collapse every time), a start 5 mm / 5° off was corrected in 19 of 20 and flagged
    in the other; the images of a frame 10 frames later went unflagged in 10 of 20 (9 before) —
    a valid image of the bone 2-7 mm away, which only the jump from the guess can tell, and a
    retry's limit (twice ``o.max_jump``) lets through. Keeping ``o.max_jump`` on retries catches
    those over 4 mm (4 of the 10; measured on this 2-core CPU, 3 of 6) but flagged every start
    5 mm off that the retry had corrected (8 of 8 there, ``tracking_flags_cpu.json``), and a bone
    whose guesses go stale after flagged frames would stay flagged. Given the bone's good poses
    (``history``) and the ``frame`` number, :func:`motion_check` judges the pose against the
    bone's own recent motion instead (limits ``o.motion_limit``, ``o.motion_floor``): on the
    acceptance trial (1024², joint, one H200, ``resources/benchmarks/tracking_flags2_h200.json``)
    the frames out of order went from 4 of 12 silent to 0 (the other 8 within 1 mm / 2°),
    corrected starts stayed unflagged (11 of 12, the 12th flagged either way) and no tracked frame
    was flagged (0 of 292 good frames). ``prediction``: the frame's constant-velocity prediction
    from ``history`` when the caller has it (the tracker's frame step computes it once for the
    guess and every check of the frame, :func:`core.tracking.frame_state.motion_prediction`);
    None computes it.

    ``reference``: the score of the bone's first flagged frame while it has no good score (the
    tracker's :class:`~core.tracking.frame_state._BoneState`); a score below ``o.min_score_ratio`` × it
    is flagged ``"low score against the flagged first frame"`` — not confirmable, there is no
    verified frame to confirm against. The wrist radius with the Gauss–Newton global search (one
    H200): frame 0099 flagged (not converged) at 0.391, frame 0158 at 0.283 16 mm from the
    quadratic form's pose, unflagged before; now flagged, retried wider to 0.397 within 0.5 mm /
    0.9° of that pose, and flagged ambiguous by the restart check.
    """
    out = []
    if not res.converged:
        out.append(f"not converged ({res.reason})")
    recent = [float(v) for v in (good_scores or [])[-o.history:] if v is not None and math.isfinite(v)]
    if not recent and reference is not None and math.isfinite(reference) \
            and res.score < o.min_score_ratio * float(reference):
        out.append(f"low score against the flagged first frame ({res.score:.3f} < {o.min_score_ratio:g} x "
                   f"{float(reference):.3f}; no verified frame to compare with)")
    med = _median(recent) if recent else None
    if med is not None and res.score < o.min_score_ratio * med:
        out.append(f"{SCORE_DROP} ({res.score:.3f} < {o.min_score_ratio:g} x recent median {med:.3f})")
    if start_score is not None and math.isfinite(start_score):
        floor = o.min_start_ratio * float(start_score)
        if res.score < floor and (not recent or min(recent) >= floor):
            out.append(f"{SCORE_DROP} below the start ({res.score:.3f} < {o.min_start_ratio:g} x first frame "
                       f"{start_score:.3f})")
    collapse = getattr(o, "collapse_ratio", COLLAPSE_RATIO)
    if med is not None and res.score < collapse * med:
        out.append(f"score collapse ({res.score:.3f} < {collapse:g} x recent median {med:.3f})")
    dt, dr = _distance(guess_pose, res.pose, center)
    stale = _stale(history, frame)
    if dt > o.max_jump[0] * jump_factor * stale or dr > o.max_jump[1] * jump_factor * stale:
        out.append(f"pose jump ({dt:.2f} mm, {dr:.2f} deg from the guess)")
    if history is not None and frame is not None:
        out += motion_check(res.pose, history, frame, center, n=o.history,
                            limit=getattr(o, "motion_limit", MOTION_LIMIT),
                            floor=getattr(o, "motion_floor", MOTION_FLOOR), prediction=prediction)
    return out


def _median(values: list) -> float:
    """``float(np.median(values))`` of a few finite numbers without numpy's machinery (the same
    value: the middle one, or the two middle ones' sum halved)."""
    v = sorted(values)
    m = len(v) // 2
    return float(v[m]) if len(v) % 2 else float((v[m - 1] + v[m]) / 2)


def _stale(history, frame) -> float:
    """How many of the good poses' spacings the guess of ``frame`` extrapolates over (at least 1):
    after flagged frames the velocity guess extrapolates one noisy step over the gap, and the jump
    limit from it grows alike (on the 512² foot demo, one H200, the metatarsal2's guesses were
    12-36° off in frames 38-45 after three flagged frames while the bone was within 1.6°)."""
    h = list(history or [])
    if frame is None or len(h) < 2:
        return 1.0
    (f0, _), (f1, _) = h[-2], h[-1]
    return max(1.0, abs(frame - f1) / max(abs(f1 - f0), 1))


#: :func:`motion_check`: a pose farther from the motion prediction than this many times the median
#: of the bone's recent prediction residuals (mm and degrees apart) is flagged ...
#: (the default of ``TrackingOptions.motion_limit``)
MOTION_LIMIT = 6.0
#: ... and never closer than this (mm, degrees) for one frame of constant acceleration (the default
#: of ``TrackingOptions.motion_floor``)
MOTION_FLOOR = (1.0, 2.0)


_PREDICTIONS: dict = {}  # _predict's poses by their inputs (bytes, frames), a copy handed out each call


def _predict(f0, T0, f1, T1, f, c) -> np.ndarray:
    """Constant-velocity prediction at frame ``f`` from poses at frames ``f0``, ``f1`` (as
    :func:`core.tracking.trial.predict_pose` ``"velocity"``; the tracker computes a frame's once,
    :func:`core.tracking.frame_state.motion_prediction`, and hands it to :func:`failures`). Kept by its
    inputs for the next call with the same ones: a frame's motion prediction is, once its pose joins the
    history, the prediction whose miss the next frame's motion limits measure (:func:`_miss`). A new
    array each call (the caller's own)."""
    T1 = np.asarray(T1, float)
    if f1 == f0:
        return T1
    T0 = np.asarray(T0, float)
    c = np.asarray(c, dtype=float)
    key = None
    if T0.shape == T1.shape == (4, 4) and c.shape == (3,):
        key = (T0.tobytes(), T1.tobytes(), c.tobytes(), f0, f1, f)
        hit = _PREDICTIONS.get(key)
        if hit is not None:
            return hit.copy()
    out = step_pose(pose_delta(T0, T1, c) * (f - f1) / (f1 - f0), T1, c)
    if key is not None:
        if len(_PREDICTIONS) >= 64:
            _PREDICTIONS.clear()
        _PREDICTIONS[key] = out.copy()
    return out


def _reach(f0, f1, f) -> float:
    """How a constant acceleration's miss of the velocity prediction grows with the frame gaps
    (1 for consecutive frames): ``|f - f1| (|f - f1| + |f1 - f0|) / 2``."""
    g, g0 = abs(f - f1), abs(f1 - f0)
    return max(g * (g + g0) / 2.0, 1.0)


def motion_check(pose, history, frame: int, center, *, n: int = 10, limit: float = MOTION_LIMIT,
                 floor=MOTION_FLOOR, min_residuals: int = 3, prediction=None) -> list[str]:
    """The ``"unexpected motion"`` flag: ``pose`` (frame ``frame``) against the constant-velocity
    prediction from the bone's last two good poses, judged by the bone's own recent motion.

    ``history`` holds the bone's good ``(frame, pose)`` (tracking order). For each of its last
    ``n`` poses with two good predecessors, the miss of their prediction (mm and degrees apart,
    divided by :func:`_reach` of the gaps) is a sample of how unpredictable the bone's motion and
    its registrations are; with at least ``min_residuals`` of them the limit is ``limit`` × their
    median, at least ``floor``, times the reach of this frame's gaps. Without enough history
    nothing is flagged. A registration of a valid image of the bone at another pose (a frame out
    of order, a view's frames shifted) is a true optimum that restarts confirm and the score checks
    pass; only the motion tells it from the bone's track. Unlike a fixed jump limit from the
    start, a start far off (a stale guess) that the retry corrected is not flagged: the
    prediction comes from the good poses, not from the start. ``prediction``: that prediction when
    the caller has it (:func:`failures`); None computes it.
    """
    got = motion_miss(pose, history, frame, center, n=n, limit=limit, floor=floor,
                      min_residuals=min_residuals, prediction=prediction)
    if got is None:
        return []
    dt, dr, lim_t, lim_r, m = got
    if dt > lim_t or dr > lim_r:
        return [f"unexpected motion ({dt:.2f} mm, {dr:.2f} deg from the motion prediction; limits "
                f"{lim_t:.2f} mm, {lim_r:.2f} deg from the bone's last {m} frames)"]
    return []


_MISSES: dict = {}  # the history's prediction misses by their poses and frames (_miss)


def _miss(f0, T0, f1, T1, fj, Tj, c, data=None) -> tuple[float, float]:
    """The miss of the prediction of pose ``Tj`` from ``T0``, ``T1`` over :func:`_reach` (mm,
    degrees), kept for the next frames (the same history poses each frame). ``data``: the bytes
    of ``T0``, ``T1``, ``Tj`` and ``c`` when the caller has them."""
    if data is None:
        data = (*(np.asarray(T, dtype=float).tobytes() for T in (T0, T1, Tj)), c.tobytes())
    key = (*data[:3], f0, f1, fj, data[3])
    hit = _MISSES.get(key)
    if hit is None:
        dt, dr = _distance(_predict(f0, T0, f1, T1, fj, c), Tj, c)
        k = _reach(f0, f1, fj)
        if len(_MISSES) >= 1024:
            _MISSES.clear()
        hit = _MISSES[key] = (dt / k, dr / k)
    return hit


_BOUNDS: dict = {}  # motion_miss: per history list, its prediction and limits for a frame


def motion_miss(pose, history, frame: int, center, *, n: int = 10, limit: float = MOTION_LIMIT,
                floor=MOTION_FLOOR, min_residuals: int = 3, prediction=None) -> tuple | None:
    """``(mm, degrees from the prediction, limit mm, limit degrees, residuals used)`` of
    :func:`motion_check`, or None without enough history. The limits of a history list (and the
    prediction, unless the caller passes it as ``prediction``) are kept for the next call with the
    same list, unchanged (its length and last pose the same objects), the same frame and options:
    the tracker checks each bone's registrations of a frame — joint tracking's rounds, retries —
    against its one history."""
    c = np.asarray(center, dtype=float)
    got = _limits(history, frame, c, n, limit, floor, min_residuals, prediction)
    if got is None:
        return None
    pred, lim_t, lim_r, m = got
    if prediction is not None:
        pred = prediction
    elif pred is None:  # (kept from a call that was given the prediction)
        (f0, T0), (f1, T1) = history[-2], history[-1]
        pred = _predict(f0, T0, f1, T1, frame, c)
    dt, dr = _distance(pred, pose, c)
    return dt, dr, lim_t, lim_r, m


def motion_limits(history, frame: int, center, *, n: int = 10, limit: float = MOTION_LIMIT,
                  floor=MOTION_FLOOR, min_residuals: int = 3, prediction=None) -> None:
    """Compute and keep the limits (and prediction) of :func:`motion_miss` for ``history`` and
    ``frame`` now, as its first call would (arguments as there): the tracker does so while the device
    works on the frame's first search step (:func:`core.tracking.attempt.register_checked`), and
    the checks after the registration find them kept. The same values either way."""
    _limits(history, frame, np.asarray(center, dtype=float), n, limit, floor, min_residuals, prediction)


def _limits(history, frame: int, c: np.ndarray, n: int, limit: float, floor, min_residuals: int, prediction):
    """:func:`_bounds` of ``history`` and ``frame``, kept per history list while it is unchanged (its
    length and last pose the same objects) for the same frame and options (:func:`motion_miss`)."""
    key = (int(frame), c.tobytes(), int(n), float(limit), tuple(floor), int(min_residuals))
    hit = _BOUNDS.get(id(history))
    if (hit is not None and hit[0] is history and hit[1] == len(history) and hit[1]
            and hit[2] is history[-1][1] and hit[3] == key):
        return hit[4]
    got = _bounds(history, frame, c, n, limit, floor, min_residuals, prediction)
    if isinstance(history, list):
        if len(_BOUNDS) >= 64:
            _BOUNDS.clear()
        _BOUNDS[id(history)] = (history, len(history), history[-1][1] if history else None, key, got)
    return got


def _bounds(history, frame: int, c: np.ndarray, n: int, limit: float, floor, min_residuals: int,
            prediction=None):
    """:func:`motion_miss`'s prediction and limits: ``(pose, mm, degrees, residuals)`` or None
    (the pose None when the caller has the ``prediction``: not computed, and the caller's array
    not kept)."""
    h = list(history or [])
    if len(h) < min_residuals + 2:
        return None
    lo = max(2, len(h) - int(n))
    cb = c.tobytes()
    data = [np.asarray(T, dtype=float).tobytes() for _, T in h[lo - 2:]]  # (each pose's once)
    miss = [_miss(*h[j - 2], *h[j - 1], *h[j], c, (*data[j - lo:j - lo + 3], cb)) for j in range(lo, len(h))]
    if len(miss) < min_residuals:
        return None
    if any(x != x for m in miss for x in m):  # NaN: numpy's median (NaN)
        med = np.median(np.asarray(miss), axis=0)
    else:  # the same values (_median)
        med = (_median([m[0] for m in miss]), _median([m[1] for m in miss]))
    (f0, T0), (f1, T1) = h[-2], h[-1]
    k = _reach(f0, f1, frame)
    lim_t = max(limit * float(med[0]), float(floor[0])) * k
    lim_r = max(limit * float(med[1]), float(floor[1])) * k
    pred = _predict(f0, T0, f1, T1, frame, c) if prediction is None else None
    return pred, lim_t, lim_r, len(miss)


#: :func:`sigma_check`: a confidence σ longer than this many times the median of the bone's recent
#: good frames' σ (translation or rotation) is flagged (the default of
#: ``TrackingOptions.sigma_limit``, which the tracker passes as ``limit``)
SIGMA_LIMIT = 3.0


def sigma_check(conf: dict | None, good_sigmas, *, n: int = 10, limit: float = SIGMA_LIMIT,
                min_frames: int = 5) -> list[str]:
    """The ``"uncertain"`` flag of a frame whose confidence σ (lengths of the translation and
    rotation σ vectors, :class:`~core.tracking.confidence.PoseConfidence`) exceeds ``limit`` ×
    the median of the bone's last ``n`` good frames' (``good_sigmas``: ``(mm, degrees)`` pairs,
    tracking order), given at least ``min_frames`` of them, or that is not well posed while they
    were: the cost's curvature about this optimum is much flatter than the bone's own."""
    if conf is None:
        return []
    recent = [(float(t), float(r)) for t, r in list(good_sigmas or [])[-int(n):]
              if t is not None and r is not None and math.isfinite(t) and math.isfinite(r)]
    if len(recent) < min_frames:
        return []
    mt, mr = _median([t for t, _ in recent]), _median([r for _, r in recent])
    t, r = conf.get("translation_mm"), conf.get("rotation_deg")
    if not conf.get("well_posed", True) or t is None or r is None:
        return [f"uncertain (the pose is not determined along every axis; the bone's last {len(recent)} "
                f"frames were)"]
    if t > limit * mt or r > limit * mr:
        return [f"uncertain (confidence {t:.3f} mm, {r:.3f} deg; over {limit:g} x the bone's recent "
                f"{mt:.3f} mm, {mr:.3f} deg)"]
    return []


def confirmable(flag: str) -> bool:
    """Whether ``flag`` (of :func:`failures`) is a score drop that a confirmed optimum clears."""
    return flag.startswith(SCORE_DROP)


def same_optimum(a: np.ndarray, b: np.ndarray, center) -> bool:
    """Whether poses ``a`` and ``b`` are within :data:`SAME_OPTIMUM` of each other."""
    dt, dr = _distance(a, b, center)
    return bool(dt <= SAME_OPTIMUM[0] and dr <= SAME_OPTIMUM[1])


def uncertain(conf: dict | None, limits: tuple[float, float]) -> list[str]:
    """The ``"uncertain"`` flag of a frame's confidence (a dict of
    :class:`~core.tracking.confidence.PoseConfidence`) beyond ``limits`` (mm, degrees)."""
    lt, lr = (float(v) for v in limits)
    if conf is None:
        return ["uncertain (no confidence could be computed)"]
    t, r = conf.get("translation_mm"), conf.get("rotation_deg")
    if not conf.get("well_posed", True) or t is None or r is None:
        return ["uncertain (the pose is not determined along every axis)"]
    if t > lt or r > lr:
        return [f"uncertain (confidence {t:.3f} mm, {r:.3f} deg; limits {lt:g} mm, {lr:g} deg)"]
    return []
