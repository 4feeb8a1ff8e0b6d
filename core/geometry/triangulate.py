"""n-view triangulation of points observed by calibrated cameras.

Two estimators, both vectorised over many points:

* ``"linear"``: the homogeneous DLT (each view contributes ``u p3 - p1`` and ``v p3 - p2``),
  Hartley-normalised (image points per view: centroid to 0, mean distance sqrt(2); lab: the
  centroid of the X-ray sources to 0, their spread to ~1) and solved by SVD. Exact on noise-free
  data; minimises an algebraic error otherwise.
* ``"optimal"``: minimises the sum of squared reprojection errors (pixels) over all views with
  :func:`scipy.optimize.least_squares` (analytic, block-sparse Jacobian), initialised by the
  linear solution. Optimal (maximum likelihood) for isotropic Gaussian pixel noise.

Image points are ``(u, v) = (column, row)`` pixels with the origin at the centre of the top-left
pixel. A point missing from a view is given as NaN ``(u, v)`` there; points seen in fewer than
``min_views`` (>= 2) views are returned as NaN.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.sparse
from scipy.optimize import least_squares

from .._validate import as_float_array
from .camera import Camera, Rig

__all__ = ["Triangulation", "triangulate"]


@dataclass(frozen=True, eq=False)
class Triangulation:
    """Result of :func:`triangulate`.

    Attributes
    ----------
    points : (..., 3) array
        Lab points, mm; NaN for points seen in fewer than ``min_views`` views.
    reprojection_error : (..., V) array
        Distance (pixels) between the observed and the reprojected point in each view; NaN where
        the point was not observed or not triangulated.
    n_views : (...,) int array
        Number of views in which each point was observed.
    method : str
        ``"linear"`` or ``"optimal"``.
    """

    points: np.ndarray
    reprojection_error: np.ndarray
    n_views: np.ndarray
    method: str

    @property
    def rms_error(self) -> np.ndarray:
        """``(...,)`` root-mean-square reprojection error of each point over its views, pixels."""
        e = self.reprojection_error
        cnt = np.sum(np.isfinite(e), axis=-1)
        ss = np.nansum(e**2, axis=-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(cnt > 0, np.sqrt(ss / np.maximum(cnt, 1)), np.nan)


def _projection_matrices(cameras) -> np.ndarray:
    if isinstance(cameras, Rig):
        cameras = cameras.cameras
    if isinstance(cameras, Sequence) and cameras and all(isinstance(c, Camera) for c in cameras):
        P = np.stack([c.P for c in cameras])
    else:
        P = as_float_array(cameras, "cameras", ndim=3)
        if P.shape[1:] != (3, 4):
            raise ValueError(
                "cameras: expected a Rig, a sequence of Camera or a (V, 3, 4) array of projection "
                f"matrices, got an array of shape {P.shape}"
            )
    if len(P) < 2:
        raise ValueError(f"cameras: expected at least 2 views, got {len(P)}")
    return P


def _camera_centres(P: np.ndarray) -> np.ndarray:
    """(V, 3) centres (null vectors) of projection matrices (V, 3, 4)."""
    _, _, Vt = np.linalg.svd(P)
    h = Vt[:, -1, :]
    if np.any(np.abs(h[:, 3]) <= 1e-12 * np.abs(h[:, :3]).max(axis=1)):
        raise ValueError("cameras: a projection matrix has its centre at infinity (affine camera)")
    return h[:, :3] / h[:, 3:]


def _project(P: np.ndarray, X: np.ndarray) -> np.ndarray:
    """Project points X (N, 3) by matrices P (N, 3, 4) -> (N, 2)."""
    h = np.einsum("nij,nj->ni", P[:, :, :3], X) + P[:, :, 3]
    return h[:, :2] / h[:, 2:]


def _linear(P: np.ndarray, uv: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Normalised homogeneous DLT. P (V, 3, 4), uv (V, N, 2), mask (V, N) -> X (N, 3)."""
    V, N = mask.shape
    # Lab normalisation from the sources (independent of the unknown points).
    C = _camera_centres(P)
    m = C.mean(axis=0)
    spread = np.sqrt(np.mean(np.sum((C - m) ** 2, axis=1)))
    s3 = 1.0 / spread if spread > 0 else 1.0
    H_inv = np.eye(4)
    H_inv[:3, :3] /= s3
    H_inv[:3, 3] = m  # X = H_inv @ Xn
    Pn = P @ H_inv
    # Image normalisation per view from its observed points.
    uvn = np.zeros_like(uv)
    for i in range(V):
        pts = uv[i, mask[i]]
        if len(pts) == 0:
            continue
        c = pts.mean(axis=0)
        d = np.linalg.norm(pts - c, axis=1).mean()
        s = np.sqrt(2) / d if d > 0 else np.sqrt(2) / max(np.abs(c).max(), 1.0)
        T = np.array([[s, 0, -s * c[0]], [0, s, -s * c[1]], [0, 0, 1.0]])
        Pn[i] = T @ Pn[i]
        uvn[i] = np.where(mask[i, :, None], (uv[i] - c) * s, 0.0)
    A = np.zeros((N, 2 * V, 4))
    A[:, 0::2] = uvn[:, :, 0].T[:, :, None] * Pn[None, :, 2] - Pn[None, :, 0]
    A[:, 1::2] = uvn[:, :, 1].T[:, :, None] * Pn[None, :, 2] - Pn[None, :, 1]
    A *= np.repeat(mask.T, 2, axis=1)[:, :, None]
    norms = np.linalg.norm(A, axis=2, keepdims=True)
    A = np.divide(A, norms, out=np.zeros_like(A), where=norms > 0)
    _, _, Vt = np.linalg.svd(A)
    Xh = Vt[:, -1, :] @ H_inv.T
    with np.errstate(divide="ignore", invalid="ignore"):
        X = Xh[:, :3] / Xh[:, 3:]
    X[~np.all(np.isfinite(X), axis=1)] = np.nan
    return X


def _optimal(P: np.ndarray, uv: np.ndarray, mask: np.ndarray, X0: np.ndarray) -> np.ndarray:
    """Minimise reprojection error for each point (rows of X0 without NaN)."""
    good = np.all(np.isfinite(X0), axis=1)
    idx = np.flatnonzero(good)
    if idx.size == 0:
        return X0
    sub = mask[:, idx]
    pj, vi = np.nonzero(sub.T)  # observation k: local point pj[k] seen in view vi[k]
    Pobs = P[vi]
    obs = uv[vi, idx[pj]]
    n_obs, n_pts = len(vi), len(idx)
    rows = np.repeat(np.arange(2 * n_obs), 3)
    cols = (3 * np.repeat(pj, 2)[:, None] + np.arange(3)).ravel()

    def residuals(x):
        X = x.reshape(-1, 3)[pj]
        return (_project(Pobs, X) - obs).ravel()

    def jacobian(x):
        X = x.reshape(-1, 3)[pj]
        h = np.einsum("nij,nj->ni", Pobs[:, :, :3], X) + Pobs[:, :, 3]
        w = h[:, 2:3]
        ju = (Pobs[:, 0, :3] - (h[:, 0:1] / w) * Pobs[:, 2, :3]) / w
        jv = (Pobs[:, 1, :3] - (h[:, 1:2] / w) * Pobs[:, 2, :3]) / w
        data = np.stack([ju, jv], axis=1).ravel()
        return scipy.sparse.csr_matrix((data, (rows, cols)), shape=(2 * n_obs, 3 * n_pts))

    sol = least_squares(
        residuals,
        X0[idx].ravel(),
        jac=jacobian,
        method="trf",
        tr_solver="lsmr",
        x_scale="jac",
        xtol=1e-12,
        ftol=1e-12,
        gtol=1e-12,
    )
    X = X0.copy()
    X[idx] = sol.x.reshape(-1, 3)
    return X


def triangulate(cameras, uv, *, method: str = "optimal", min_views: int = 2) -> Triangulation:
    """Triangulate points observed in several calibrated views.

    Parameters
    ----------
    cameras : Rig, sequence of Camera, or (V, 3, 4) array
        The V >= 2 views (projection matrices in Talus pixels, lab in mm).
    uv : (V, ..., 2) array
        Observed image points ``(u, v) = (column, row)`` in pixels, origin at the centre of the
        top-left pixel, one slice per view (the layout of :meth:`Rig.project`). NaN (both
        coordinates) marks a point not observed in that view.
    method : {"optimal", "linear"}
        ``"linear"``: normalised DLT; ``"optimal"``: least-squares reprojection error,
        initialised by the linear solution.
    min_views : int
        Points observed in fewer views (>= 2) come back as NaN.

    Returns
    -------
    Triangulation
        ``points (..., 3)`` mm, ``reprojection_error (..., V)`` pixels, ``n_views (...,)``.

    Raises
    ------
    ValueError
        On a wrong number of views, wrong shapes, infinite values, a point with only one of
        its two coordinates NaN, or bad options.
    """
    if method not in ("linear", "optimal"):
        raise ValueError(f'method: expected "linear" or "optimal", got {method!r}')
    if isinstance(min_views, bool) or int(min_views) != min_views or min_views < 2:
        raise ValueError(f"min_views: expected an integer >= 2, got {min_views!r}")
    P = _projection_matrices(cameras)
    V = len(P)
    uv = as_float_array(uv, "uv", finite=False)
    if uv.ndim < 2 or uv.shape[0] != V or uv.shape[-1] != 2:
        raise ValueError(f"uv: expected shape ({V}, ..., 2) for {V} views, got {uv.shape}")
    if np.any(np.isinf(uv)):
        raise ValueError("uv: contains infinite values (use NaN for a missing observation)")
    lead = uv.shape[1:-1]
    uv = uv.reshape(V, -1, 2)
    nan = np.isnan(uv)
    if np.any(nan[..., 0] != nan[..., 1]):
        raise ValueError("uv: a point has one coordinate NaN and the other finite")
    mask = ~nan[..., 0]
    n_views = mask.sum(axis=0)
    enough = n_views >= min_views
    X = np.full((uv.shape[1], 3), np.nan)
    if np.any(enough):
        m = mask[:, enough]
        Xe = _linear(P, uv[:, enough], m)
        if method == "optimal":
            Xe = _optimal(P, uv[:, enough], m, Xe)
        X[enough] = Xe
    err = np.full((uv.shape[1], V), np.nan)
    for i in range(V):
        with np.errstate(divide="ignore", invalid="ignore"):
            proj = _project(np.broadcast_to(P[i], (len(X), 3, 4)), X)
        err[:, i] = np.linalg.norm(proj - uv[i], axis=1)
    err[~mask.T] = np.nan
    return Triangulation(
        points=X.reshape(*lead, 3),
        reprojection_error=err.reshape(*lead, V),
        n_views=n_views.reshape(lead),
        method=method,
    )
