"""Issue 20's goals on the acceptance trial (:mod:`core.studies.tracking.acceptance`): per bone the
goals met or not (:func:`goals`), the flagged frames as the run returned them (:func:`flag_counts`),
joint against sequential tracking (:func:`compare_modes`) and the smallest joint space against the
truth's (:func:`joint_space`)."""

from __future__ import annotations

import numpy as np

__all__ = ["GOALS", "PAIRS", "compare_modes", "flag_counts", "goals", "joint_space"]


#: Bone pairs that touch in the trial (talocrural, subtalar): :func:`joint_space`.
PAIRS = (("tibia", "talus"), ("talus", "calcaneus"))


def joint_space(ts, res) -> dict:
    """Per touching pair (:data:`PAIRS`) of ``ts`` (a ``TrackingScene``) tracked in ``res``, the
    smallest joint space over the trial (signed surface distance,
    :func:`core.tracking.contact.surface_gap`; negative: the bones interpenetrate) at the tracked
    poses and at the true ones, with its frame, and the tracked-minus-true gap per frame (RMS and
    largest magnitude, frames where both bones have a pose; None where no frame has both)."""
    from core.tracking.contact import ContactModel, surface_gap

    cm = {n: ContactModel.from_bone(m) for n, m in zip(ts.names, ts.models, strict=True)}
    out = {}
    for a, b in PAIRS:
        if a not in cm or b not in cm:
            continue
        ia, ib = ts.names.index(a), ts.names.index(b)
        got, true = [], []
        for f in range(ts.scene.n_frames):
            T = ts.truth(f)
            true.append(surface_gap(cm[a], T[ia], cm[b], T[ib]))
            ra, rb = res.results.get((a, f)), res.results.get((b, f))
            ok = ra is not None and rb is not None and ra.pose is not None and rb.pose is not None
            got.append(surface_gap(cm[a], ra.pose, cm[b], rb.pose) if ok else np.nan)
        got, true = np.array(got), np.array(true)
        d = (got - true)[np.isfinite(got)]
        kt = int(np.argmin(true))
        k = int(np.nanargmin(got)) if d.size else None  # None: no frame with both bones' poses
        out[f"{a}-{b}"] = {"min_mm": None if k is None else float(got[k]), "min_frame": k,
                           "truth_min_mm": float(true[kt]), "truth_min_frame": kt,
                           "rms_diff_mm": float(np.sqrt(np.mean(d**2))) if d.size else None,
                           "max_abs_diff_mm": float(np.abs(d).max()) if d.size else None}
    return out


def flag_counts(res, name: str) -> dict:
    """The bone's flagged frames as the run returned them (the failure checks' flags and the
    trajectory post-pass's), and how many of them the post-pass alone flagged."""
    from core.tracking.flags_post import FLAG

    mine = {f: r.flags for (bn, f), r in res.results.items() if bn == name and r.flags}
    post = [f for f, fl in mine.items() if all(s.startswith(FLAG) for s in fl)]
    return {"flagged_frames": sorted(mine), "flagged_off_trajectory_only": sorted(post)}


#: Issue 20's per-frame goals on the acceptance trial (:func:`goals`).
GOALS = {"max_rms_over_bound": 1.25, "min_converged_fraction": 0.99, "max_silent_over_4x": 0,
         "min_within_2_sigma": 0.90}


def goals(per_bone: dict) -> dict:
    """Per bone, each of :data:`GOALS` — the measured value and whether it is met."""
    out = {}
    for n, t in per_bone.items():
        g = {"converged_fraction": [t["converged_fraction"],
                                    t["converged_fraction"] >= GOALS["min_converged_fraction"]]}
        if "rms_over_bound" in t:
            for k in ("mm", "deg"):
                r = t["rms_over_bound"][k]
                g[f"rms_over_bound_{k}"] = [r, r is not None and r <= GOALS["max_rms_over_bound"]]
            s = t["over_4x_bound"]["silent"]
            g["silent_over_4x"] = [s, s <= GOALS["max_silent_over_4x"]]
        w = t["within_2_sigma_fraction"]
        g["within_2_sigma"] = [w, w is not None and w >= GOALS["min_within_2_sigma"]]
        out[n] = g
    return out


def compare_modes(runs: dict) -> dict:
    """Per bone, joint against sequential RMS error (mm, °) and their ratio (joint / sequential:
    at most 1 where joint is at least as good)."""
    if not {"joint", "sequential"} <= set(runs):
        return {}
    out = {}
    for n, j in runs["joint"]["tracking"].items():
        s = runs["sequential"]["tracking"].get(n)
        if s is None:
            continue
        out[n] = {k: {"joint": j[f"rms_error_{k}"], "sequential": s[f"rms_error_{k}"],
                      "ratio": None if None in (j[f"rms_error_{k}"], s[f"rms_error_{k}"])  # no pose
                      else j[f"rms_error_{k}"] / s[f"rms_error_{k}"]} for k in ("mm", "deg")}
    return out
