"""Self-calibration of the residual distortion from a tracked trial.

A distortion correction fitted to a grid leaves a smooth residual warp (a global polynomial
leaves ~0.1 mm on an image intensifier, thesis Table 3.1). Every bone's pose absorbs the part of
that warp it can mimic at its place in the image, so the poses carry errors that are smooth in
time. This module estimates the residual warp of each view from the tracked trial itself — the
frames and the tracked poses only — and undoes it.

Model
-----
Per view a displacement field ``g(u, v)`` on a generic basis: the monomials ``x^i y^j``
(``i + j <= order``) of the image coordinates normalised to [-1, 1] about the image centre
(:class:`ResidualWarp`), for ``u`` and ``v`` separately. The corrected frame shows at ``p`` the
content that belongs at ``p - g(p)``; :meth:`ResidualWarp.apply` resamples it at ``x + g(x)``.

Linearisation (:func:`frame_system`): per frame and view, the frame's line integrals ``-log I``
and the tracked bones' DRRs at their tracked poses, both band-passed (a Gaussian of
``smooth_px`` minus one of ``highpass_px``: the soft tissue's smooth structure taken out), over
the bones' footprint. The residual is modelled as a gain on the DRRs, each bone's pose change
(central differences of its DRR, mm and radians about its centroid, the convention of
:func:`core.geometry.transforms.pose_from_params`) and the field's image motion (the DRR's
gradient times each basis function). Pixels weigh by Cauchy weights of their residual after the
gain fit (``weighting="robust"``): the skin's and the walkway's edges, which no DRR carries,
otherwise pull the least-squares poses by ~1 mm even from the true poses (256² acceptance
frames, this 2-core CPU machine).

Fit (:func:`estimate_residual_warp`): every (frame) gain and (frame, bone) pose change is a free
unknown, eliminated per frame by its Schur complement, so the field is fitted only from what no
pose change can produce: the same warp seen by bones at different places, in two views, over
many frames. What a motion of the whole rig can mimic (roughly the constant and linear terms of
both views) is not determined by the images; a ridge (``ridge_low`` on the terms of order <= 1,
``ridge`` on the others, relative to the mean diagonal of the field's normal matrix) keeps those
terms at zero, leaving the poses as tracked in those directions. Gauss–Newton iterations
(``iterations``) warp the frames by the current field and move the poses by the fitted changes.
:func:`refine_residual_warp` is the user's entry: estimate from a first tracking run, then track
again on the re-warped frames (from the first run's pose of each bone at its first frame).

What it achieves (measured): a known smooth warp of noise-free frames is recovered with an
error of 20-36 % of its RMS over the bones (two bones, two frames, 128²:
``tests/core/tracking/test_residual_warp.py``). On the acceptance trial it does NOT work
(:mod:`core.studies.tracking.self_calibration`, ``resources/benchmarks/
tracking_self_calibration_h200.json`` and ``_cpu.json``): at 1024² (one H200) the true residual
is 0.17 / 0.21 px RMS over the bones and the estimate is 0.22-0.26 px off it, from the true poses
as from the tracked ones; re-tracking on it left the tibia at 2.97× (plain, from 2.21×) and
4.27× (final stage, from 4.34×) its bound. The pixel model lacks the skin's and walkway's edges:
from the true poses, with the field held at zero, its poses are already 0.9-1.5× the bound off,
as much as the warp moves them, and the field fits that mismatch. Not for users as it is.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from .feed import MissingView

__all__ = ["ResidualWarp", "WarpEstimate", "estimate_residual_warp", "frame_system", "monomials",
           "refine_residual_warp"]


def monomials(order: int) -> list[tuple[int, int]]:
    """Exponents ``(i, j)`` of ``x^i y^j`` with ``i + j <= order``, by total order."""
    return [(n - j, j) for n in range(order + 1) for j in range(n + 1)]


@dataclass
class ResidualWarp:
    """Per view a polynomial displacement field (pixels) over normalised coordinates
    ``x = (u - cu) / s``, ``y = (v - cv) / s`` with ``(cu, cv)`` the image centre and ``s`` half
    the shorter side. ``coef[view]`` is ``(2, K)``: the u and v components' coefficients of
    :func:`monomials` ``(order)``."""

    shapes: list[tuple[int, int]]
    order: int = 3
    coef: list[np.ndarray] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.shapes = [(int(h), int(w)) for h, w in self.shapes]
        K = len(monomials(self.order))
        if not self.coef:
            self.coef = [np.zeros((2, K)) for _ in self.shapes]
        self.coef = [np.asarray(c, dtype=float).reshape(2, K) for c in self.coef]
        self._maps: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    @property
    def n_basis(self) -> int:
        return len(monomials(self.order))

    def basis(self, view: int, uv) -> np.ndarray:
        """``(N, K)`` basis values at pixel positions ``uv (N, 2)`` of ``view``."""
        h, w = self.shapes[view]
        s = min(h, w) / 2.0
        uv = np.asarray(uv, dtype=float).reshape(-1, 2)
        x, y = (uv[:, 0] - (w - 1) / 2) / s, (uv[:, 1] - (h - 1) / 2) / s
        return np.stack([x**i * y**j for i, j in monomials(self.order)], axis=1)

    def displacement(self, view: int, uv) -> np.ndarray:
        """``(N, 2)`` field ``g`` at ``uv (N, 2)`` of ``view`` (pixels)."""
        return self.basis(view, uv) @ self.coef[view].T

    def add(self, view: int, dcoef) -> None:
        self.coef[view] = self.coef[view] + np.asarray(dcoef, dtype=float).reshape(2, -1)
        self._maps.pop(view, None)

    def maps(self, view: int) -> tuple[np.ndarray, np.ndarray]:
        """cv2.remap tables of :meth:`apply` (float32)."""
        if view not in self._maps:
            h, w = self.shapes[view]
            v, u = np.mgrid[0:h, 0:w].astype(float)
            uv = np.stack([u.ravel(), v.ravel()], axis=1)
            d = self.displacement(view, uv)
            self._maps[view] = ((uv[:, 0] + d[:, 0]).reshape(h, w).astype(np.float32),
                                (uv[:, 1] + d[:, 1]).reshape(h, w).astype(np.float32))
        return self._maps[view]

    def apply(self, view: int, image):
        """The frame with the field undone: output ``x`` samples ``image`` at ``x + g(x)``
        (bilinear, edges replicated). None (or a :class:`core.tracking.feed.MissingView`) stays."""
        if image is None or isinstance(image, MissingView) or not np.any(self.coef[view]):
            return image
        mx, my = self.maps(view)
        return cv2.remap(np.asarray(image, dtype=np.float32), mx, my, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REPLICATE)

    def frames(self, frames: Callable[[int], Sequence]) -> Callable[[int], list]:
        """``frames`` (a tracking frame source) with the field undone in every view; its
        ``reason(frame, view)`` (why a view has no image, :mod:`core.tracking.feed`) kept."""
        def warped(i):
            return [self.apply(v, x) for v, x in enumerate(frames(i))]

        if (why := getattr(frames, "reason", None)) is not None:
            warped.reason = why
        return warped

    def rms_px(self, view: int, step: int = 8) -> float:
        """RMS of the field over ``view``'s image (every ``step``-th pixel)."""
        h, w = self.shapes[view]
        v, u = np.mgrid[0:h:step, 0:w:step]
        d = self.displacement(view, np.stack([u.ravel(), v.ravel()], axis=1))
        return float(np.sqrt(np.mean(np.sum(d**2, axis=1))))

    def to_dict(self) -> dict:
        return {"model": "polynomial", "order": self.order, "shapes": [list(s) for s in self.shapes],
                "coef": [c.tolist() for c in self.coef]}


# --------------------------------------------------------------------------- measurements
def _band(img: np.ndarray, smooth_px: float, highpass_px: float) -> np.ndarray:
    img = np.asarray(img, dtype=np.float32)
    a = cv2.GaussianBlur(img, (0, 0), smooth_px) if smooth_px > 0 else img
    return a - cv2.GaussianBlur(img, (0, 0), highpass_px)


def frame_system(fluence, base, derivs, warp: ResidualWarp, view: int, *, smooth_px: float,
                 highpass_px: float, valid_range=(0.02, 0.999), stride: int = 1, dilate_px: float = 0.0,
                 weighting: str = "robust", robust_c: float = 2.0):
    """One view of one frame linearised (module docs): ``(X_local, X_field, r, w)`` over the used
    pixels, with ``r ≈ X_local @ [gain - 1, -δ_1, ..., -δ_n] + X_field @ -dcoef``.

    ``base`` ``(n_bones, H, W)``: the bones' DRRs at the current poses; ``derivs``
    ``(n_bones, 6, H, W)``: their derivatives per unit pose change (mm, rad)."""
    img = np.asarray(fluence, dtype=np.float32)
    # only the bones' bounding box (grown by the filters' reach) is needed
    vs, us = np.nonzero(np.sum(base, axis=0) > 0)
    if len(vs) == 0:
        return np.zeros((0, 1 + 6 * len(base))), np.zeros((0, 2 * warp.n_basis)), np.zeros(0), np.zeros(0)
    m = int(np.ceil(3 * highpass_px + dilate_px)) + 2
    v0, v1 = max(vs.min() - m, 0), min(vs.max() + m + 1, img.shape[0])
    u0, u1 = max(us.min() - m, 0), min(us.max() + m + 1, img.shape[1])
    img = img[v0:v1, u0:u1]
    base = np.asarray(base)[:, v0:v1, u0:u1]
    derivs = np.asarray(derivs)[:, :, v0:v1, u0:u1]
    lo, hi = valid_range
    ok = (img > lo) & (img < hi)
    ok = cv2.erode(ok.astype(np.uint8), np.ones((2 * int(np.ceil(highpass_px)) + 3,) * 2, np.uint8)) > 0
    L = -np.log(np.clip(img, 1e-4, None))
    L = np.where(ok, L, float(np.median(L[ok])) if ok.any() else 0.0).astype(np.float32)
    Lb = _band(L, smooth_px, highpass_px)
    Db = _band(np.sum(base, axis=0), smooth_px, highpass_px)
    support = (np.sum(base, axis=0) > 0).astype(np.uint8)
    if dilate_px > 0:
        support = cv2.dilate(support, np.ones((2 * int(np.ceil(dilate_px)) + 1,) * 2, np.uint8))
    support = support > 0
    use = ok & support
    if stride > 1:
        sub = np.zeros_like(use)
        sub[(-v0) % stride::stride, (-u0) % stride::stride] = True
        use &= sub
    gy, gx = np.gradient(Db)
    vv, uu = np.nonzero(use)
    B = warp.basis(view, np.stack([uu + u0, vv + v0], axis=1).astype(float))
    cols = [Db[use]]
    for b in range(len(base)):
        for k in range(6):
            cols.append(_band(derivs[b, k], smooth_px, highpass_px)[use])
    X_local = np.stack(cols, axis=1).astype(float)
    X_field = np.concatenate([gx[use][:, None] * B, gy[use][:, None] * B], axis=1)
    r = (Lb - Db)[use].astype(float)
    # the log image's noise variance ~ 1 / fluence ("counts"), every pixel alike ("uniform"), or
    # Cauchy weights of the residual after a gain fit ("robust": what the DRRs lack — the skin's
    # and the walkway's edges, untracked bones — weighs little)
    w = img[use].astype(float) if weighting == "counts" else np.ones(len(r))
    if weighting == "robust" and len(r):
        d = X_local[:, 0]
        a = float(d @ (r + d)) / max(float(d @ d), 1e-30)
        e = r + d - a * d
        sig = 1.4826 * float(np.median(np.abs(e - np.median(e)))) or 1.0
        w = 1.0 / (1.0 + (e / (robust_c * sig)) ** 2)
    return X_local, X_field, r, w


def _derivatives(renderer, poses: np.ndarray, bones: Sequence[int], centroids, view: int, step=(0.05, 0.05)):
    """``(base (n, H, W), derivs (n, 6, H, W))``: the bones' full-image DRRs in ``view`` and
    their central-difference derivatives per mm and radian."""
    from ..geometry.transforms import pose_from_params

    h = np.array([step[0]] * 3 + [np.radians(step[1])] * 3)
    base, der = [], []
    for k, b in enumerate(bones):
        P = [poses[k]]
        for j in range(6):
            for sgn in (1, -1):
                e = np.zeros(6)
                e[j] = sgn * h[j]
                P.append(pose_from_params(e, center=centroids[k], base=poses[k]))
        batch = renderer.render(np.array(P)[:, None], views=[view], bones=[b], roi="full")
        out = np.array(batch.numpy()[:, 0, 0])
        base.append(out[0])
        der.append((out[1::2] - out[2::2]) / (2 * h[:, None, None]))
    return np.array(base), np.array(der)


# --------------------------------------------------------------------------- estimate
@dataclass
class WarpEstimate:
    """What :func:`estimate_residual_warp` found: the field, the poses moved by the fitted pose
    errors (``poses[(bone, frame)]``), a log per iteration and the time it took."""

    warp: ResidualWarp
    poses: dict
    iterations: list
    time_s: float

    def to_dict(self) -> dict:
        return {"warp": self.warp.to_dict(), "iterations": self.iterations, "time_s": self.time_s,
                "rms_px": [self.warp.rms_px(v) for v in range(len(self.warp.shapes))]}


def estimate_residual_warp(renderer, bones, frames: Callable[[int], Sequence], poses: Mapping, *,
                           frame_list: Sequence[int] | None = None, order: int = 3, iterations: int = 2,
                           smooth_px: float | None = None, highpass_px: float | None = None,
                           ridge: float = 1e-3, ridge_low: float | None = 1e3, stride: int | None = None,
                           valid_range=(0.02, 0.999), step=(0.05, 0.05), dilate_px: float = 0.0,
                           weighting: str = "robust") -> WarpEstimate:
    """Estimate each view's residual warp from frames and tracked poses (module docs).

    Parameters
    ----------
    renderer : DRRRenderer
        Volume ``i`` is ``bones[i]`` (as for :func:`core.tracking.trial.track`).
    bones : sequence of BoneModel
    frames : callable(frame) -> per view flatfield-normalised images (as for ``track``)
    poses : mapping (bone name, frame) -> (4, 4) pose or None
        The tracked poses; a bone without a (finite) pose in a frame is left out of that frame.
    frame_list : frames to use (default every frame in ``poses``)
    smooth_px, highpass_px : the band-pass (default 1 and 4 pixels at 256² views, scaled with the
        image's shorter side); ``stride``: every ``stride``-th pixel in each direction (default 1
        up to 256², then scaled)
    ridge, ridge_low : the field's ridge relative to the mean diagonal of its normal matrix, on
        the terms of order >= 2 and <= 1 (``ridge_low`` None: the same as ``ridge``)
    """
    from ..geometry.transforms import pose_from_params

    t0 = time.perf_counter()
    names = [b.name for b in bones]
    fl = sorted({f for (_, f) in poses}) if frame_list is None else [int(f) for f in frame_list]
    poses = {k: p for k, p in poses.items() if k[1] in set(fl)}
    shapes = [np.asarray(x).shape for x in frames(fl[0])]
    scale = min(shapes[0]) / 256.0
    smooth_px = float(smooth_px if smooth_px is not None else max(1.0, 0.5 * scale))
    highpass_px = float(highpass_px if highpass_px is not None else max(2.0, 2.0 * scale))
    stride = int(stride or max(1, round(scale)))
    warp = ResidualWarp(shapes, order)
    V, K = len(shapes), warp.n_basis
    low = np.array([i + j <= 1 for i, j in monomials(order)])
    is_low = np.tile(low, 2 * V)
    cur = {k: (None if p is None or not np.all(np.isfinite(p)) else np.asarray(p, float))
           for k, p in poses.items()}
    log = []
    for it in range(iterations):
        Ncc = np.zeros((2 * V * K, 2 * V * K))
        bc = np.zeros(2 * V * K)
        parts = {}
        chi2, npx = 0.0, 0
        for f in fl:
            have = [b for b, nm in enumerate(names) if cur.get((nm, f)) is not None]
            if not have:
                continue
            img = frames(f)
            P = np.array([cur[(names[b], f)] for b in have])
            nl = V + 6 * len(have)
            Nll = np.zeros((nl, nl))
            Nlc = np.zeros((nl, 2 * V * K))
            bl = np.zeros(nl)
            blocks = []
            for v in range(V):
                if img[v] is None or isinstance(img[v], MissingView):
                    continue
                base, der = _derivatives(renderer, P, have, [bones[b].centroid for b in have], v, step)
                XL, XF, r, w = frame_system(warp.apply(v, img[v]), base, der, warp, v, smooth_px=smooth_px,
                                            highpass_px=highpass_px, valid_range=valid_range, stride=stride,
                                            dilate_px=dilate_px, weighting=weighting)
                # local columns: this view's gain, then every bone's 6 pose columns
                idx = np.r_[v, V + np.arange(6 * len(have))]
                fidx = np.arange(v * 2 * K, (v + 1) * 2 * K)
                WL, WF = XL * w[:, None], XF * w[:, None]
                Nll[np.ix_(idx, idx)] += XL.T @ WL
                Nlc[np.ix_(idx, fidx)] += WL.T @ XF
                Ncc[np.ix_(fidx, fidx)] += XF.T @ WF
                bl[idx] += WL.T @ r
                bc[fidx] += WF.T @ r
                chi2 += float(r @ (w * r))
                npx += len(r)
                blocks.append(v)
            if not blocks:
                continue
            Nll += 1e-9 * np.trace(Nll) / nl * np.eye(nl)
            Linv = np.linalg.inv(Nll)
            Ncc -= Nlc.T @ Linv @ Nlc
            bc -= Nlc.T @ Linv @ bl
            parts[f] = (have, Linv, Nlc, bl)
        d = float(np.mean(np.diag(Ncc))) or 1.0
        reg = np.where(is_low, ridge if ridge_low is None else ridge_low, ridge) * d
        c = np.linalg.solve(Ncc + np.diag(reg), bc)
        # r = X_local [a-1, -δ] + X_field (-g): the solution's field is -c, the pose errors -x
        for v in range(V):
            warp.add(v, -c[v * 2 * K:(v + 1) * 2 * K])
        moves = []
        for f, (have, Linv, Nlc, bl) in parts.items():
            x = Linv @ (bl - Nlc @ c)
            for k, b in enumerate(have):
                delta = -x[V + 6 * k:V + 6 * k + 6]
                moves.append(delta)
                # the tracked pose is the truth moved by δ: take δ back
                cur[(names[b], f)] = pose_from_params(-delta, center=bones[b].centroid,
                                                      base=cur[(names[b], f)])
        moves = np.array(moves) if moves else np.zeros((0, 6))
        n = len(moves)
        increment = ResidualWarp(shapes, order, [-c[u * 2 * K:(u + 1) * 2 * K] for u in range(V)])
        log.append({"iteration": it, "pixels": npx, "weighted_residual_per_pixel": chi2 / max(npx, 1),
                    "step_rms_px": [increment.rms_px(v) for v in range(V)],
                    "rms_px": [warp.rms_px(v) for v in range(V)],
                    "pose_move_rms_mm": float(np.sqrt(np.mean(np.sum(moves[:, :3] ** 2, 1)))) if n else 0.0,
                    "pose_move_rms_deg": float(np.degrees(np.sqrt(np.mean(np.sum(moves[:, 3:] ** 2, 1)))))
                    if n else 0.0})
    return WarpEstimate(warp, cur, log, time.perf_counter() - t0)


def refine_residual_warp(renderer, bones, frames: Callable[[int], Sequence], result, *, options=None,
                         order: int = 3, iterations: int = 2, retrack: bool = True, every: int = 1, **kw):
    """The user's entry: estimate the residual warp of each view from a tracking run ``result``
    (:class:`core.tracking.results.TrackingResult` of :func:`core.tracking.trial.track` on
    ``renderer``, ``bones``, ``frames``) and, with ``retrack``, track the trial again on the
    re-warped frames, starting from the first run's pose of each bone at its first frame.

    Returns ``(estimate, result)``: the :class:`WarpEstimate` (its ``warp.frames(frames)`` is the
    corrected frame source) and the new :class:`TrackingResult` (None without ``retrack``).
    Good results only (unflagged, with a pose) of every ``every``-th frame enter the estimate;
    ``kw`` goes to :func:`estimate_residual_warp`."""
    names = [b.name for b in bones]
    keyframes = {}
    if retrack:  # each bone's first pose in the run: checked before the (long) estimate
        for nm in names:
            for f in result.frames:
                r = result.results.get((nm, f))
                if r is not None and r.pose is not None:
                    keyframes[nm] = {f: r.pose}
                    break
            else:
                raise ValueError(f"refine_residual_warp: bone {nm!r} has no pose in the tracking result "
                                 "to track the trial again from (pass the bones that were tracked)")
    poses = {}
    for (nm, f), r in result.results.items():
        if nm in names and r.pose is not None and not r.flags and np.all(np.isfinite(r.pose)):
            poses[(nm, f)] = r.pose
    est = estimate_residual_warp(renderer, bones, frames, poses, frame_list=list(result.frames)[::every],
                                 order=order, iterations=iterations, **kw)
    if not retrack:
        return est, None
    from .trial import track

    new = track(renderer, bones, est.warp.frames(frames), list(result.frames), keyframes=keyframes,
                options=options)
    return est, new
