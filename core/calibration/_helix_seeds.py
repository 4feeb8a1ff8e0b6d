"""Labelling seeds for a helix seen obliquely: chains of neighbouring beads + affine camera.

Private to :mod:`core.calibration.labelling`. When the helix axis is tilted towards the view,
the order of the beads along the projected axis is scrambled and the string matching of the
thesis fails. Consecutive beads of the helix are still close in the image and alternate in
size, so chains ``a-b-c-d`` of near neighbours with alternating size classes are candidate runs
of four consecutive beads. Four points fix an affine camera (``x = c + A X``, the weak-
perspective limit of the pinhole); each (chain, model window) pair predicts every bead, and the
hypotheses that explain most detections, re-fitted to all the detections they explain, become
seeds for the perspective DLT fit.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from .detection import ObjectDetections
from .objects import CalibrationTarget


def _chains(uv: np.ndarray, cls: np.ndarray, use: np.ndarray, k_near: int) -> np.ndarray:
    """(C, 4) detection indices of near-neighbour chains with alternating size classes."""
    D = np.linalg.norm(uv[use, None] - uv[None, use], axis=2)
    np.fill_diagonal(D, np.inf)
    same = cls[use][:, None] == cls[use][None]
    near_opp = np.argsort(np.where(same, np.inf, D), axis=1)[:, :k_near]
    ok_opp = np.take_along_axis(~same & np.isfinite(D), near_opp, axis=1)
    out = []
    for a in range(len(use)):
        for b in near_opp[a][ok_opp[a]]:
            for c in near_opp[b][ok_opp[b]]:
                if c == a or cls[use][c] != cls[use][a]:
                    continue
                for d in near_opp[c][ok_opp[c]]:
                    if d != b and cls[use][d] == cls[use][b]:
                        out.append((a, b, c, d))
    return use[np.asarray(out, dtype=np.int64).reshape(-1, 4)]


def _grow(lab: np.ndarray, Xh: np.ndarray, uv: np.ndarray, ok_pair: np.ndarray, gate: float) -> np.ndarray:
    """Extend a run of labelled consecutive beads at both ends (and into gaps): an affine camera
    fitted to the run predicts the next two beads at each end, the nearest free detections of
    the right size within ``gate`` px take their labels; repeat while the run grows."""
    n = len(Xh)
    lab = lab.copy()
    for _ in range(n):
        k = lab >= 0
        have = np.zeros(n, bool)
        have[lab[k]] = True
        A = np.linalg.lstsq(Xh[lab[k]], uv[k], rcond=None)[0]
        lo, hi = int(lab[k].min()), int(lab[k].max())
        cand = np.array([b for b in (lo - 1, lo - 2, hi + 1, hi + 2, *range(lo, hi))
                         if 0 <= b < n and not have[b]], dtype=np.int64)
        if not cand.size:
            break
        d = np.linalg.norm(uv[:, None] - (Xh[cand] @ A)[None], axis=2)
        d = np.where(ok_pair[:, cand] & ~k[:, None], d, np.inf)
        added = 0
        for _ in range(len(cand)):  # greedy: closest pair first, each detection / bead once
            i, j = np.unravel_index(np.argmin(d), d.shape)
            if not d[i, j] <= gate:
                break
            lab[i] = cand[j]
            d[i, :] = np.inf
            d[:, j] = np.inf
            added += 1
        if not added:
            break
    return lab


def _period(cls: np.ndarray) -> int:
    """Smallest shift under which the size-class string repeats (0: none shorter than it)."""
    n = len(cls)
    for p in range(1, n // 2 + 1):
        if np.array_equal(cls[p:], cls[:-p]):
            return p
    return 0


def _assign(pred: np.ndarray, uv: np.ndarray, ok_pair: np.ndarray, gate: float) -> np.ndarray:
    cost = np.linalg.norm(uv[:, None] - pred[None], axis=2)
    cost = np.where(ok_pair & (cost <= gate) & np.isfinite(cost), cost, 1e6)
    r, c = linear_sum_assignment(cost)
    lab = np.full(len(uv), -1)
    keep = cost[r, c] < 1e6
    lab[r[keep]] = c[keep]
    return lab


def affine_seeds(target: CalibrationTarget, det: ObjectDetections, *, k_near: int = 3, top: int = 12,
                 chunk: int = 2048) -> np.ndarray:
    """``(S, m)`` seed labellings (model index per detection, -1 unknown), best first."""
    X = target.centers
    n, m = len(X), len(det)
    _, bcls = target.size_classes
    cls = det.size_class
    use = np.flatnonzero(cls >= 0)
    if len(use) < 6:
        return np.zeros((0, m), np.int64)
    chains = _chains(det.uv, cls, use, k_near)
    Xh = np.column_stack([X, np.ones(n)])
    win, Minv = [], []
    for k in range(n - 3):
        M = Xh[k : k + 4]
        if np.linalg.cond(M) < 1e8:
            win.append(k)
            Minv.append(np.linalg.inv(M))
    if not len(chains) or not win:
        return np.zeros((0, m), np.int64)
    win, Minv = np.asarray(win), np.stack(Minv)
    pat_c = cls[chains]  # (C, 4)
    pat_w = np.stack([bcls[k : k + 4] for k in win])  # (W, 4)
    ci, wi = np.nonzero(np.all(pat_c[:, None] == pat_w[None], axis=2))
    if ci.size == 0:
        return np.zeros((0, m), np.int64)
    nn = np.sort(np.linalg.norm(det.uv[use, None] - det.uv[None, use], axis=2), axis=1)[:, 1]
    gate = 0.35 * float(np.median(nn))
    ok_pair = (cls[:, None] < 0) | (cls[:, None] == bcls[None])  # (m, n)
    # score each (chain, window) by the detections its affine camera explains near the run
    off = np.arange(-4, 8)
    near = np.clip(win[:, None] + off[None], 0, n - 1)  # (W, 12) beads around the run
    uvm = det.uv
    u, v = uvm[None, :, None, 0], uvm[None, :, None, 1]
    bad_w = ~ok_pair[:, near].transpose(1, 0, 2)  # (W, m, 12): a detection of another size
    scores = np.empty(len(ci))
    g2 = gate * gate
    for s in range(0, len(ci), chunk):
        c_, w_ = ci[s : s + chunk], wi[s : s + chunk]
        A = Minv[w_] @ uvm[chains[c_]]  # (h, 4, 2) affine parameters
        pred = Xh[near[w_]] @ A  # (h, 12, 2)
        du = u - pred[:, None, :, 0]
        dv = v - pred[:, None, :, 1]
        d2 = du * du + dv * dv  # (h, m, 12)
        d2[bad_w[w_]] = np.inf
        scores[s : s + chunk] = (d2.min(axis=2) <= g2).sum(axis=1)
    order = np.argsort(-scores, kind="stable")
    grown, shapes = [], set()
    for h in order[: 8 * top]:
        if len(grown) >= top or scores[h] < 5:
            break
        lab = np.full(m, -1)
        lab[chains[ci[h]]] = np.arange(win[wi[h]], win[wi[h]] + 4)
        lab = _grow(lab, Xh, det.uv, ok_pair, gate)
        k = lab >= 0
        shape = (lab - lab[k].min() * k).tobytes()  # the same run shifted along the helix
        if k.sum() >= 6 and shape not in shapes:
            shapes.add(shape)
            grown.append(lab)
    # a helix is locally invariant under a screw motion by one pattern period: a run of beads
    # fits every shift equally well, only the ends tell them apart; all shifts become seeds (the
    # perspective fit then explains the most detections with the right one)
    p = _period(bcls)
    seeds, seen = [], set()
    for lab in grown:
        k = lab >= 0
        for j in (range(-int(lab[k].max()), n - int(lab[k].min()), p) if p else (0,)):
            sh = np.where(k, lab + j, -1)
            sh[(sh < 0) | (sh >= n)] = -1
            if (sh >= 0).sum() < 6:
                continue
            key = sh.tobytes()
            if key not in seen:
                seen.add(key)
                seeds.append(sh)
    return np.asarray(seeds, dtype=np.int64).reshape(-1, m)
