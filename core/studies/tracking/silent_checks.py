"""Candidate review checks for the frames over 4× the Cramér–Rao bound that the tracker's flags leave
silent (``python -m core.studies.tracking.silent_checks DUMP.npz ...``).

Reads the dumps of :mod:`core.studies.tracking.silent_failures` (``--dump``, one per scene seed and
mode) and judges every candidate check on the same bone-frames: which of the frames over
:data:`~core.studies.tracking.silent_failures.OVER` × the bone's bound left unflagged by the tracker
(its per-frame checks and the trajectory post-pass, :mod:`core.tracking.flags_post`) the candidate
flags (*caught*), and how many good frames (within 4×) it flags that the tracker did not (*new
false flags*), over all the dumps given. A candidate reads only what a user's run has — poses,
scores, confidence σ, the tracker's flags — except ``bound_*``, which read each frame's own bound at
the true pose (the dump's ``frame_bound``; a user would compute it at the tracked pose): what a
per-frame bound could add if it were built. ``modes`` needs both a joint and a sequential dump of
the seed (a user running both). ``--keep-per-frame`` keeps the dumps' state in the JSON
(``per_frame``), which :func:`load` reads back as ``FILE.json#RUN``.

Measured (seeds 0-2, joint and sequential, tracked on one NVIDIA H100 at ea76c8b, judged on this
2-core CPU; ``resources/benchmarks/tracking_silent_checks_h100.json``, the per-frame state in
``tracking_silent_checks_per_frame_h100.json``): 20 silent tibia frames against 1672 unflagged good
bone-frames; no candidate separates them (AUC 0.44-0.87; at 1 % of the good frames flagged none
catches more than 3, at 5 % 9); what the tracker's check now adds is in
:mod:`core.tracking.flags_post` (*next to a flagged frame*: 3 caught, 11 more good frames flagged).
"""

from __future__ import annotations

import argparse
import json
import math
import re

import numpy as np

__all__ = ["CANDIDATES", "auc", "block_residuals", "evaluate", "load", "main", "per_frame",
           "trajectory_counts"]


def load(path: str) -> dict:
    """Per bone of a dump (``.npz``, or ``FILE.json#RUN``: a run's :func:`per_frame` kept in a
    benchmark JSON's ``per_frame``): ``frames``, ``pose``, ``err``, ``sigma``, ``score``, ``flags``
    (the tracker's, post-pass included), ``own`` (without the post-pass's), ``center``, ``bound``
    (the bone's RMS bound), ``frame_sigma`` (``(n, 6)`` each frame's own bound's σ, NaN where not
    computed, or None), ``over`` and ``good``."""
    from core.studies.tracking.silent_failures import OVER, _center
    from core.tracking.flags_post import FLAG

    if "#" in path:
        file, run = path.rsplit("#", 1)
        with open(file) as fh:
            src = json.load(fh)["per_frame"][run]
        names = list(src)
        get = {n: {k: (v if k in ("flags", "bound") or v is None else np.array(v, dtype=float))
                   for k, v in d.items()} for n, d in src.items()}
        for g in get.values():
            top = g["pose"].reshape(-1, 3, 4)
            g["pose"] = np.concatenate([top, np.tile([[[0.0, 0.0, 0.0, 1.0]]], (len(top), 1, 1))], axis=1)
    else:
        z = np.load(path)
        names = sorted({k.split(".")[0] for k in z.files}, key=lambda n: z.files.index(f"{n}.pose"))
        get = {}
        for n in names:
            fb = z[f"{n}.frame_bound"] if f"{n}.frame_bound" in z.files else None
            fs = None if fb is None else np.sqrt(np.abs(np.diagonal(fb, axis1=1, axis2=2)))
            get[n] = {"err": z[f"{n}.err"], "bound": json.loads(str(z[f"{n}.bound"])),
                      "flags": json.loads(str(z[f"{n}.flags"])), "pose": z[f"{n}.pose"],
                      "sigma": z[f"{n}.sigma"], "score": z[f"{n}.score"], "center": _center(z, n),
                      "frame_sigma": fs}
    out = {}
    for n in names:
        g = get[n]
        E, b, fl = np.asarray(g["err"], float), g["bound"], g["flags"]
        ok = np.all(np.isfinite(E), axis=1)
        q = np.maximum(np.linalg.norm(E[:, :3], axis=1) / b["rms_mm"],
                       np.linalg.norm(E[:, 3:], axis=1) / b["rms_deg"])
        out[n] = {"frames": np.arange(len(E)), "pose": np.asarray(g["pose"], float), "err": E,
                  "sigma": np.asarray(g["sigma"], float), "score": np.asarray(g["score"], float),
                  "flags": np.array([bool(f) for f in fl]),
                  "own": np.array([any(not s.startswith(FLAG) for s in f) for f in fl]),
                  "center": np.asarray(g["center"], float).reshape(3), "bound": b,
                  "frame_sigma": g.get("frame_sigma"), "ratio": q, "over": ok & (q > OVER),
                  "good": ok & ~(q > OVER)}
    return out


def per_frame(path: str) -> dict:
    """A ``.npz`` dump's per-bone state as JSON lists (:func:`load` reads it back from a benchmark
    JSON): the poses' top 3 rows, errors, σ, scores, flags, the rotation centre, the bone's bound and
    each frame's own bound's σ (None where not computed)."""
    def rows(a, d):
        return [[None if not np.isfinite(v) else round(float(v), d) for v in np.ravel(r)] for r in a]

    z = np.load(path)
    out = {}
    for n, b in load(path).items():
        out[n] = {"pose": rows(b["pose"][:, :3, :], 7), "err": rows(b["err"], 5),
                  "sigma": rows(b["sigma"], 5), "score": [round(float(v), 6) for v in b["score"]],
                  "flags": json.loads(str(z[f"{n}.flags"])),
                  "center": np.round(b["center"], 5).tolist(), "bound": b["bound"],
                  "frame_sigma": None if b["frame_sigma"] is None else rows(b["frame_sigma"], 6)}
    return out


def _deltas(P0: np.ndarray, P: np.ndarray, c: np.ndarray) -> np.ndarray:
    from core.tracking.flags_post import _deltas

    return _deltas(np.repeat(P0[None], len(P), axis=0), P, c)


def block_residuals(poses: np.ndarray, use: np.ndarray, center, *, gap: int = 0, half_window: int = 4,
                    degree: int = 2, reach: int = 3) -> np.ndarray:
    """``(n, 6)`` residual of each frame's pose (mm, degrees; frames consecutive) from a polynomial of
    ``degree`` through the poses of its ``half_window`` nearest frames in ``use`` on each side beyond
    its ``gap`` nearest (left out: a short run of frames off together does not pull its own fit),
    within ``reach × half_window + gap`` frames, divided by ``sqrt(1 + leverage)``; NaN where fewer
    than ``degree + 2`` neighbours."""
    n = len(poses)
    c = np.asarray(center, float)
    out = np.full((n, 6), np.nan)
    far = reach * half_window + gap
    good = np.flatnonzero(use)
    for i in np.flatnonzero(use):
        left = good[(good < i - gap) & (good >= i - far)][-half_window:]
        right = good[(good > i + gap) & (good <= i + far)][:half_window]
        j = np.r_[left, right].astype(int)
        if len(j) < degree + 2:
            continue
        x = (j - i).astype(float)
        A = np.vander(x, degree + 1)
        AtA = A.T @ A
        if abs(np.linalg.det(AtA)) < 1e-9:
            continue
        row = np.linalg.solve(AtA, A.T)[-1]
        k = math.sqrt(1.0 + float(np.linalg.inv(AtA)[-1, -1]))  # an extrapolation's grows
        r = -(row @ _deltas(poses[i], poses[j], c))  # the frame's pose about the fit's value there
        out[i] = np.r_[r[:3], np.degrees(r[3:])] / k
    return out


def _norm_scale(R: np.ndarray, use: np.ndarray) -> np.ndarray:
    """``(n,)`` max over translation and rotation of the residual's norm over the bone's median norm."""
    t, r = np.linalg.norm(R[:, :3], axis=1), np.linalg.norm(R[:, 3:], axis=1)
    have = use & np.isfinite(t)
    if have.sum() < 8:
        return np.zeros(len(R))
    return np.nan_to_num(np.maximum(t / np.median(t[have]), r / np.median(r[have])))


def _axis_scale(R: np.ndarray, use: np.ndarray) -> np.ndarray:
    """``(n,)`` max over the 6 components of ``|r| / (1.4826 MAD)`` (each axis at its own scale)."""
    have = use & np.all(np.isfinite(R), axis=1)
    if have.sum() < 8:
        return np.zeros(len(R))
    med = np.median(R[have], axis=0)
    s = 1.4826 * np.median(np.abs(R[have] - med), axis=0)
    return np.nan_to_num(np.abs(R - med) / np.maximum(s, 1e-12)).max(axis=1)


def _mahal(R: np.ndarray, use: np.ndarray) -> np.ndarray:
    """``(n,)`` Mahalanobis length of the residual under the bone's robust (MAD-scaled, inliers')
    covariance; chi with 6 degrees of freedom for Gaussian residuals."""
    have = use & np.all(np.isfinite(R), axis=1)
    if have.sum() < 12:
        return np.zeros(len(R))
    X = R[have]
    med = np.median(X, axis=0)
    s = 1.4826 * np.median(np.abs(X - med), axis=0)
    inl = np.all(np.abs(X - med) <= 3 * s, axis=1)
    C = np.cov(X[inl].T) + np.diag((1e-6 * s) ** 2)
    D = np.nan_to_num(R - med)
    return np.sqrt(np.einsum("ni,ij,nj->n", D, np.linalg.inv(C), D))


def _frame_sigma(b: dict):
    """``(n, 6)`` each frame's own bound's σ, interpolated over the frames without one (the bound is
    smooth in the frame); None without."""
    sb = b["frame_sigma"]
    if sb is None:
        return None
    have = np.all(np.isfinite(sb), axis=1)
    f = b["frames"]
    return np.stack([np.interp(f, f[have], sb[have, k]) for k in range(6)], axis=1)


def _sigma_bound(b: dict) -> np.ndarray:
    """Worst axis of the frame's confidence σ over its own bound's σ, against the bone's median."""
    sb = _frame_sigma(b)
    if sb is None:
        return np.zeros(len(b["pose"]))
    r = b["sigma"] / sb
    return np.nan_to_num(r / np.nanmedian(r, axis=0)).max(axis=1)


def _bound_size(b: dict) -> np.ndarray:
    """The frame's own bound (RMS mm and deg) over the bone's, the larger: frames the image
    determines worse than the bone's usual frame."""
    sb = _frame_sigma(b)
    if sb is None:
        return np.zeros(len(b["pose"]))
    return np.maximum(np.sqrt((sb[:, :3] ** 2).sum(1)) / b["bound"]["rms_mm"],
                      np.sqrt((sb[:, 3:] ** 2).sum(1)) / b["bound"]["rms_deg"])


def _scores(b: dict, other: dict | None) -> dict:
    """Candidate name -> ``(n,)`` score of each frame (larger: more suspect); the threshold sweep is
    :func:`evaluate`'s."""
    use = ~b["flags"] & np.all(np.isfinite(b["pose"].reshape(len(b["pose"]), -1)), axis=1)
    P, c = b["pose"], b["center"]
    out = {}
    R = {(g, h, d): block_residuals(P, use, c, gap=g, half_window=h, degree=d)
         for g, h, d in ((0, 4, 2), (1, 4, 2), (2, 4, 2), (0, 8, 3), (2, 8, 3), (3, 8, 3))}
    out["traj_norm_g0"] = _norm_scale(R[(0, 4, 2)], use)
    out["traj_norm_g1"] = _norm_scale(R[(1, 4, 2)], use)
    out["traj_norm_g2"] = _norm_scale(R[(2, 4, 2)], use)
    out["traj_norm_g012"] = np.maximum.reduce([out["traj_norm_g0"], out["traj_norm_g1"], out["traj_norm_g2"]])
    out["traj_wide8_g0"] = _norm_scale(R[(0, 8, 3)], use)
    out["traj_wide8_g2"] = _norm_scale(R[(2, 8, 3)], use)
    out["traj_wide8_g3"] = _norm_scale(R[(3, 8, 3)], use)
    out["traj_axis_g0"] = _axis_scale(R[(0, 4, 2)], use)
    near = ((0, 4, 2), (1, 4, 2), (2, 4, 2))
    out["traj_axis_g012"] = np.maximum.reduce([_axis_scale(R[k], use) for k in near])
    out["traj_mahal_g0"] = _mahal(R[(0, 4, 2)], use)
    out["traj_mahal_g012"] = np.maximum.reduce([_mahal(R[k], use) for k in near])
    s = b["sigma"]
    out["sigma_median"] = np.nan_to_num(s / np.nanmedian(s[use], axis=0)).max(axis=1)
    out["score_drop"] = np.nan_to_num(np.nanmedian(b["score"][use]) / b["score"])
    out["bound_sigma"] = _sigma_bound(b)
    out["bound_size"] = _bound_size(b)
    if other is not None:
        D = np.array([np.r_[d[:3], np.degrees(d[3:])] for d in
                      (_deltas(P[i], other["pose"][i:i + 1], c)[0] for i in range(len(P)))])
        out["modes"] = _axis_scale(D, use & ~other["flags"])
    return out


CANDIDATES = ("traj_norm_g0", "traj_norm_g1", "traj_norm_g2", "traj_norm_g012", "traj_wide8_g0",
              "traj_wide8_g2", "traj_wide8_g3", "traj_axis_g0", "traj_axis_g012", "traj_mahal_g0",
              "traj_mahal_g012", "sigma_median", "score_drop", "bound_sigma", "bound_size", "modes")


def auc(pos: np.ndarray, neg: np.ndarray) -> float:
    """Rank AUC: the chance that a positive scores above a negative (ties half)."""
    if not len(pos) or not len(neg):
        return math.nan
    hits = (pos[:, None] > neg[None]).sum() + 0.5 * (pos[:, None] == neg[None]).sum()
    return float(hits / (len(pos) * len(neg)))


def _other_mode(path: str) -> str:
    return re.sub(r"joint|sequential", "X", path.rsplit("/", 1)[-1])


def trajectory_counts(paths, **post) -> dict:
    """Per dump and bone, the frames over 4× left silent and the good frames flagged by the tracker's
    per-frame checks with :func:`core.tracking.flags_post.apply_trajectory_flags` (``post``: its
    keywords, e.g. ``limit``, ``near``) run afresh on the dump's poses, and the totals."""
    from core.tracking.flags_post import apply_trajectory_flags
    from core.tracking.results import FrameResult, TrackingResult

    out, tot = {}, {"over": 0, "silent": 0, "good": 0, "good_flagged": 0}
    for p in paths:
        bones = load(p)
        res = {}
        for n, b in bones.items():
            for f in b["frames"]:
                own = ("own",) if b["own"][f] else ()
                pose = b["pose"][f] if np.all(np.isfinite(b["pose"][f])) else None
                res[(n, int(f))] = FrameResult(n, int(f), pose, float(b["score"][f]), 0, 0.0, not own, own)
        frames = tuple(int(f) for f in next(iter(bones.values()))["frames"])
        got, _ = apply_trajectory_flags(TrackingResult(tuple(bones), frames, res, "complete", 0.0),
                                        {n: b["center"] for n, b in bones.items()}, **post)
        out[p] = {}
        for n, b in bones.items():
            fl = np.array([bool(got.results[(n, int(f))].flags) for f in b["frames"]])
            silent, good = np.flatnonzero(b["over"] & ~fl), np.flatnonzero(b["good"] & fl)
            out[p][n] = {"over": np.flatnonzero(b["over"]).tolist(), "silent": silent.tolist(),
                         "good_flagged": good.tolist(), "good": int(b["good"].sum())}
            tot["over"] += int(b["over"].sum())
            tot["silent"] += len(silent)
            tot["good"] += int(b["good"].sum())
            tot["good_flagged"] += len(good)
    return {"runs": out, "total": tot}


def evaluate(paths, *, fractions=(0.01, 0.02, 0.03, 0.05, 0.10)) -> dict:
    """Per candidate over all ``paths`` (the dumps): the silent frames (over 4×, no flag), the AUC of
    the score on silent against unflagged good frames, and at thresholds that flag the given
    fractions of the unflagged good frames (one threshold for all bones and runs) the silent frames
    caught; also each run's silent frames with their scores."""
    runs = {}
    for p in paths:
        runs[p] = load(p)
    by_seed = {}
    for p in paths:
        by_seed.setdefault(_other_mode(p), []).append(p)
    rows = []  # (run, bone, frame, silent?, good-unflagged?, scores)
    for p, bones in runs.items():
        pair = [q for q in by_seed[_other_mode(p)] if q != p]
        for n, b in bones.items():
            other = runs[pair[0]][n] if pair else None
            sc = _scores(b, other)
            silent = b["over"] & ~b["flags"]
            neg = b["good"] & ~b["flags"]
            for f in np.flatnonzero(silent | neg):
                rows.append((p, n, int(f), bool(silent[f]), float(b["ratio"][f]),
                             {k: float(v[f]) for k, v in sc.items()}))
    out = {"silent": [(p.rsplit("/", 1)[-1], n, f, round(q, 2)) for p, n, f, s, q, _ in rows if s],
           "good_unflagged": sum(1 for r in rows if not r[3]), "candidates": {}}
    for k in CANDIDATES:
        have = [r for r in rows if k in r[5]]
        if not have:
            continue
        pos = np.array([r[5][k] for r in have if r[3]])
        neg = np.array([r[5][k] for r in have if not r[3]])
        c = {"auc": round(auc(pos, neg), 3), "at": {}}
        for fr in fractions:
            thr = float(np.quantile(neg, 1.0 - fr))
            c["at"][f"{fr:g}"] = {"threshold": round(thr, 3), "caught": int((pos > thr).sum()),
                                  "of": len(pos), "good_flagged": int((neg > thr).sum())}
        c["silent_scores"] = [round(r[5][k], 2) for r in have if r[3]]
        out["candidates"][k] = c
    return out


def main(argv=None) -> int:
    from core.io.atomic import print_json

    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.silent_checks",
                                description=__doc__.split("\n")[0])
    p.add_argument("dumps", nargs="+", help="silent_failures --dump files (.npz), or FILE.json#RUN")
    p.add_argument("--near", default="off,0.5,0.6,0.7,0.8",
                   help="the trajectory check's near values to count (off: None), comma-separated")
    p.add_argument("--keep-per-frame", action="store_true", help="write the .npz dumps' state as per_frame")
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    nears = [None if v == "off" else float(v) for v in a.near.split(",") if v]
    out = {"study": "core.studies.tracking.silent_checks", "dumps": a.dumps, **evaluate(a.dumps),
           "trajectory_check": {str(v): trajectory_counts(a.dumps, near=v) for v in nears}}
    if a.keep_per_frame:
        out["per_frame"] = {re.sub(r"^[^_]*_|_newton$", "", d.rsplit("/", 1)[-1][:-4]): per_frame(d)
                            for d in a.dumps if d.endswith(".npz")}  # d_0_joint_newton.npz: 0_joint
    print_json(out, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
