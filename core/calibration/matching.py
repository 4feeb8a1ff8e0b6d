"""Two-view consistency of the labels: fundamental matrix (7/8-point + RANSAC) and resolution.

A labelling of one view can be ambiguous (a spiral missing its end beads fits two labellings; a
symmetric object fits its mirror labelling). The two views of a frame see the *same* beads, so
the right pair of labellings puts every bead on its epipolar line. The epipolar geometry comes
from a rough rig (:func:`core.markers.fundamental_matrix`) or, before any rig exists, from the
labelled beads themselves: for a rigid rig ``F`` is the same in every frame whatever the object
pose, so :func:`ransac_fundamental` pools correspondences of many frames.

* :func:`fundamental_8point` / :func:`fundamental_7point`: Hartley-normalised estimators
  (``x₂ᵀ F x₁ = 0``, rank 2).
* :func:`ransac_fundamental`: robust F; with ``groups`` the minimal samples are drawn within one
  group (one frame's candidate correspondence set) and each group counts only once.
* :func:`resolve_frame`: the pair of alternatives (per view) that agrees best with F.
* :func:`label_sequence`: labels every frame of a calibration sequence (both views), estimating
  F from the frames when no rig is given, and returns :class:`~core.calibration.ObjectFrame`
  observations for the bundle adjustment.

Pixels are ``(u, v) = (column, row)``, origin at the centre of the top-left pixel.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .._validate import as_float_array
from ..geometry.camera import Rig
from ..markers.pose import epipolar_distance, fundamental_matrix
from .bundle import ObjectFrame
from .detection import ObjectDetections
from .labelling import Labelling, label_view
from .objects import CalibrationTarget

__all__ = [
    "FrameLabels",
    "FundamentalFit",
    "fundamental_7point",
    "fundamental_8point",
    "label_sequence",
    "ransac_fundamental",
    "resolve_frame",
    "sampson_distance",
    "transfer_labels",
]


def _normalise(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c = x.mean(axis=0)
    s = np.sqrt(2) / max(np.linalg.norm(x - c, axis=1).mean(), 1e-12)
    T = np.array([[s, 0, -s * c[0]], [0, s, -s * c[1]], [0, 0, 1.0]])
    return np.column_stack([x, np.ones(len(x))]) @ T.T, T


def _design(x1: np.ndarray, x2: np.ndarray):
    h1, T1 = _normalise(x1)
    h2, T2 = _normalise(x2)
    A = np.einsum("ni,nj->nij", h2, h1).reshape(len(x1), 9)  # rows of x2 x1ᵀ
    return A, T1, T2


def fundamental_8point(x1, x2) -> np.ndarray:
    """Normalised 8-point ``F`` (>= 8 correspondences ``(N, 2)`` px), rank 2, unit norm."""
    a = as_float_array(x1, "x1", shape=(None, 2))
    b = as_float_array(x2, "x2", shape=(len(a), 2))
    if len(a) < 8:
        raise ValueError(f"x1: expected at least 8 correspondences, got {len(a)}")
    A, T1, T2 = _design(a, b)
    F = np.linalg.svd(A)[2][-1].reshape(3, 3)
    U, S, Vt = np.linalg.svd(F)
    F = U @ np.diag([S[0], S[1], 0.0]) @ Vt
    F = T2.T @ F @ T1
    return F / np.linalg.norm(F)


def fundamental_7point(x1, x2) -> list[np.ndarray]:
    """The 1-3 rank-2 solutions ``F`` through exactly 7 correspondences (Hartley–Zisserman)."""
    a = as_float_array(x1, "x1", shape=(7, 2))
    b = as_float_array(x2, "x2", shape=(7, 2))
    A, T1, T2 = _design(a, b)
    Vt = np.linalg.svd(A)[2]
    F1, F2 = Vt[-1].reshape(3, 3), Vt[-2].reshape(3, 3)
    # det(a F1 + (1 - a) F2) = 0: a cubic in a, from 4 samples
    xs = np.array([-1.0, 0.0, 1.0, 2.0])
    ys = [np.linalg.det(t * F1 + (1 - t) * F2) for t in xs]
    roots = np.roots(np.polyfit(xs, ys, 3))
    out = []
    for r in roots[np.abs(roots.imag) < 1e-9].real:
        F = T2.T @ (r * F1 + (1 - r) * F2) @ T1
        out.append(F / np.linalg.norm(F))
    return out


def sampson_distance(F, x1, x2) -> np.ndarray:
    """First-order geometric error (px) of each correspondence under ``F``."""
    h1 = np.column_stack([x1, np.ones(len(x1))])
    h2 = np.column_stack([x2, np.ones(len(x2))])
    Fx1, Ftx2 = h1 @ F.T, h2 @ F
    num = np.sum(h2 * Fx1, axis=1)
    den = Fx1[:, 0] ** 2 + Fx1[:, 1] ** 2 + Ftx2[:, 0] ** 2 + Ftx2[:, 1] ** 2
    return np.abs(num) / np.sqrt(np.maximum(den, 1e-300))


@dataclass(frozen=True, eq=False)
class FundamentalFit:
    """Result of :func:`ransac_fundamental`: ``F``, ``inliers (N,)`` and ``distance (N,)`` px
    (Sampson), ``n_groups`` supporting groups."""

    F: np.ndarray
    inliers: np.ndarray
    distance: np.ndarray
    n_groups: int


def ransac_fundamental(x1, x2, *, groups=None, method: str = "7point", threshold_px: float = 1.0,
                       iterations: int = 500, rng=0) -> FundamentalFit:
    """Robust fundamental matrix from putative correspondences ``x1, x2 (N, 2)`` px.

    Parameters
    ----------
    groups : (N,) int array, optional
        Group of each correspondence (e.g. one frame's candidate labelling); every sample is
        drawn within one group. Groups with the same ``group // 1000`` are alternatives of each
        other (the candidate labellings of one frame): only the best of them counts.
    method : {"7point", "8point"}
        Minimal solver of each sample; the final F is the 8-point fit to all inliers.
    threshold_px : float
        Inlier threshold on the Sampson distance.
    """
    a = as_float_array(x1, "x1", shape=(None, 2))
    b = as_float_array(x2, "x2", shape=(len(a), 2))
    if method not in ("7point", "8point"):
        raise ValueError(f"method: expected '7point' or '8point', got {method!r}")
    k = 7 if method == "7point" else 8
    grp = np.zeros(len(a), np.int64) if groups is None else np.asarray(groups, np.int64)
    if grp.shape != (len(a),):
        raise ValueError(f"groups: expected {len(a)} group ids, got shape {grp.shape}")
    g = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    ids = [gi for gi in np.unique(grp) if np.sum(grp == gi) >= k]
    if not ids:
        raise ValueError(f"x1: no group has the {k} correspondences a sample needs")
    sets = grp // 1000
    ug, gidx = np.unique(grp, return_inverse=True)
    uset, sidx = np.unique(ug // 1000, return_inverse=True)

    def support(F):
        d = sampson_distance(F, a, b)
        cnt = np.bincount(gidx[d <= threshold_px], minlength=len(ug))
        best = np.zeros(len(uset), np.int64)
        np.maximum.at(best, sidx, cnt)
        return int(best.sum()), d

    best_F, best_score = None, -1
    for _ in range(int(iterations)):
        gi = ids[g.integers(len(ids))]
        idx = g.choice(np.flatnonzero(grp == gi), k, replace=False)
        try:
            Fs = fundamental_7point(a[idx], b[idx]) if k == 7 else [fundamental_8point(a[idx], b[idx])]
        except np.linalg.LinAlgError:
            continue
        for F in Fs:
            sc, _ = support(F)
            if sc > best_score:
                best_F, best_score = F, sc
    if best_F is None:
        raise ValueError("x1, x2: no sample gave a fundamental matrix")
    # final: 8-point fit to the inliers of the best group of each set, then re-score
    d = sampson_distance(best_F, a, b)
    inl = _best_groups(d <= threshold_px, grp, sets)
    if inl.sum() >= 8:
        best_F = fundamental_8point(a[inl], b[inl])
        d = sampson_distance(best_F, a, b)
        inl = _best_groups(d <= threshold_px, grp, sets)
    return FundamentalFit(best_F, inl, d, len(np.unique(grp[inl])))


def _best_groups(inl: np.ndarray, grp: np.ndarray, sets: np.ndarray) -> np.ndarray:
    out = np.zeros_like(inl)
    for s in np.unique(sets):
        cand = np.unique(grp[sets == s])
        cnt = [np.sum(inl & (grp == gi)) for gi in cand]
        gi = cand[int(np.argmax(cnt))]
        out |= inl & (grp == gi)
    return out


def _pairs(l1: np.ndarray, l2: np.ndarray, uv1, uv2) -> tuple[np.ndarray, np.ndarray]:
    """Image points of the beads labelled in both views."""
    o1 = np.full((max(l1.max(initial=-1), l2.max(initial=-1)) + 1, 2), np.nan)
    o2 = o1.copy()
    o1[l1[l1 >= 0]] = uv1[l1 >= 0]
    o2[l2[l2 >= 0]] = uv2[l2 >= 0]
    ok = np.all(np.isfinite(o1), axis=1) & np.all(np.isfinite(o2), axis=1)
    return o1[ok], o2[ok]


def _options(lab: Labelling) -> list[np.ndarray]:
    return [lab.labels, *lab.alternatives] if lab.ok else []


@dataclass(frozen=True, eq=False)
class FrameLabels:
    """Both views of one frame after :func:`resolve_frame`: the chosen ``labellings``, ``ok``,
    ``reason`` and the median epipolar ``distance_px`` of the beads labelled in both views."""

    labellings: tuple[Labelling, ...]
    ok: bool
    reason: str
    distance_px: float


def transfer_labels(source: Labelling, det: ObjectDetections, F, target: CalibrationTarget, *,
                    source_view: int = 0, max_px: float = 2.0, samples: int = 3000, rng=0) -> Labelling:
    """Label a view from the other view's labelling and the epipolar geometry.

    Each labelled bead of ``source`` gives an epipolar line in the other view; the detections of
    the right size class within ``max_px`` of it are its candidates. The lines of a biplane rig
    are nearly parallel, so a line often passes several beads: RANSAC over random 6-tuples of
    candidate pairs (batched DLTs) keeps the one whose projection explains most detections, and
    :func:`~core.calibration.labelling.fit_labels` completes it. ``source_view`` says which view
    ``source`` is (0: the ``x1`` of ``x₂ᵀ F x₁ = 0``).
    """
    from .labelling import _batched_dlt, _score, fit_labels

    k = np.flatnonzero(source.labels >= 0)
    fail = Labelling(np.full(len(det), -1), det.uv.copy(), len(target), False,
                     "too few epipolar candidates to transfer labels")
    if len(k) < 6 or len(det) < 6:
        return fail
    src = source.uv[k]
    D = epipolar_distance(F, src, det.uv) if source_view == 0 else epipolar_distance(F, det.uv, src).T
    sizes, bead_cls = target.size_classes
    cls_ok = (det.size_class[None] < 0) | (det.size_class[None] == bead_cls[source.labels[k]][:, None])
    bi, di = np.nonzero(cls_ok & (D <= max_px))  # candidate (source bead, detection) pairs
    if len(np.unique(bi)) < 6:
        return fail
    g = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    pick = np.argsort(g.random((samples, len(bi))), axis=1)[:, :6]
    B, Dt = source.labels[k[bi[pick]]], di[pick]
    distinct = np.array([len(set(b)) == 6 and len(set(d)) == 6 for b, d in zip(B, Dt, strict=True)])
    if not distinct.any():
        return fail
    B, Dt = B[distinct], Dt[distinct]
    P = _batched_dlt(target.centers[B], det.uv[Dt])
    scale = det.px_per_mm if np.isfinite(det.px_per_mm) else 1.0
    gate = max(2.0, 0.6 * sizes[0] * scale)
    h = int(np.argmax(_score(P, target, det, gate)))
    seed = np.full(len(det), -1)
    seed[Dt[h]] = B[h]
    return fit_labels(target, det, seed)


def resolve_frame(labs: tuple[Labelling, Labelling], F, *, target: CalibrationTarget | None = None,
                  detections: tuple[ObjectDetections, ObjectDetections] | None = None,
                  max_px: float = 2.0, min_common: int = 6, margin: float = 3.0) -> FrameLabels:
    """Choose, among each view's labelling and its ``alternatives``, the pair whose common beads
    (at least ``min_common``; 4 when neither view has an alternative, and then all of them on
    their lines) lie on each other's epipolar lines: fewest beads farther than ``max_px`` from the
    line (at most 10 % of the common beads, which then lose their labels), then the smallest median
    distance. A runner-up as good (median within ``margin`` x the best) that is not the image of
    the best pair under a symmetry of ``target`` is resolved by the detections each pair
    explains, or else by keeping only the labels both agree on; failing that the frame is
    ambiguous (``ok=False``).

    With ``target`` and ``detections``, a frame that is not consistent is tried once more with
    each view labelled from the other one (:func:`transfer_labels`).
    """
    F = as_float_array(F, "F", shape=(3, 3))
    out = _resolve(labs, F, target, max_px, min_common, margin, detections)
    if out.ok or target is None or detections is None or "equally well" in out.reason:
        return out
    found = {}
    for v in (0, 1):
        if not labs[v].ok:
            continue
        for src in [labs[v].labels, *labs[v].alternatives]:
            other = transfer_labels(replace(labs[v], labels=src), detections[1 - v], F, target,
                                    source_view=v, max_px=max_px)
            own = labs[1 - v]
            worse = own.ok and other.n_explained < own.n_explained - max(2, 0.15 * own.n_explained)
            # when the epipolar lines run along the object (a spiral's axis in the epipolar
            # plane) a wrong transfer can be epipolar-consistent: it must explain the view well
            # (at most one detection per bead: spurious detections of a frame, e.g. a walkway
            # plate's, cannot be explained and must not make a right transfer look weak)
            weak = other.n_explained < 0.85 * min(np.sum(detections[1 - v].size_class >= 0), len(target))
            if not other.ok or worse or weak:
                continue
            pair = (replace(labs[v], labels=src, alternatives=()), other)
            retry = _resolve(pair if v == 0 else pair[::-1], F, target, max_px, min_common, margin)
            if retry.ok:
                key = _canonical(retry, target)
                if key not in found or retry.distance_px < found[key].distance_px:
                    found[key] = retry
    if not found:
        return out
    # the right labelling explains the most detections (a wrong shift along a helix loses its ends)
    total = {k: sum(lab.n_explained for lab in fr.labellings) for k, fr in found.items()}
    ranked = sorted(found, key=lambda k: (-total[k], found[k].distance_px))
    if len(ranked) > 1 and total[ranked[1]] == total[ranked[0]]:
        return FrameLabels(out.labellings, False, "labels transferred between the views fit in "
                           "more than one way", out.distance_px)
    return found[ranked[0]]


def _canonical(fr: FrameLabels, target: CalibrationTarget) -> bytes:
    """A key equal for labellings that differ only by a symmetry of the object."""
    keys = []
    for p in target.symmetries:
        keys.append(b"".join(np.where(lab.labels >= 0, p[lab.labels], -1).tobytes()
                             for lab in fr.labellings))
    return min(keys)


def _explained(target, dets, l1, l2) -> int:
    """Detections of both views explained by the labellings ``l1, l2`` once re-fitted."""
    from .labelling import fit_labels

    fits = [fit_labels(target, d, lab) for d, lab in zip(dets, (l1, l2), strict=True)]
    return sum(f.n_explained for f in fits) if all(f.ok for f in fits) else -1


def _resolve(labs, F, target, max_px, min_common, margin, dets=None) -> FrameLabels:
    a, b = labs
    if not (a.ok and b.ok):
        why = a.reason if not a.ok else b.reason
        return FrameLabels(labs, False, f"a view has no labelling: {why}", float("nan"))
    # a view whose labelling has no alternative (no rival, no symmetric image) needs no choice
    # between pairs, only a check: then 4 common beads do, every one on its epipolar line
    single = len(_options(a)) == 1 and len(_options(b)) == 1
    need = min(min_common, 4) if single else min_common
    scores = []
    for i, l1 in enumerate(_options(a)):
        for j, l2 in enumerate(_options(b)):
            p1, p2 = _pairs(l1, l2, a.uv, b.uv)
            if len(p1) < need:
                continue
            d = np.diag(epipolar_distance(F, p1, p2))
            n_bad = int(np.sum(d > max_px))
            scores.append((n_bad, float(np.median(d)), i, j))
    if not scores:
        return FrameLabels(labs, False, f"fewer than {need} beads labelled in both views", float("nan"))
    scores.sort()

    def pair(i, j):
        return _prune(replace(a, labels=_options(a)[i], alternatives=(), ambiguous=False),
                      replace(b, labels=_options(b)[j], alternatives=(), ambiguous=False), F, max_px)

    n_bad, best, i, j = scores[0]
    pick = pair(i, j)
    shared = len(_pairs(_options(a)[i], _options(b)[j], a.uv, b.uv)[0])
    if n_bad > (max(1, 0.1 * shared) if shared >= min_common else 0) or best > max_px:
        return FrameLabels(pick, False, f"no pair of labellings is epipolar-consistent (best: {n_bad} of "
                           f"{shared} common beads off their lines by > {max_px:g} px)", best)
    perms = target.symmetries[1:] if target is not None else ()
    equiv = {(np.where(pick[0].labels >= 0, p[pick[0].labels], -1).tobytes(),
              np.where(pick[1].labels >= 0, p[pick[1].labels], -1).tobytes()) for p in perms}
    equiv.add((pick[0].labels.tobytes(), pick[1].labels.tobytes()))
    rivals = [(sc, i2, j2) for nb, sc, i2, j2 in scores[1:]
              if (_options(a)[i2].tobytes(), _options(b)[j2].tobytes()) not in equiv
              and nb <= max(n_bad, 1) and sc <= margin * max(best, 0.05)]
    if rivals and target is not None and dets is not None:
        # the right pair explains the most detections (a wrong shift along a helix loses its ends)
        cand = [(i, j)] + [(i2, j2) for _, i2, j2 in rivals]
        n_exp = [_explained(target, dets, _options(a)[i2], _options(b)[j2]) for i2, j2 in cand]
        top = int(np.argmax(n_exp))
        if n_exp.count(n_exp[top]) == 1 and n_exp[top] >= 0:
            return FrameLabels(pair(*cand[top]), True, "", best)
    if rivals:
        # rivals that agree on every bead both views see differ only where no epipolar check is
        # possible: keep the labels all of them agree on
        agreed = _consensus(pick, [pair(i2, j2) for _, i2, j2 in rivals], perms)
        if all(lab.n_labelled >= min_common for lab in agreed):
            p1, p2 = _pairs(agreed[0].labels, agreed[1].labels, a.uv, b.uv)
            if len(p1) >= min_common:
                return FrameLabels(agreed, True, "", best)
        return FrameLabels(pick, False, "two pairs of labellings agree with the epipolar geometry "
                           "equally well (end beads missing in both views)", best)
    return FrameLabels(pick, True, "", best)


def _prune(a: Labelling, b: Labelling, F, max_px: float) -> tuple[Labelling, Labelling]:
    """Unlabel the beads labelled in both views that lie off each other's epipolar lines."""
    la, lb = a.labels.copy(), b.labels.copy()
    common = np.intersect1d(la[la >= 0], lb[lb >= 0])
    if common.size:
        ia = np.array([np.flatnonzero(la == k)[0] for k in common])
        ib = np.array([np.flatnonzero(lb == k)[0] for k in common])
        bad = np.diag(epipolar_distance(F, a.uv[ia], b.uv[ib])) > max_px
        la[ia[bad]] = -1
        lb[ib[bad]] = -1
    return replace(a, labels=la), replace(b, labels=lb)


def _consensus(pick, others, perms) -> tuple[Labelling, Labelling]:
    """``pick`` with the labels removed where any of ``others`` (each brought into the same
    symmetric representative as ``pick``) disagrees."""
    la, lb = pick[0].labels.copy(), pick[1].labels.copy()
    for o in others:
        best = None
        for p in (np.arange(max(la.max(), lb.max(), o[0].labels.max(), o[1].labels.max()) + 1), *perms):
            oa = np.where(o[0].labels >= 0, p[o[0].labels], -1)
            ob = np.where(o[1].labels >= 0, p[o[1].labels], -1)
            agree = np.sum(oa == la) + np.sum(ob == lb)
            if best is None or agree > best[0]:
                best = (agree, oa, ob)
        la[best[1] != la] = -1
        lb[best[2] != lb] = -1
    return replace(pick[0], labels=la), replace(pick[1], labels=lb)


def _estimate_F(per_frame: list, threshold_px: float, rng) -> FundamentalFit:
    """F from the frames' candidate labellings: each (frame, pair of options) is a group, the
    options of one frame are alternatives of each other."""
    x1, x2, grp = [], [], []
    for f, (a, b) in enumerate(per_frame):
        opts = [(i, j) for i in range(len(_options(a))) for j in range(len(_options(b)))]
        for k, (i, j) in enumerate(opts[:16]):
            p1, p2 = _pairs(_options(a)[i], _options(b)[j], a.uv, b.uv)
            if len(p1) >= 8:
                x1.append(p1)
                x2.append(p2)
                grp.append(np.full(len(p1), 1000 * f + k))
    if not x1:
        raise ValueError("detections: no frame has 8 beads labelled in both views to estimate F")
    return ransac_fundamental(np.concatenate(x1), np.concatenate(x2), groups=np.concatenate(grp),
                              threshold_px=threshold_px, rng=rng)


def label_sequence(target: CalibrationTarget, detections, *, rig: Rig | None = None, F=None,
                   max_px: float = 2.0, rng=0) -> tuple[list[FrameLabels], list[ObjectFrame], np.ndarray]:
    """Label both views of every frame of a calibration sequence.

    Parameters
    ----------
    target : CalibrationTarget
    detections : sequence of (ObjectDetections, ObjectDetections)
        Per frame, the detections of view 1 and view 2.
    rig : Rig, optional
        A rough rig; its epipolar geometry resolves the ambiguities.
    F : (3, 3) array, optional
        A fundamental matrix (``x₂ᵀ F x₁ = 0``) instead of ``rig``. Without either, F is estimated
        from the sequence (:func:`ransac_fundamental` over the frames' candidate labellings).
    max_px : float
        Largest median epipolar distance (px) of a consistent frame.

    Returns
    -------
    frames : list of FrameLabels
        Per frame; ``ok=False`` frames carry the reason.
    observations : list of ObjectFrame
        One per consistent frame (beads in object coordinates, their image positions).
    F : (3, 3) array
        The epipolar geometry used.
    """
    dets = list(detections)
    if not all(len(d) == 2 and all(isinstance(x, ObjectDetections) for x in d) for d in dets):
        raise ValueError("detections: expected one (view 1, view 2) pair of ObjectDetections per frame")
    per_frame = [(label_view(target, d1), label_view(target, d2)) for d1, d2 in dets]
    if rig is not None:
        F = fundamental_matrix(rig[0], rig[1])
    elif F is None:
        F = _estimate_F(per_frame, threshold_px=max_px, rng=rng).F
    F = as_float_array(F, "F", shape=(3, 3))
    frames = [resolve_frame(p, F, target=target, detections=d, max_px=max_px)
              for p, d in zip(per_frame, dets, strict=True)]
    obs = [ObjectFrame(target.centers, np.stack([lab.observed() for lab in fr.labellings]))
           for fr in frames if fr.ok]
    return frames, obs, F
