"""The acceptance study's per-bone records of one tracking run (:func:`core.studies.tracking.acceptance.run`):
per bone its per-frame errors against the truth and their statistics, the low-passed trajectory's, the
converged fraction and the frames not converged, the flagged frames as the run returned them
(:func:`flag_counts`) with each one's reasons (:func:`flag_reasons`: its flags, then its notes), silent
frames, the confidence σ and each frame's signals — score, work, the final stage's outcome and move,
the searched pose's error (:func:`frame_signals`; a stored record's as arrays: :func:`stored_signals`)
— (:func:`bone_records`); with the Cramér–Rao bound, the errors over it and the frames over 4× it,
flagged or silent (:func:`add_bound`, :func:`over_bound`), with what the run showed of each silent one
(:func:`silent_details`).
``pose_errors`` is importable from :mod:`core.studies.tracking.acceptance`, ``flag_counts`` and
``silent_details`` from :mod:`core.studies.tracking.acceptance_goals`, as before."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from core.geometry.transforms import params_from_pose

__all__ = ["FILTER_MIN_FRAMES", "NOTE", "SILENT_OVER_HALF", "BoneRecords", "add_bound", "bone_records",
           "error_stats", "flag_counts", "flag_reasons", "frame_signals", "over_bound", "pose_errors",
           "reasons", "silent_details", "silent_over_half", "stored_signals"]

#: the record's count of unflagged frames whose error is over 0.5 mm or 0.5° (an absolute threshold, the
#: study's first failure count; :func:`bone_records`), named ``silent_failures`` in runs stored before
#: (:func:`silent_over_half` reads either). Not issue 20's measure: that is the unflagged frames over 4×
#: the bone's Cramér–Rao bound, ``over_4x_bound.silent`` (the goals' ``silent_over_4x``).
SILENT_OVER_HALF = "silent_over_half_mm_or_deg"


def silent_over_half(t: dict) -> int | None:
    """A bone record's count of unflagged frames over 0.5 mm or 0.5° (:data:`SILENT_OVER_HALF`), from a
    run stored before the rename too (``silent_failures``); None where the record has neither."""
    v = t.get(SILENT_OVER_HALF, t.get("silent_failures"))
    return None if v is None else int(v)

#: what marks a frame's note (an event that needed no review, ``FrameResult.notes``) among its reasons,
#: after its flags (:func:`reasons`)
NOTE = "note: "

#: the fewest frames the trial's low-pass takes (:func:`core.tracking.kinematics.butterworth` at the
#: second order :meth:`~core.tracking.results.TrackingResult.filtered_poses` uses: 3 (order + 1) + 1);
#: a shorter trial's bones have no filtered errors (:func:`bone_records`)
FILTER_MIN_FRAMES = 10


def pose_errors(pose: np.ndarray, truth: np.ndarray, center: np.ndarray) -> np.ndarray:
    """``(6,)`` error of ``pose`` vs ``truth``: centroid displacement (mm) and rotation vector (deg)."""
    e = params_from_pose(pose, center=center, base=truth)
    return np.r_[e[:3], np.degrees(e[3:])]


def error_stats(E: np.ndarray) -> dict:
    """RMS and largest translation/rotation errors of ``E`` (frames' (n, 6) errors, per frame or
    filtered); None where it has no frame (no pose in any frame; for the filter, every frame flagged
    or missing: it keeps them NaN)."""
    if not len(E):
        return {"rms_error_mm": None, "rms_error_deg": None, "max_error_mm": None, "max_error_deg": None}
    et, er = np.linalg.norm(E[:, :3], axis=1), np.linalg.norm(E[:, 3:], axis=1)
    return {"rms_error_mm": float(np.sqrt(np.mean(et ** 2))),
            "rms_error_deg": float(np.sqrt(np.mean(er ** 2))), "max_error_mm": float(et.max()),
            "max_error_deg": float(er.max())}


def reasons(fr) -> list[str]:
    """A frame result's reasons as the JSON keeps them: its flags (why it wants review), then its
    notes (events that needed no review), each prefixed :data:`NOTE`."""
    return [*(str(s) for s in fr.flags), *(NOTE + str(s) for s in (getattr(fr, "notes", None) or ()))]


def flag_reasons(res, name: str) -> dict[str, list[str]]:
    """Bone ``name``'s flagged frames in ``res`` (a tracking result), frame (as a JSON key, ascending)
    -> :func:`reasons`; unflagged frames left out."""
    mine = {f: r for (bn, f), r in res.results.items() if bn == name and r.flags}
    return {str(f): reasons(mine[f]) for f in sorted(mine)}


def flag_counts(res, name: str) -> dict:
    """The bone's flagged frames as the run returned them (the failure checks' flags and the
    trajectory post-pass's), and how many of them the post-pass alone flagged."""
    from core.tracking.flags_post import FLAG

    mine = {f: r.flags for (bn, f), r in res.results.items() if bn == name and r.flags}
    post = [f for f, fl in mine.items() if all(s.startswith(FLAG) for s in fl)]
    return {"flagged_frames": sorted(mine), "flagged_off_trajectory_only": sorted(post)}


def _rounded(v: float, digits: int = 3) -> float | None:
    """``v`` to ``digits`` decimals, None where it is NaN (no residual) or infinite."""
    return None if not np.isfinite(v) else round(float(v), digits)


def _stage(timing: dict | None) -> str | None:
    """A frame's final stage outcome from its ``timing`` (:data:`core.tracking.frame_records.STAGE_KEYS`):
    ``"taken"`` (the pose is the stage's), ``"rejected"`` (the move check sent it back to the search's),
    ``"untaken"`` (it ran, its steps failed or left its reach: the search's pose), None (the registration
    kept ran none: no stage, or a retry's search kept)."""
    t = timing or {}
    if t.get("likelihood_rejected"):
        return "rejected"
    if "likelihood_taken" not in t:
        return None
    return "taken" if t["likelihood_taken"] else "untaken"


def frame_signals(res, name: str, frames, truth, center) -> dict:
    """Bone ``name``'s per-frame signals in ``res`` (a tracking result), compact arrays in the order of
    ``frames`` (its frames with a pose, ``frames_with_pose``), flagged or not — what a flag rule can be
    tested on against the good frames: ``score`` (the search's, the final stage leaves it), ``evaluations``
    and ``time_s`` (every registration of the frame), ``retried``; the final stage's outcome
    (``stage``: :func:`_stage`), its move's size from its timing (``stage_move_mm`` / ``_deg``, also
    where rejected), the stages' time and steps over the frame's registrations (``stage_s``,
    ``stage_steps``), and its move as a vector where the pose is the stage's (``stage_move``: the
    stage's pose relative to the search's, :func:`pose_errors`, mm and degrees; None otherwise);
    ``search_error``: the search's pose's error against the truth (``truth(f)``: the bone's true pose
    in frame ``f``) as ``per_frame_error``'s, where the pose is the stage's (None otherwise: the pose
    is the search's, its error ``per_frame_error``'s: kept once, the JSON writes a number a line);
    ``cost_noise`` of the confidence (σ is ``per_frame_sigma``). Rounded as the errors are (5 decimals;
    the score 6, times 4); None where a value is missing or not finite."""
    def num(v, d):
        return None if v is None or not np.isfinite(v) else round(float(v), d)

    keys = ("score", "evaluations", "time_s", "retried", "stage", "stage_move_mm", "stage_move_deg",
            "stage_s", "stage_steps", "stage_move", "search_error", "cost_noise")
    out: dict = {k: [] for k in keys}
    for f in frames:
        r = res.results[(name, f)]
        t, st = r.timing or {}, _stage(r.timing)
        sp = getattr(r, "search_pose", None)
        moved = st == "taken" and sp is not None  # (else the pose is the search's)
        steps = t.get("likelihood_steps")
        out["score"].append(num(r.score, 6))
        out["evaluations"].append(int(r.evaluations))
        out["time_s"].append(num(r.time_s, 4))
        out["retried"].append(bool(r.retried))
        out["stage"].append(st)
        out["stage_move_mm"].append(num(t.get("likelihood_move_mm"), 5))
        out["stage_move_deg"].append(num(t.get("likelihood_move_deg"), 5))
        out["stage_s"].append(num(t.get("likelihood_s"), 4))
        out["stage_steps"].append(None if steps is None else int(steps))
        out["stage_move"].append(pose_errors(r.pose, sp, center).round(5).tolist() if moved else None)
        out["search_error"].append(pose_errors(sp, truth(f), center).round(5).tolist() if moved else None)
        out["cost_noise"].append(num((r.confidence or {}).get("cost_noise"), 6))
    return out


def stored_signals(t: dict) -> dict | None:
    """A bone's stored record ``t`` (a JSON's ``tracking[bone]``) as per-frame arrays, to test a flag
    rule on: ``frames``; ``(n, 6)`` arrays (mm, degrees) ``error``, ``search_error`` (the pose's error
    where the pose is the search's), ``stage_move`` (the pose relative to the search's: zero there; a
    rejected stage's move has its size only, ``stage_move_mm``) and ``sigma`` (NaN where the frame has
    none, ``inf`` on an unbounded axis); ``over_bound`` (the larger of the translation and the rotation
    error over the bone's Cramér–Rao bound; NaN without one), ``flagged`` (bool) and the scalar
    signals of :func:`frame_signals` as float arrays (NaN for None; ``stage`` as stored). None where
    the record has no ``per_frame_signals`` (a run before them)."""
    sig = t.get("per_frame_signals")
    if sig is None:
        return None
    E = np.asarray(t["per_frame_error"], dtype=float).reshape(-1, 6)
    frames = np.asarray(t["frames_with_pose"], dtype=int)

    def vec(rows, fill):
        return np.array([fill[k] if q is None else q for k, q in enumerate(rows)], dtype=float).reshape(-1, 6)

    out = {"frames": frames, "error": E, "search_error": vec(sig["search_error"], E),
           "stage_move": vec(sig["stage_move"], np.zeros_like(E)), "stage": list(sig["stage"]),
           "flagged": np.isin(frames, t.get("flagged_frames") or [])}
    sg = t.get("per_frame_sigma") or [None] * len(E)
    out["sigma"] = np.array([[np.nan] * 6 if q is None else [np.inf if v is None else v for v in q]
                             for q in sg], dtype=float).reshape(-1, 6)
    cb = t.get("cramer_rao")
    out["over_bound"] = (np.maximum(np.linalg.norm(E[:, :3], axis=1) / cb["rms_mm"],
                                    np.linalg.norm(E[:, 3:], axis=1) / cb["rms_deg"])
                         if cb else np.full(len(E), np.nan))
    for k, v in sig.items():
        if k not in out and k not in ("search_error", "stage_move"):
            out[k] = np.array([np.nan if x is None else float(x) for x in v], dtype=float)
    return out


def silent_details(res, name: str, center, errors: dict, bound: dict, silent) -> list:
    """Per silent frame of bone ``name`` (``silent``: frames over 4× the bound left unflagged), what
    the run showed of it: its error (mm, °, and × the bone's bound ``rms_mm`` / ``rms_deg``), score,
    convergence, confidence σ and notes, the final stage's outcome and move (``stage``,
    ``stage_move_mm``: :func:`frame_signals`'); the errors × the bound of the frames within ±2 (a run of
    frames off, or one alone); the flagged frames within the trajectory check's window; and the
    trajectory check's view of it (:mod:`core.tracking.flags_post`, recomputed on the returned poses):
    its residual against the fit through its good neighbours — with the frames only the post-pass
    flagged in the fit (``first``, the pass's first judgement; the bone's median of those is the
    scale) and without any flagged frame (``last``) — in mm and ° and × the scale, beside the limit
    (:data:`~core.tracking.flags_post.LIMIT` × the scale) and the next-to-flagged rule's
    (:data:`~core.tracking.flags_post.NEAR` × the limit). ``errors``: frame -> ``(6,)`` error."""
    from core.tracking.flags_post import FLAG, HALF_WINDOW, LIMIT, NEAR, trajectory_residuals

    mine = {f: r for (bn, f), r in res.results.items() if bn == name}
    fs = sorted(f for f, r in mine.items() if r.pose is not None)
    P = np.array([mine[f].pose for f in fs], dtype=float).reshape(-1, 4, 4)
    own = np.array([any(not s.startswith(FLAG) for s in mine[f].flags) for f in fs], dtype=bool)
    anyf = np.array([bool(mine[f].flags) for f in fs], dtype=bool)
    R = {}
    for k, drop in (("first", own), ("last", anyf)):
        Q = P.copy()
        Q[drop] = np.nan
        R[k] = trajectory_residuals(fs, Q, center) if len(fs) else np.zeros((0, 2))
    fin = np.isfinite(R["first"]).all(axis=1)
    med = np.median(R["first"][fin], axis=0) if fin.any() else np.full(2, np.nan)

    def over(f):
        e = errors.get(f)
        return None if e is None else round(float(max(np.linalg.norm(e[:3]) / bound["rms_mm"],
                                                      np.linalg.norm(e[3:]) / bound["rms_deg"])), 2)

    out = []
    for f in silent:
        r, e, i = mine[f], np.asarray(errors[f], dtype=float), fs.index(f)
        t = getattr(r, "timing", None) or {}
        et, er = float(np.linalg.norm(e[:3])), float(np.linalg.norm(e[3:]))
        traj = {k: {"mm": _rounded(R[k][i, 0], 4), "deg": _rounded(R[k][i, 1], 4),
                    "x_median": [_rounded(R[k][i, u] / med[u], 2) for u in (0, 1)]} for k in R}
        out.append({"frame": int(f), "error_mm": round(et, 4), "error_deg": round(er, 4),
                    "over_bound": [round(et / bound["rms_mm"], 2), round(er / bound["rms_deg"], 2)],
                    "error": np.round(e, 4).tolist(), "score": _rounded(r.score, 6),
                    "converged": bool(r.converged), "retried": bool(r.retried), "notes": list(r.notes),
                    "stage": _stage(t), "stage_move_mm": _rounded(t.get("likelihood_move_mm", np.nan), 5),
                    "sigma": (r.confidence or {}).get("sigma"),
                    "neighbours_over_bound": {str(g): over(g) for g in range(f - 2, f + 3)
                                              if g in mine and g != f},
                    "flagged_within_window": [g for g in sorted(mine)
                                              if mine[g].flags and 0 < abs(g - f) <= HALF_WINDOW],
                    "trajectory": {**traj, "median_mm": _rounded(med[0], 4),
                                   "median_deg": _rounded(med[1], 4), "limit_x_median": LIMIT,
                                   "near_x_median": round(NEAR * LIMIT, 3)}})
    return out


def over_bound(res, name: str, E: np.ndarray, frames: list, bound: dict, k: float = 4.0) -> dict:
    """The issue's failure count: frames whose translation or rotation error is over ``k`` times the
    bone's Cramér–Rao bound (RMS of its per-frame bounds), flagged or not (*silent*), and the flagged
    frames within it (``false_flags``, ``false_flag_frames``)."""
    over = (np.linalg.norm(E[:, :3], axis=1) > k * bound["rms_mm"]) | (np.linalg.norm(E[:, 3:], axis=1)
                                                                        > k * bound["rms_deg"])
    bad = [f for f, o in zip(frames, over, strict=True) if o]
    silent = [f for f in bad if not res.results[(name, f)].flags]
    good_flagged = [f for f, o in zip(frames, over, strict=True) if not o and res.results[(name, f)].flags]
    return {"k": k, "frames": bad, "silent": len(silent), "silent_frames": silent,
            "false_flags": len(good_flagged), "false_flag_frames": good_flagged}


@dataclass
class BoneRecords:
    """:func:`bone_records`' result: ``tracking`` (bone -> its JSON record), and per bone its
    per-frame errors ``errors`` (``(n, 6)``, mm and degrees, one row per frame with a pose),
    ``frames`` (those frames) and ``filtered`` (``(frames, (m, 6) errors)`` of the low-passed
    trajectory)."""

    tracking: dict = field(default_factory=dict)
    errors: dict = field(default_factory=dict)
    frames: dict = field(default_factory=dict)
    filtered: dict = field(default_factory=dict)


def bone_records(ts, res, frame_rate_hz: float) -> BoneRecords:
    """Per bone of ``ts`` (a :class:`~core.studies.tracking.acceptance.TrackingScene`) tracked in
    ``res``: the errors of the tracked and the low-passed poses (cut-off by Winter's residual analysis
    at ``frame_rate_hz``; none in a trial under :data:`FILTER_MIN_FRAMES` frames) against the truth,
    converged fraction and the frames not converged (``unconverged_frames``), flagged frames
    (:func:`flag_counts`) and each one's reasons (``flag_reasons``,
    :func:`flag_reasons`), the unflagged frames over 0.5 mm or 0.5° (:data:`SILENT_OVER_HALF`), the 2σ
    coverage, the per-frame σ and the per-frame signals (``per_frame_signals``, :func:`frame_signals`)."""
    out, n_frames = BoneRecords(), ts.scene.n_frames
    for b, (n, m) in enumerate(zip(ts.names, ts.models, strict=True)):
        if n_frames >= FILTER_MIN_FRAMES and any(r.pose is not None and not r.flags
                                                 for (bn, _), r in res.results.items() if bn == n):
            F, cutoff = res.filtered_poses(n, frame_rate_hz, center=m.centroid)
        else:  # too few frames, or every frame flagged or missing: nothing for the low-pass
            F, cutoff = np.full((n_frames, 4, 4), np.nan), None
        ff = [f for f in range(n_frames) if np.all(np.isfinite(F[f]))]
        Ef = np.array([pose_errors(F[f], ts.truth(f)[b], m.centroid) for f in ff]).reshape(-1, 6)
        out.filtered[n] = (ff, Ef)
        rows, inside, silent, conv, sig, fwp = [], [], 0, 0, [], []
        for f in range(n_frames):
            fr = res.results[(n, f)]
            conv += fr.converged
            if fr.pose is None:
                continue
            e = pose_errors(fr.pose, ts.truth(f)[b], m.centroid)
            rows.append(e)
            fwp.append(f)
            sig.append(fr.confidence["sigma"] if fr.confidence else None)
            bad = np.linalg.norm(e[:3]) > 0.5 or np.linalg.norm(e[3:]) > 0.5
            silent += bool(bad and not fr.flags)
            if fr.confidence and all(s is not None for s in fr.confidence["sigma"]):
                inside.append(np.abs(e) <= 2 * np.array(fr.confidence["sigma"]))
        E = np.array(rows).reshape(-1, 6)  # no row: the bone has no pose in any frame
        out.errors[n], out.frames[n] = E, fwp
        motion = [np.linalg.norm(pose_errors(ts.truth(f + 1)[b], ts.truth(f)[b], m.centroid)[:3])
                  for f in range(n_frames - 1)]
        out.tracking[n] = {
            **error_stats(E), "filtered": {"cutoff_hz": cutoff, **error_stats(Ef), "frames": len(Ef)},
            "mean_error": {"mm": E[:, :3].mean(0).round(4).tolist(),
                           "deg": E[:, 3:].mean(0).round(4).tolist()} if len(E) else None,
            "converged_fraction": conv / n_frames,
            # the frames that did not converge (a registration the frame step flagged, or no pose), whose
            # reasons are in flag_reasons: what "converged 98 %" counts
            "unconverged_frames": [f for f in range(n_frames) if not res.results[(n, f)].converged],
            **flag_counts(res, n),
            "flag_reasons": flag_reasons(res, n),
            SILENT_OVER_HALF: silent,  # silent_failures before; not the goal's silent_over_4x
            "within_2_sigma_fraction": float(np.mean(inside)) if inside else None,
            "motion_per_frame_mm": {"median": float(np.median(motion)), "max": float(np.max(motion))},
            "per_frame_sigma": [None if q is None else [None if v is None else round(v, 5) for v in q]
                                for q in sig],
            # (frames_with_pose's order: every frame's score, work, the final stage's outcome and move,
            # the searched pose's error; frame_signals)
            "per_frame_signals": frame_signals(res, n, fwp, lambda f, b=b: ts.truth(f)[b], m.centroid),
        }
    return out


def add_bound(rec: BoneRecords, ts, res, bound: dict) -> None:
    """Add to ``rec``'s records (:func:`bone_records`) of each bone with a Cramér–Rao bound in
    ``bound`` (:func:`~core.studies.tracking.acceptance.cramer_rao`): the bound, the RMS errors
    over it (None where the bone has no (filtered) frame), the errors' spread, the frames over 4×
    it (:func:`over_bound`) with what the run showed of each silent one
    (:func:`silent_details`), and where the bound has the tissue-unknown one (``tissue_unknown``,
    :func:`core.studies.tracking.tissue_bound_acceptance.acceptance_bound`) the RMS errors over that beside
    (``rms_over_tissue_unknown_bound``; the goal is judged on ``rms_over_bound``); and to every bone's its
    per-frame errors and their frames (``per_frame_error``, ``frames_with_pose``)."""
    for n, E in rec.errors.items():
        t, fwp = rec.tracking[n], rec.frames[n]
        if n in bound:
            cb = t["cramer_rao"] = bound[n]
            t["rms_over_bound"] = {k: None if v is None else v / cb[f"rms_{u}"] for k, v, u in (
                ("mm", t["rms_error_mm"], "mm"), ("deg", t["rms_error_deg"], "deg"),
                ("filtered_deg", t["filtered"]["rms_error_deg"], "deg"))}
            if (tu := cb.get("tissue_unknown")) is not None:
                t["rms_over_tissue_unknown_bound"] = {
                    u: None if t[f"rms_error_{u}"] is None else t[f"rms_error_{u}"] / tu[f"rms_{u}"]
                    for u in ("mm", "deg")}
            t["std_error"] = {"mm": E[:, :3].std(0).round(4).tolist(),
                              "deg": E[:, 3:].std(0).round(4).tolist()} if len(E) else None
            ob = t["over_4x_bound"] = over_bound(res, n, E, fwp, cb)
            center = ts.models[ts.names.index(n)].centroid
            ob["silent_details"] = silent_details(res, n, center, dict(zip(fwp, E, strict=True)), cb,
                                                  ob["silent_frames"])  # what the run showed
        t["per_frame_error"] = E.round(5).tolist()
        t["frames_with_pose"] = fwp  # per_frame_error's, per_frame_sigma's
