"""Beads seen by calibrated cameras: epipolar matching, triangulation, rigid-body pose.

* :func:`fundamental_matrix` / :func:`epipolar_distance` — the epipolar geometry of two
  :class:`~core.geometry.Camera` objects (``x_bᵀ F x_a = 0``), distances in pixels.
* :func:`match_epipolar` — one-to-one correspondences between the bead detections of two views
  (Hungarian assignment on the symmetric epipolar distance, gated), flagging ambiguous ones.
* :func:`triangulate_beads` — :func:`core.geometry.triangulate` with reprojection errors.
* :func:`rigid_fit` — least-squares rigid (Kabsch) or similarity (Umeyama) transform from ≥ 3
  model points to observed points, vectorised over frames; NaN observations are skipped; returns
  the residual of every point.

Pixels are ``(u, v) = (column, row)`` with the origin at the centre of the top-left pixel; lab
points in mm; poses are 4 × 4 ``T_lab_from_model``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from .._validate import as_float_array
from ..geometry.camera import Camera
from ..geometry.triangulate import Triangulation, triangulate

__all__ = [
    "EpipolarMatches",
    "RigidFit",
    "epipolar_distance",
    "fundamental_matrix",
    "match_epipolar",
    "rigid_fit",
    "triangulate_beads",
]


def fundamental_matrix(cam_a: Camera, cam_b: Camera) -> np.ndarray:
    """``F`` (3 × 3) with ``x_bᵀ F x_a = 0`` for homogeneous pixels of one lab point.

    ``F = [e_b]ₓ P_b P_a⁺`` with ``e_b = P_b C_a`` (the epipole of camera a in view b).
    """
    if not (isinstance(cam_a, Camera) and isinstance(cam_b, Camera)):
        raise ValueError("cam_a, cam_b: expected two core.geometry.Camera objects")
    Pa, Pb = cam_a.P, cam_b.P
    e = Pb @ np.append(cam_a.source, 1.0)
    ex = np.array([[0, -e[2], e[1]], [e[2], 0, -e[0]], [-e[1], e[0], 0]])
    F = ex @ Pb @ np.linalg.pinv(Pa)
    return F / np.linalg.norm(F)


def epipolar_distance(F, uv_a, uv_b) -> np.ndarray:
    """``(N, M)`` symmetric epipolar distance (px): mean of the point-to-epipolar-line distances
    of ``uv_b[j]`` to the line of ``uv_a[i]`` and of ``uv_a[i]`` to the line of ``uv_b[j]``."""
    F = as_float_array(F, "F", shape=(3, 3))
    a = as_float_array(uv_a, "uv_a", shape=(None, 2))
    b = as_float_array(uv_b, "uv_b", shape=(None, 2))
    ha = np.column_stack([a, np.ones(len(a))])
    hb = np.column_stack([b, np.ones(len(b))])
    la = ha @ F.T  # lines in view b, (N, 3)
    lb = hb @ F  # lines in view a, (M, 3)
    num = np.abs(ha @ F.T @ hb.T)  # |x_bᵀ F x_a|, (N, M)
    da = num / np.hypot(la[:, 0], la[:, 1])[:, None]
    db = num / np.hypot(lb[:, 0], lb[:, 1])[None, :]
    return 0.5 * (da + db)


@dataclass(frozen=True, eq=False)
class EpipolarMatches:
    """Correspondences between two views.

    ``pairs (K, 2)`` indices into the two detection lists, ``distance (K,)`` symmetric epipolar
    distance in px, ``ambiguous (K,)`` True when another candidate of either point lies within
    the gate (the match may be swapped: resolve with a third view, size or tracking).
    """

    pairs: np.ndarray
    distance: np.ndarray
    ambiguous: np.ndarray


def match_epipolar(cam_a: Camera, cam_b: Camera, uv_a, uv_b, *, max_distance: float = 2.0
                   ) -> EpipolarMatches:
    """One-to-one matches of detections ``uv_a (N, 2)``, ``uv_b (M, 2)`` within ``max_distance``
    pixels of each other's epipolar lines (minimum total distance, Hungarian algorithm)."""
    if not (np.isfinite(max_distance) and max_distance > 0):
        raise ValueError(f"max_distance: expected a positive distance in pixels, got {max_distance!r}")
    D = epipolar_distance(fundamental_matrix(cam_a, cam_b), uv_a, uv_b)
    if D.size == 0:
        z = np.zeros(0)
        return EpipolarMatches(np.zeros((0, 2), np.int64), z, z.astype(bool))
    big = 1e6
    cost = np.where(D <= max_distance, D, big)
    ia, ib = linear_sum_assignment(cost)
    keep = cost[ia, ib] < big
    ia, ib = ia[keep], ib[keep]
    within = D <= max_distance
    amb = (within[ia].sum(axis=1) > 1) | (within[:, ib].sum(axis=0) > 1)
    return EpipolarMatches(np.stack([ia, ib], axis=1), D[ia, ib], amb)


def triangulate_beads(cameras, uv, *, method: str = "optimal") -> Triangulation:
    """Lab positions (mm) of beads seen in ``V`` views: ``uv (V, ..., 2)`` px, NaN = unseen.

    A thin wrapper of :func:`core.geometry.triangulate`; the result carries the reprojection
    error of every bead in every view (px).
    """
    return triangulate(cameras, uv, method=method)


@dataclass(frozen=True, eq=False)
class RigidFit:
    """Result of :func:`rigid_fit` (leading shape ``S`` of the frames, ``()`` for one).

    Attributes
    ----------
    T : (*S, 4, 4)
        ``T_observed_from_model`` (rotation, translation in mm; times ``scale`` for Umeyama).
    scale : (*S,)
        Similarity scale (1 for a rigid fit).
    residuals : (*S, N)
        Distance (mm) between each observed point and the transformed model point; NaN where
        the observation is missing.
    rms : (*S,)
        Root-mean-square residual over the used points (mm); NaN when fewer than 3.
    n_used : (*S,)
        Points used.
    """

    T: np.ndarray
    scale: np.ndarray
    residuals: np.ndarray
    rms: np.ndarray
    n_used: np.ndarray


def rigid_fit(model, observed, *, weights=None, scale: bool = False) -> RigidFit:
    """Least-squares ``observed ≈ s R model + t`` (Kabsch; Umeyama with ``scale=True``).

    Parameters
    ----------
    model : (N, 3) array
        Points in the model (bone / CT) frame, mm.
    observed : (N, 3) or (F, N, 3) array
        The same points observed (e.g. triangulated) in the lab, mm, per frame; NaN rows are
        missing and skipped.
    weights : (N,) or (F, N) array, optional
        Non-negative weights (e.g. 1 / σ² of each bead).
    scale : bool
        Also fit an isotropic scale (Umeyama 1991).

    Returns
    -------
    RigidFit
        Frames with fewer than 3 usable, non-collinear points get NaN transforms.
    """
    X = as_float_array(model, "model", shape=(None, 3))
    Y = as_float_array(observed, "observed", finite=False)
    single = Y.ndim == 2
    Y = Y[None] if single else Y
    if Y.ndim != 3 or Y.shape[1:] != X.shape:
        raise ValueError(f"observed: expected shape {X.shape} or (F, {len(X)}, 3), got {np.shape(observed)}")
    F, N = Y.shape[:2]
    w = np.ones((F, N)) if weights is None else np.broadcast_to(
        as_float_array(weights, "weights"), (F, N)).astype(float)
    if np.any(w < 0):
        raise ValueError("weights: expected non-negative weights")
    w = np.where(np.all(np.isfinite(Y), axis=2), w, 0.0)
    Yz = np.where(np.isfinite(Y), Y, 0.0)
    W = w.sum(axis=1)
    n_used = (w > 0).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mx = (w[..., None] * X[None]).sum(axis=1) / W[:, None]
        my = (w[..., None] * Yz).sum(axis=1) / W[:, None]
        Xc = X[None] - mx[:, None]
        Yc = Yz - my[:, None]
        C = np.einsum("fn,fni,fnj->fij", w, Yc, Xc) / W[:, None, None]  # cov(Y, X)
    C = np.where(np.isfinite(C), C, 0.0)
    U, Sv, Vt = np.linalg.svd(C)
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.ones((F, 3))
    D[:, 2] = d
    R = U @ (D[:, :, None] * Vt)
    if scale:
        varx = np.einsum("fn,fni,fni->f", w, Xc, Xc) / W
        s = (Sv * D).sum(axis=1) / varx
    else:
        s = np.ones(F)
    t = my - s[:, None] * np.einsum("fij,fj->fi", R, mx)
    # degenerate: < 3 points or (nearly) collinear (second singular value ~ 0)
    bad = (n_used < 3) | (Sv[:, 1] <= 1e-9 * np.maximum(Sv[:, 0], 1e-300)) | ~np.isfinite(s)
    T = np.zeros((F, 4, 4))
    T[:, :3, :3] = s[:, None, None] * R
    T[:, :3, 3] = t
    T[:, 3, 3] = 1.0
    T[bad] = np.nan
    pred = np.einsum("fij,nj->fni", T[:, :3, :3], X) + T[:, None, :3, 3]
    res = np.linalg.norm(pred - Y, axis=2)
    used = w > 0
    res = np.where(used, res, np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        rms = np.sqrt(np.where(used, res, 0.0).__pow__(2).sum(axis=1) / n_used)
    rms = np.where(bad, np.nan, rms)
    s = np.where(bad, np.nan, s)
    if single:
        return RigidFit(T[0], s[0], res[0], rms[0], n_used[0])
    return RigidFit(T, s, res, rms, n_used)
