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
the seed (a user running both).
"""

from __future__ import annotations

import argparse
import json
import math

import numpy as np

__all__ = ["CANDIDATES", "auc", "block_residuals", "evaluate", "load", "main"]


def load(path: str) -> dict:
    """Per bone of a dump: ``frames``, ``pose``, ``err``, ``sigma``, ``score``, ``flags`` (the tracker's,
    post-pass included), ``own`` (without the post-pass's), ``center``, ``bound`` (the bone's RMS
    bound), ``frame_bound`` (``(n, 6, 6)`` or None), ``over`` and ``good``."""
    from core.studies.tracking.silent_failures import OVER, _center
    from core.tracking.flags_post import FLAG

    z = np.load(path)
    names = sorted({k.split(".")[0] for k in z.files}, key=lambda n: z.files.index(f"{n}.pose"))
    out = {}
    for n in names:
        E = np.asarray(z[f"{n}.err"], float)
        b = json.loads(str(z[f"{n}.bound"]))
        fl = json.loads(str(z[f"{n}.flags"]))
        ok = np.all(np.isfinite(E), axis=1)
        q = np.maximum(np.linalg.norm(E[:, :3], axis=1) / b["rms_mm"],
                       np.linalg.norm(E[:, 3:], axis=1) / b["rms_deg"])
        fb = z[f"{n}.frame_bound"] if f"{n}.frame_bound" in z.files else None
        out[n] = {"frames": np.arange(len(E)), "pose": np.asarray(z[f"{n}.pose"], float), "err": E,
                  "sigma": np.asarray(z[f"{n}.sigma"], float), "score": np.asarray(z[f"{n}.score"], float),
                  "flags": np.array([bool(f) for f in fl]),
                  "own": np.array([any(not s.startswith(FLAG) for s in f) for f in fl]),
                  "center": _center(z, n), "bound": b, "frame_bound": fb, "ratio": q,
                  "over": ok & (q > OVER), "good": ok & ~(q > OVER)}
    return out


def _deltas(P0: np.ndarray, P: np.ndarray, c: np.ndarray) -> np.ndarray:
    from core.tracking.flags_post import _deltas

    return _deltas(np.repeat(P0[None], len(P), axis=0), P, c)


def block_residuals(poses: np.ndarray, use: np.ndarray, center, *, gap: int = 0, half_window: int = 4,
                    degree: int = 2) -> np.ndarray:
    """``(n, 6)`` residual of each frame's pose (mm, degrees; frames consecutive) against a polynomial
    of ``degree`` through the poses in ``use`` at offsets ``gap < |d| <= gap + half_window`` (its
    ``2 gap`` nearest neighbours left out: a short run of frames off together does not pull its own
    fit), divided by ``sqrt(1 + leverage)``; NaN where fewer than ``degree + 2`` neighbours."""
    n = len(poses)
    c = np.asarray(center, float)
    out = np.full((n, 6), np.nan)
    offs = np.array([d for d in range(-gap - half_window, gap + half_window + 1) if abs(d) > gap])
    for i in range(n):
        j = i + offs
        m = (j >= 0) & (j < n)
        m[m] &= use[j[m]]
        if m.sum() < degree + 2 or not use[i]:
            continue
        x = offs[m].astype(float)
        # with neighbours on one side only, an extrapolation: the leverage grows
        A = np.vander(x, degree + 1)
        AtA = A.T @ A
        if abs(np.linalg.det(AtA)) < 1e-9:
            continue
        row = np.linalg.solve(AtA, A.T)[-1]
        k = math.sqrt(1.0 + float(np.linalg.inv(AtA)[-1, -1]))
        Y = _deltas(poses[i], poses[j[m]], c)
        r = -(row @ Y)  # the frame's pose about the fit's value there
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


def _sigma_bound(b: dict) -> np.ndarray:
    """Worst axis of the frame's confidence σ over its own bound's σ (frames without a bound:
    interpolated over the frames that have one, the bound being smooth in the frame)."""
    fb = b["frame_bound"]
    if fb is None:
        return np.zeros(len(b["pose"]))
    sb = np.sqrt(np.abs(np.diagonal(fb, axis1=1, axis2=2)))
    have = np.all(np.isfinite(sb), axis=1)
    f = b["frames"]
    sb = np.stack([np.interp(f, f[have], sb[have, k]) for k in range(6)], axis=1)
    r = b["sigma"] / sb
    med = np.nanmedian(r, axis=0)
    return np.nan_to_num(r / med).max(axis=1)


def _bound_size(b: dict) -> np.ndarray:
    """The frame's own bound (RMS mm and deg) over the bone's, the larger: frames the image
    determines worse than the bone's usual frame."""
    fb = b["frame_bound"]
    if fb is None:
        return np.zeros(len(b["pose"]))
    d = np.abs(np.diagonal(fb, axis1=1, axis2=2))
    t, r = np.sqrt(d[:, :3].sum(1)) / b["bound"]["rms_mm"], np.sqrt(d[:, 3:].sum(1)) / b["bound"]["rms_deg"]
    have = np.isfinite(t) & np.isfinite(r)
    f = b["frames"]
    return np.maximum(np.interp(f, f[have], t[have]), np.interp(f, f[have], r[have]))


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
        key = p.replace("_joint_", "_X_").replace("_sequential_", "_X_")
        by_seed.setdefault(key, []).append(p)
    rows = []  # (run, bone, frame, silent?, good-unflagged?, scores)
    for p, bones in runs.items():
        pair = [q for q in by_seed[p.replace("_joint_", "_X_").replace("_sequential_", "_X_")] if q != p]
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
    p.add_argument("dumps", nargs="+", help="silent_failures --dump files")
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    print_json({"study": "core.studies.tracking.silent_checks", "dumps": a.dumps, **evaluate(a.dumps)}, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
