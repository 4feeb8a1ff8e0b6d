"""Which bead is which: automatic labelling of one view, and the manual-correction API (§5.4.2).

Every labelling ends the same way (:func:`fit_labels`): a DLT camera (object frame) is fitted to
the labelled beads, all model beads are projected, detections are assigned to the projections
(Hungarian, gated, size classes must agree), beads whose projections overlap another bead are
left out (their centroids are biased), and the fit is repeated until the labels are stable.
Only the *seeds* differ:

* **Spiral** (:func:`label_spiral`): the principal axis (PCA) of the detections approximates the
  projected helix axis; ordered along it, the detections' size classes form a string that is
  matched against the model's string (3.0/5.0 mm alternation) at every offset and in both
  directions, on short runs of consecutive detections (so missing or overlapping beads elsewhere
  do not matter). Each consistent run seeds a DLT; the seed that explains most detections wins.
* **Cube and other objects** (:func:`label_ransac`): RANSAC over correspondences — random
  6-tuples (two per size class where possible) labelled with random beads of the same class give
  batched DLTs; the one whose projections agree with most detections (projection consistency)
  seeds the fit. When its labelling leaves a bead's detection unexplained (among many spurious
  detections of one bead size, random samples are rarely all right), further rounds draw from
  the size classes least crowded by them, and the labelling that explains most detections wins.

A helix is (nearly) invariant under a screw motion that moves every bead two places along it, so
a view in which the end beads are missing can fit two labellings equally well. Such a
:class:`Labelling` is flagged ``ambiguous`` and carries the ``alternatives``; the two-view step
(:mod:`core.calibration.matching`) resolves it with the epipolar geometry.

Manual correction (for the calibration wizard): :meth:`Labelling.assign`,
:meth:`Labelling.unassign` and :func:`propagate_labels` (label at least six detections by hand,
the rest follows from the fitted projection).

Pixels are ``(u, v) = (column, row)``, origin at the centre of the top-left pixel; mm.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import linear_sum_assignment

from ._helix_seeds import affine_seeds
from ._near_symmetry import near_symmetries
from .detection import ObjectDetections
from .dlt import dlt_batch, planarity
from .objects import CalibrationTarget

__all__ = ["Labelling", "fit_labels", "label_ransac", "label_spiral", "label_view", "near_symmetries",
           "propagate_labels"]


@dataclass(frozen=True, eq=False)
class Labelling:
    """Bead identity of every detection of one view.

    Attributes
    ----------
    labels : (m,) int
        Model index (into the target's beads) of each detection, -1 when unlabelled.
    uv : (m, 2)
        The detections, px.
    n_beads : int
        Beads of the target.
    ok : bool
        A consistent labelling was found (``reason`` says why not).
    reason : str
    P : (3, 4) array or None
        DLT camera (object frame -> pixels) fitted to the labelled beads.
    rms_px : float
        Reprojection RMS of the labelled beads under ``P``.
    ambiguous : bool
        Another labelling (in ``alternatives``), not a symmetric image of this one, fits as well.
    alternatives : tuple of (m,) int arrays
        The images of ``labels`` under the object's symmetries
        (:attr:`CalibrationTarget.symmetries`; a view cannot tell them apart, the other view
        can), then other labellings that fit (nearly) as well.
    manual : bool
        Edited by hand.
    n_explained : int
        Detections lying on the projection of some bead of the right size under ``P``, whether
        labelled or left out because their bead overlaps another: the evidence for ``labels``.
    """

    labels: np.ndarray
    uv: np.ndarray
    n_beads: int
    ok: bool = True
    reason: str = ""
    P: np.ndarray | None = None
    rms_px: float = float("nan")
    ambiguous: bool = False
    alternatives: tuple = ()
    manual: bool = False
    n_explained: int = 0

    @property
    def n_labelled(self) -> int:
        return int(np.sum(self.labels >= 0))

    def observed(self) -> np.ndarray:
        """``(n_beads, 2)`` image position of every model bead (NaN where not labelled)."""
        out = np.full((self.n_beads, 2), np.nan)
        k = self.labels >= 0
        out[self.labels[k]] = self.uv[k]
        return out

    def _check_det(self, detection: int) -> int:
        if isinstance(detection, bool) or int(detection) != detection or not 0 <= detection < len(self.uv):
            raise ValueError(f"detection: expected an index in [0, {len(self.uv)}), got {detection!r}")
        return int(detection)

    def assign(self, detection: int, bead: int) -> Labelling:
        """A copy in which ``detection`` is bead ``bead`` (model index); a detection that had
        that bead loses it."""
        i = self._check_det(detection)
        if isinstance(bead, bool) or int(bead) != bead or not 0 <= bead < self.n_beads:
            raise ValueError(f"bead: expected a model index in [0, {self.n_beads}), got {bead!r}")
        lab = self.labels.copy()
        lab[lab == bead] = -1
        lab[i] = int(bead)
        return replace(self, labels=lab, manual=True, ambiguous=False, alternatives=(), reason="")

    def unassign(self, detection: int) -> Labelling:
        """A copy in which ``detection`` carries no label."""
        lab = self.labels.copy()
        lab[self._check_det(detection)] = -1
        return replace(self, labels=lab, manual=True)


def _empty(uv, n, reason) -> Labelling:
    return Labelling(np.full(len(uv), -1), np.asarray(uv, float).reshape(-1, 2), n, False, reason)


def _collinear(uv: np.ndarray, *, min_px: float = 1.0, min_ratio: float = 0.02) -> bool:
    """Image points on (nearly) one line: their spread across the principal direction is below
    ``min_px`` (RMS) or ``min_ratio`` of the spread along it. No view of a calibration object
    (helix or cube) images its beads on a line, and no camera can be fitted to such points."""
    uv = np.asarray(uv, float)
    if len(uv) < 3:
        return True
    s = np.linalg.svd(uv - uv.mean(axis=0), compute_uv=False) / np.sqrt(len(uv))
    return bool(s[1] < max(min_px, min_ratio * s[0]))


def _project(P: np.ndarray, X: np.ndarray) -> np.ndarray:
    h = X @ P[..., :3].swapaxes(-1, -2) + P[..., None, :, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        return h[..., :2] / h[..., 2:]


def _overlapping(proj: np.ndarray, radius_px: np.ndarray, factor: float) -> np.ndarray:
    d = np.linalg.norm(proj[:, None] - proj[None], axis=2)
    np.fill_diagonal(d, np.inf)
    return np.any(d < factor * (radius_px[:, None] + radius_px[None]), axis=1)


def fit_labels(target: CalibrationTarget, det: ObjectDetections, seed_labels, *, gate_px: float | None = None,
               overlap: float = 1.25, max_iter: int = 6, max_rms_px: float = 1.5) -> Labelling:
    """Refine a (partial) labelling by DLT fitting and re-assignment (module docstring).

    Parameters
    ----------
    target : CalibrationTarget
    det : ObjectDetections
    seed_labels : (m,) int array
        Initial model index per detection (-1 = unknown); at least 6 labelled, non-coplanar.
    gate_px : float, optional
        Largest distance (px) between a detection and its bead's projection; default 0.6 of the
        smallest projected bead diameter (at least 2 px).
    overlap : float
        Beads whose projected discs come closer than ``overlap`` x (sum of radii) to another
        bead are left unlabelled (biased centroids). 0 keeps them.
    max_iter : int
        Fit / re-assign rounds.
    max_rms_px : float
        A fit whose reprojection RMS exceeds this is not a labelling (``ok=False``).
    """
    X, n = target.centers, len(target)
    uv = det.uv
    lab = np.asarray(seed_labels, dtype=np.int64).copy()
    if lab.shape != (len(uv),):
        raise ValueError(f"seed_labels: expected {len(uv)} labels, got shape {lab.shape}")
    sizes, bead_cls = target.size_classes
    scale = det.px_per_mm if np.isfinite(det.px_per_mm) else 1.0
    gate = max(2.0, 0.6 * sizes[0] * scale) if gate_px is None else float(gate_px)
    radius = 0.5 * target.diameters * scale
    P, rms = None, float("nan")
    for _ in range(max_iter):
        k = lab >= 0
        if k.sum() < 6 or planarity(X[lab[k]]) < 0.02:
            return _empty(uv, n, "fewer than 6 non-coplanar labelled beads to fit a camera")
        P = dlt_batch(X[lab[k]], uv[k][None])[0]
        proj = _project(P, X)
        cost = np.linalg.norm(uv[:, None] - proj[None], axis=2)
        known = det.size_class >= 0
        bad = known[:, None] & (det.size_class[:, None] != bead_cls[None])
        cost = np.where(bad | (cost > gate) | ~np.isfinite(cost), 1e6, cost)
        if overlap > 0:
            cost[:, _overlapping(proj, radius, overlap)] = 1e6
        r, c = linear_sum_assignment(cost)
        keep = cost[r, c] < 1e6
        new = np.full(len(uv), -1)
        new[r[keep]] = c[keep]
        done = np.array_equal(new, lab)
        lab = new
        if done:
            break
    k = lab >= 0
    if k.sum() < 6:
        return _empty(uv, n, "fewer than 6 detections agree with the fitted projection")
    if _collinear(uv[k]):
        return _empty(uv, n, "the labelled detections lie on a line: no camera can be fitted to them")
    P = dlt_batch(X[lab[k]], uv[k][None])[0]
    rms = float(np.sqrt(np.mean(np.sum((_project(P, X[lab[k]]) - uv[k]) ** 2, axis=1))))
    if not rms <= max_rms_px:
        return replace(_empty(uv, n, f"the labelled beads do not fit one camera (RMS {rms:.2g} px > "
                                     f"{max_rms_px:g} px)"), P=P, rms_px=rms)
    explained = int(_score(P[None], target, det, gate)[0])
    return Labelling(lab, uv.copy(), n, True, "", P, rms, n_explained=explained)


def _score(P: np.ndarray, target: CalibrationTarget, det: ObjectDetections, gate: float) -> np.ndarray:
    """Detections explained by each hypothesis camera ``P (H, 3, 4)``: (H,) counts."""
    P = np.asarray(P, dtype=np.float64)
    H, m = len(P), len(det)
    if m == 0 or H == 0:
        return np.zeros(H, np.int64)
    _, bead_cls = target.size_classes
    cls = det.size_class
    # each detection is explained by the nearest projected bead of its own size class (any bead
    # for a detection of unknown size): per class, the squared distances of its beads to the
    # detections that may be theirs, the nearest one kept (NaN projections ignored: fmin). The
    # square root of the minimum is the minimum of the square roots, so the gate compares exactly
    # the distances a (H, n, m) norm would give.
    groups = []
    for k in np.unique(bead_cls):
        j = np.flatnonzero((cls < 0) | (cls == k))
        if j.size:
            groups.append((target.centers[bead_cls == k], j))
    u, v = det.uv[:, 0], det.uv[:, 1]
    out = np.empty(H, np.int64)
    step = max(1, (1 << 20) // max(len(target) * m, 1))  # hypotheses per chunk (~8 MB temporaries)
    for s in range(0, H, step):
        Pc = P[s : s + step]
        best = np.full((len(Pc), m), np.inf)
        for X, j in groups:
            proj = _project(Pc, X)  # (h, n_k, 2)
            du = proj[:, :, 0, None] - u[j]
            dv = proj[:, :, 1, None] - v[j]
            d2 = np.fmin.reduce(du * du + dv * dv, axis=1)  # (h, |j|)
            best[:, j] = np.fmin(best[:, j], d2)
        with np.errstate(invalid="ignore"):
            out[s : s + step] = (np.sqrt(best) <= gate).sum(axis=1)
    return out


def _refine(target, det, seeds: np.ndarray, gate: float, *, keep: int = 6) -> list[Labelling]:
    """Score seed labellings ``(H, m)`` by the detections their DLT explains; refine the best."""
    if len(seeds) == 0:
        return []
    X = target.centers
    cnt = (seeds >= 0).sum(axis=1)
    P = np.zeros((len(seeds), 3, 4))
    for c in np.unique(cnt):  # one batched DLT per seed size
        h = np.flatnonzero(cnt == c)
        I = np.stack([np.flatnonzero(seeds[i] >= 0) for i in h])
        P[h] = _batched_dlt(X[np.take_along_axis(seeds[h], I, axis=1)], det.uv[I])
    score = _score(P, target, det, gate)
    order = np.argsort(-score, kind="stable")
    results, seen = [], set()
    for h in order[: 3 * keep]:
        if len(results) >= keep or score[h] < 6:
            break
        lab = fit_labels(target, det, seeds[h], gate_px=gate)
        key = lab.labels.tobytes()
        if lab.ok and key not in seen:
            seen.add(key)
            results.append(lab)
    return results


def _choose(results: list[Labelling], uv, target: CalibrationTarget) -> Labelling:
    """Best labelling (most detections explained, then most labelled, then lowest RMS). Its
    images under the object's symmetries and other labellings that fit as well become
    ``alternatives``; only the latter make it ``ambiguous``."""
    if not results:
        return _empty(uv, len(target), "no hypothesis explains at least 6 detections")
    uniq = {r.labels.tobytes(): r for r in results}
    results = sorted(uniq.values(), key=lambda r: (-r.n_explained, -r.n_labelled, r.rms_px))
    best = results[0]
    sym = [np.where(best.labels >= 0, p[best.labels], -1) for p in target.symmetries[1:]]
    same = {x.tobytes() for x in sym} | {best.labels.tobytes()}
    rivals = [r.labels for r in results[1:] if r.labels.tobytes() not in same
              and r.n_explained >= best.n_explained and r.rms_px <= 3.0 * best.rms_px + 0.05]
    return replace(best, ambiguous=bool(rivals), alternatives=tuple(sym + rivals))


def label_spiral(target: CalibrationTarget, det: ObjectDetections, *, run: int = 7,
                 gate_px: float | None = None) -> Labelling:
    """Label a helical spiral's detections (string matching along the PCA axis + DLT fit)."""
    n, m = len(target), len(det)
    if m < 6:
        return _empty(det.uv, n, f"only {m} detection(s) in this view, at least 6 are needed")
    _, bead_cls = target.size_classes
    use = np.flatnonzero(det.size_class >= 0)
    if len(use) < 6:
        return _empty(det.uv, n, "fewer than 6 detections have a recognisable bead size")
    pts = det.uv[use]
    c = pts - pts.mean(axis=0)
    axis = np.linalg.svd(c, full_matrices=False)[2][0]
    w = min(run, len(use))
    seeds = []
    for sgn in (1.0, -1.0):
        order = use[np.argsort(sgn * (c @ axis))]
        cls = det.size_class[order]
        for p in range(0, len(order) - w + 1, max(1, w // 3)):
            s_cls = cls[p : p + w]
            for k0 in range(0, n - w + 1):
                if np.sum(bead_cls[k0 : k0 + w] != s_cls) > 0:
                    continue
                lab = np.full(m, -1)
                lab[order[p : p + w]] = np.arange(k0, k0 + w)
                seeds.append(lab)
    scale = det.px_per_mm if np.isfinite(det.px_per_mm) else 1.0
    gate = max(2.0, 0.6 * target.size_classes[0][0] * scale) if gate_px is None else float(gate_px)
    results = _refine(target, det, np.asarray(seeds, dtype=np.int64).reshape(-1, m), gate)
    best = _choose(results, det.uv, target)
    if not best.ok or best.ambiguous or best.n_labelled < 0.9 * len(use):
        # oblique view (the order along the axis is scrambled): chains + affine camera seeds
        results += _refine(target, det, affine_seeds(target, det), gate, keep=12)
        best = _choose(results, det.uv, target)
    return best


def label_ransac(target: CalibrationTarget, det: ObjectDetections, *, samples: int = 20000,
                 rounds: int = 3, rng=0, gate_px: float | None = None, extra_rounds: int = 4,
                 keep: int = 4) -> Labelling:
    """Label any object by RANSAC over size-consistent correspondences (the cube).

    ``rounds`` rounds of ``samples`` random 6-tuples (two correspondences per size class where
    possible); the best hypothesis is refined. When its labelling does not explain a detection
    for every bead the view can hold (``min(beads, detections)``), up to ``extra_rounds`` more
    rounds draw from the size classes least crowded by spurious detections (every other round;
    the rounds between use other sets of classes in turn: :func:`_likely_allocations`), and
    their ``keep`` best distinct hypotheses are refined too; the labelling that explains most
    detections wins, so a labelling the first rounds find is never lost (the extra rounds
    continue the same random stream).
    """
    n, m = len(target), len(det)
    if m < 6:
        return _empty(det.uv, n, f"only {m} detection(s) in this view, at least 6 are needed")
    g = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    sizes, bead_cls = target.size_classes
    use = np.flatnonzero(det.size_class >= 0)
    by_cls = [use[det.size_class[use] == k] for k in range(len(sizes))]
    beads_of = [np.flatnonzero(bead_cls == k) for k in range(len(sizes))]
    per = [min(2, len(by_cls[k]), len(beads_of[k])) for k in range(len(sizes))]
    while sum(per) < 6:  # classes with few detections: take more from the others
        grow = [k for k in range(len(sizes)) if per[k] < min(len(by_cls[k]), len(beads_of[k]))]
        if not grow:
            return _empty(det.uv, n, "fewer than 6 detections have a recognisable bead size")
        per[grow[0]] += 1
    scale = det.px_per_mm if np.isfinite(det.px_per_mm) else 1.0
    gate = max(2.0, 0.6 * sizes[0] * scale) if gate_px is None else float(gate_px)
    best_seed, best_score = None, -1
    for _ in range(rounds):
        D, B = _draw(g, by_cls, beads_of, per, samples)  # (S, 6+)
        P = _batched_dlt(target.centers[B], det.uv[D], fast=True)
        score = _score(P, target, det, gate)
        h = int(np.argmax(score))
        if score[h] > best_score:
            best_score = int(score[h])
            best_seed = np.full(m, -1)
            best_seed[D[h]] = B[h]
        if best_score >= len(use):
            break
    results = [] if best_seed is None or best_score < 6 else \
        _with_near_images(target, det, _refine(target, det, best_seed[None], gate, keep=1), gate)
    # among many spurious detections of one bead size (a walkway plate's, noise) random samples
    # are rarely all right: a weak result (some bead's detection unexplained) is searched again
    # from the classes least crowded by them
    full = min(n, m)
    if extra_rounds > 0 and max((r.n_explained for r in results), default=0) < full:
        allocs = _likely_allocations(per, [len(c) for c in by_cls], beads_of, target)
        # the likeliest allocation every other round, the others in turn between them
        order = [allocs[0] if r % 2 == 0 or len(allocs) == 1 else allocs[1 + (r // 2) % (len(allocs) - 1)]
                 for r in range(extra_rounds)]
        for alloc in order:
            D, B = _draw(g, by_cls, beads_of, alloc, samples)
            score = _score(_batched_dlt(target.centers[B], det.uv[D], fast=True), target, det, gate)
            top = np.argsort(-score, kind="stable")[: 4 * keep]
            seeds = np.full((len(top), m), -1)
            seeds[np.arange(len(top))[:, None], D[top]] = B[top]
            results += _with_near_images(target, det, _refine(target, det, seeds, gate, keep=keep), gate)
            if max((r.n_explained for r in results), default=0) >= full:
                break
    if not results:
        return _empty(det.uv, n, "no correspondence hypothesis explains at least 6 detections")
    return _choose(_distinct(results), det.uv, target)


def _distinct(results: list[Labelling]) -> list[Labelling]:
    """``results`` without a labelling that agrees with a better one (more detections explained,
    then more labelled, then lower RMS) on every detection both label: refinements of two
    hypotheses of the same labelling may differ by a bead left out, and are no rival of it."""
    out = []
    for r in sorted(results, key=lambda r: (-r.n_explained, -r.n_labelled, r.rms_px)):
        same = False
        for q in out:
            both = (r.labels >= 0) & (q.labels >= 0)
            if both.sum() >= 6 and np.array_equal(r.labels[both], q.labels[both]):
                same = True
                break
        if not same:
            out.append(r)
    return out


def _draw(g: np.random.Generator, by_cls, beads_of, per, samples: int) -> tuple[np.ndarray, np.ndarray]:
    """``samples`` random tuples of ``per[k]`` detections of each size class ``k``, labelled with
    as many random beads of that class: detection indices and bead indices, both (S, sum(per))."""
    dets, beads = [], []
    for k, q in enumerate(per):
        if q == 0:
            continue
        dets.append(by_cls[k][np.argsort(g.random((samples, len(by_cls[k]))), axis=1)[:, :q]])
        beads.append(beads_of[k][np.argsort(g.random((samples, len(beads_of[k]))), axis=1)[:, :q]])
    return np.concatenate(dets, axis=1), np.concatenate(beads, axis=1)


def _with_near_images(target, det, results: list[Labelling], gate: float) -> list[Labelling]:
    """``results`` and the refined images of each under the target's near symmetries.

    A hypothesis may be a near-symmetric image of the right labelling (the cube's squares turned
    by 90°): every image is fitted too, and the one that explains most detections (the beads off
    the symmetry, e.g. each plane's fifth bead) wins; images that explain as many stay as
    alternatives for the other view to resolve."""
    out = list(results)
    for r in results:
        for p in near_symmetries(target):
            lab = fit_labels(target, det, np.where(r.labels >= 0, p[np.maximum(r.labels, 0)], -1),
                             gate_px=gate)
            if lab.ok:
                out.append(lab)
    return out


def _likely_allocations(per, n_det, beads_of, target: CalibrationTarget) -> list[list[int]]:
    """Correspondences per size class (as many as ``per`` in all), most likely first to give a
    random sample that is all right if each class's detections beyond its bead count are spurious,
    among those that do not put more than four points on one plane of beads (one class's beads
    may lie on a plane: the cube's; a DLT needs 11 independent equations, a plane gives at most
    8). After the first, each allocation is the likeliest that uses another set of classes than
    the ones before it (the prior cannot see beads detected with the wrong size or none, which
    leave a class as crowded as one with spurious detections); ``[per]`` when none is allowed."""
    from itertools import product

    n_bead = [len(b) for b in beads_of]
    flat, ranked = {}, []
    lim = [min(d, b) for d, b in zip(n_det, n_bead, strict=True)]
    for q in product(*[range(min(x, sum(per)) + 1) for x in lim]):
        if sum(q) != sum(per):
            continue
        used = tuple(k for k in range(len(q)) if q[k])
        for c in [used] + [(k,) for k in used]:
            if c not in flat:
                flat[c] = planarity(target.centers[np.concatenate([beads_of[k] for k in c])]) < 1e-3
        if flat[used] or sum(min(2 * q[k], 8) if flat[(k,)] else 2 * q[k] for k in used) < 2 * sum(q):
            continue
        p = 1.0
        for k, qk in enumerate(q):
            for i in range(qk):
                p *= (lim[k] - i) / (n_det[k] - i) / (n_bead[k] - i)
        ranked.append((-p, q, used))
    ranked.sort()
    out, supports = [], set()
    for _, q, used in ranked:
        if used not in supports:
            supports.add(used)
            out.append(list(q))
    return out or [list(per)]


def _batched_dlt(X: np.ndarray, uv: np.ndarray, *, fast: bool = False) -> np.ndarray:
    """DLT per sample with its own object points: ``X (S, k, 3)``, ``uv (S, k, 2)``.

    ``fast``: the camera with its last element 1 (in normalised coordinates, where that element is
    the depth of the points' centroid, far from 0), from the 11 x 11 normal equations: a tenth of
    the time of the eigenvector, for RANSAC's hypotheses (the labels' camera is fitted by
    dlt_batch)."""
    S, k = X.shape[:2]
    from .dlt import _design, _normaliser

    T3, T2 = _normaliser(X), _normaliser(uv)
    Xn = np.einsum("sij,skj->ski", T3[:, :3, :3], X) + T3[:, None, :3, 3]
    Xn = np.concatenate([Xn, np.ones((S, k, 1))], axis=2)
    xn = np.einsum("sij,skj->ski", T2[:, :2, :2], uv) + T2[:, None, :2, 2]
    A = _design(Xn, xn)
    with np.errstate(all="ignore"):
        if fast:
            M = np.swapaxes(A, 1, 2) @ A
            try:
                p = np.linalg.solve(M[:, :11, :11], -M[:, :11, 11:])[..., 0]
            except np.linalg.LinAlgError:  # a degenerate sample (points on a plane, a line)
                p = None
            if p is not None:
                Pn = np.concatenate([p, np.ones((S, 1))], axis=1).reshape(S, 3, 4)
                P = np.linalg.solve(T2, Pn) @ T3
                return np.where(np.isfinite(P), P, 0.0)
        # the right singular vector of the smallest singular value is the eigenvector of the
        # smallest eigenvalue of AᵀA (12 x 12): eigh of many small symmetric matrices takes about
        # 2/3 of the time of their SVD, and hypotheses need no more than its accuracy (the labels'
        # camera is then fitted by dlt_batch)
        Pn = np.linalg.eigh(np.swapaxes(A, 1, 2) @ A)[1][:, :, 0].reshape(S, 3, 4)
        P = np.linalg.solve(T2, Pn) @ T3
    return np.where(np.isfinite(P), P, 0.0)


def label_view(target: CalibrationTarget, det: ObjectDetections, **options) -> Labelling:
    """Label one view: :func:`label_spiral` for spirals, :func:`label_ransac` otherwise."""
    if not isinstance(target, CalibrationTarget):
        raise ValueError(f"target: expected a CalibrationTarget, got {type(target).__name__}")
    if not isinstance(det, ObjectDetections):
        raise ValueError(f"det: expected ObjectDetections, got {type(det).__name__}")
    if len(det) >= 6 and _collinear(det.uv):
        return _empty(det.uv, len(target), f"all {len(det)} detections lie on a line (no view of the "
                      "object does that: wrong input or a degenerate detection)")
    if target.kind == "spiral":
        return label_spiral(target, det, **options)
    return label_ransac(target, det, **options)


def propagate_labels(target: CalibrationTarget, det: ObjectDetections, hints: dict, **options) -> Labelling:
    """Label all detections from a few given by hand (the wizard's manual correction).

    ``hints`` maps detection index -> bead id (str) or model index (int); at least six,
    non-coplanar. The DLT fitted to them projects every bead and :func:`fit_labels` assigns the
    rest; the hinted labels are kept even when another assignment would fit better.
    """
    seed = np.full(len(det), -1)
    for i, b in hints.items():
        if isinstance(i, bool) or int(i) != i or not 0 <= i < len(det):
            raise ValueError(f"hints: detection index {i!r} is not in [0, {len(det)})")
        seed[int(i)] = target.index(b) if isinstance(b, str) else int(b)
    if len(set(seed[seed >= 0].tolist())) != int((seed >= 0).sum()):
        raise ValueError("hints: a bead is given to two detections")
    lab = fit_labels(target, det, seed, **options)
    if not lab.ok:
        return replace(lab, reason=f"hints: {lab.reason}")
    labels = lab.labels.copy()
    for i in np.flatnonzero(seed >= 0):
        labels[labels == seed[i]] = -1
        labels[i] = seed[i]
    return replace(lab, labels=labels, manual=True)

