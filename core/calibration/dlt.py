"""Direct linear transformation: one camera from >= 6 known 3-D points (thesis §5.1).

:func:`calibrate_dlt` is the static, single-frame calibration (and the initial guess of bundle
adjustment): the Hartley-normalised 11-parameter DLT of
:func:`core.geometry.dlt_from_correspondences`, decomposed (RQ, equivalent to Melen's method)
into ``K, R, t`` by :func:`core.geometry.camera_from_P`. Degenerate input never produces a
camera: the result has ``ok=False`` and a ``reason`` (fewer than 6 points, coplanar or collinear
points, a view with no detections, a rank-deficient system, points behind the source, a skewed
or mirrored decomposition).

:func:`dlt_batch` and :func:`camera_parameters` do the same for thousands of perturbed point sets
at once (sensitivity analysis): normalised DLT by batched SVD, and the decomposition of ``P``
through ``M Mᵀ = K Kᵀ`` (an "upper" Cholesky factor) instead of one RQ per sample.

Pixels are ``(u, v) = (column, row)``, origin at the centre of the top-left pixel; points in mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_float_array
from ..geometry.camera import Camera
from ..geometry.conversions import camera_from_P, dlt_from_correspondences

__all__ = ["DLTCalibration", "calibrate_dlt", "camera_parameters", "dlt_batch", "planarity"]


@dataclass(frozen=True, eq=False)
class DLTCalibration:
    """Result of :func:`calibrate_dlt`.

    Attributes
    ----------
    ok : bool
        False when no trustworthy camera could be computed; ``camera`` is then None.
    reason : str
        Why it failed ("" when ``ok``).
    camera : Camera or None
        Zero-skew camera (the DLT's small skew is dropped, see ``skew_shift_px``).
    P : (3, 4) array or None
        The DLT projection matrix (Talus pixels), ``P = K [R | t]`` with ``K[2, 2] = 1``.
    coefficients : (11,) array or None
        ``L1..L11`` in Talus pixels.
    residuals : (N,) array
        Reprojection distance (px) of every input point under ``camera`` (NaN for points not
        used: missing observations, or all when failed).
    n_points : int
        Correspondences used.
    skew_shift_px : float
        Largest image shift caused by dropping the skew (px).
    planarity : float
        Smallest over largest singular value of the centred points (0 = coplanar).
    """

    ok: bool
    reason: str
    camera: Camera | None
    P: np.ndarray | None
    coefficients: np.ndarray | None
    residuals: np.ndarray
    n_points: int
    skew_shift_px: float = float("nan")
    planarity: float = float("nan")

    @property
    def rms_px(self) -> float:
        """Root-mean-square reprojection distance of the used points (px); NaN when failed."""
        r = self.residuals[np.isfinite(self.residuals)]
        return float(np.sqrt(np.mean(r**2))) if r.size else float("nan")


def planarity(points) -> float:
    """Smallest / largest singular value of the centred ``(N, 3)`` points (0: coplanar)."""
    X = as_float_array(points, "points", shape=(None, 3))
    if len(X) < 3:
        return 0.0
    sv = np.linalg.svd(X - X.mean(axis=0), compute_uv=False)
    return float(sv[2] / sv[0]) if sv[0] > 0 else 0.0


def _fail(reason: str, n_total: int, n_used: int, plan: float = float("nan")) -> DLTCalibration:
    return DLTCalibration(False, reason, None, None, None, np.full(n_total, np.nan), n_used,
                          planarity=plan)


def calibrate_dlt(points, uv, *, width: int, height: int, pixel_size: float | None = None,
                  name: str = "", min_points: int = 6, min_planarity: float = 0.02,
                  max_skew_px: float = 0.5) -> DLTCalibration:
    """Calibrate one camera from known object points and their image positions (11-term DLT).

    Parameters
    ----------
    points : (N, 3) array
        Bead centres in the object (lab) frame, mm.
    uv : (N, 2) array
        Their image positions ``(u, v) = (column, row)`` px, origin at the centre of the
        top-left pixel; a NaN row is a bead not seen (skipped).
    width, height : int
        Image size in pixels.
    pixel_size : float, optional
        Detector pixel pitch (mm), stored in the camera (gives the SID).
    name : str
        Camera label.
    min_points : int
        Fewest correspondences accepted (>= 6, the 11-parameter minimum).
    min_planarity : float
        Smallest accepted ratio of the points' smallest to largest spread (singular values of the
        centred points): near-coplanar points give a wildly unstable DLT.
    max_skew_px : float
        Largest tolerated image shift caused by dropping the DLT's skew (px).

    Returns
    -------
    DLTCalibration
        ``ok=False`` with a ``reason`` for every degenerate configuration; never raises on bad
        geometry (only on malformed arguments).
    """
    X = as_float_array(points, "points", shape=(None, 3))
    x = as_float_array(uv, "uv", shape=(len(X), 2), finite=False)
    if int(min_points) != min_points or min_points < 6:
        raise ValueError(f"min_points: expected an integer >= 6, got {min_points!r}")
    if not (0 <= min_planarity < 1):
        raise ValueError(f"min_planarity: expected a ratio in [0, 1), got {min_planarity!r}")
    n = len(X)
    seen = np.all(np.isfinite(x), axis=1)
    m = int(seen.sum())
    if m == 0:
        return _fail("no detections in this view", n, 0)
    if m < min_points:
        return _fail(f"only {m} point(s) observed, the 11-parameter DLT needs at least {min_points}", n, m)
    plan = planarity(X[seen])
    sv = np.linalg.svd(X[seen] - X[seen].mean(axis=0), compute_uv=False)
    if sv[1] <= 1e-6 * sv[0]:
        return _fail("the observed points lie on a line", n, m, plan)
    if plan < max(min_planarity, 1e-9):
        return _fail(f"the observed points are (nearly) coplanar (planarity {plan:.2g} < "
                     f"{min_planarity:g}); the DLT needs a non-planar object", n, m, plan)
    try:
        fit = dlt_from_correspondences(X[seen], x[seen])
    except ValueError as exc:
        return _fail(f"degenerate configuration: {exc}", n, m, plan)
    Xh = np.column_stack([X[seen], np.ones(m)])
    depth = Xh @ fit.P[2]
    if np.any(depth <= 0):
        return _fail("the solution puts observed points behind the source", n, m, plan)
    try:
        cam, shift = camera_from_P(fit.P, width, height, pixel_size=pixel_size, name=name,
                                   max_skew_px=max_skew_px, return_skew_shift=True)
    except ValueError as exc:
        return _fail(f"the DLT matrix is not a plausible camera: {exc}", n, m, plan)
    res = np.full(n, np.nan)
    res[seen] = np.linalg.norm(cam.project(X[seen]) - x[seen], axis=1)
    return DLTCalibration(True, "", cam, fit.P, fit.coefficients, res, m, shift, plan)


# ---------------------------------------------------------------------------- batched
def _normaliser(pts: np.ndarray) -> np.ndarray:
    """Hartley similarity per batch item: ``pts (B, N, d)`` -> ``T (B, d+1, d+1)``."""
    B, _, d = pts.shape
    c = pts.mean(axis=1)
    s = np.sqrt(d) / np.linalg.norm(pts - c[:, None], axis=2).mean(axis=1)
    T = np.zeros((B, d + 1, d + 1))
    T[:, np.arange(d), np.arange(d)] = s[:, None]
    T[:, :d, d] = -s[:, None] * c
    T[:, d, d] = 1.0
    return T


def _design(Xn: np.ndarray, xn: np.ndarray) -> np.ndarray:
    """The DLT's homogeneous system ``A p = 0``, ``(B, 2N, 12)``, of normalised object points
    ``Xn`` (homogeneous, ``(N, 4)`` shared or ``(B, N, 4)``) and image points ``xn (B, N, 2)``."""
    B, n = xn.shape[:2]
    A = np.zeros((B, 2 * n, 12))
    A[:, 0::2, 0:4] = Xn
    A[:, 0::2, 8:12] = -xn[:, :, :1] * Xn
    A[:, 1::2, 4:8] = Xn
    A[:, 1::2, 8:12] = -xn[:, :, 1:] * Xn
    return A


def dlt_batch(points, uv) -> np.ndarray:
    """Normalised DLT for many image point sets of the same object points.

    Parameters
    ----------
    points : (N, 3) array
        Object points, mm (N >= 6, non-coplanar).
    uv : (B, N, 2) array
        ``B`` sets of image positions (px, Talus convention), all finite.

    Returns
    -------
    P : (B, 3, 4) array
        Projection matrices scaled to ``||P[2, :3]|| = 1`` with positive depth of the points.
    """
    X = as_float_array(points, "points", shape=(None, 3))
    x = as_float_array(uv, "uv", ndim=3)
    n = len(X)
    if x.shape[1:] != (n, 2):
        raise ValueError(f"uv: expected shape (B, {n}, 2), got {x.shape}")
    if n < 6:
        raise ValueError(f"points: expected at least 6 points, got {n}")
    B = len(x)
    T3 = _normaliser(X[None])[0]
    Xn = np.column_stack([X, np.ones(n)]) @ T3.T
    T2 = _normaliser(x)
    xn = np.einsum("bij,bnj->bni", T2[:, :2, :2], x) + T2[:, None, :2, 2]
    A = _design(Xn, xn)
    _, _, Vt = np.linalg.svd(A, full_matrices=False)
    Pn = Vt[:, -1].reshape(B, 3, 4)
    P = np.linalg.solve(T2, Pn) @ T3
    depth = np.einsum("bj,nj->bn", P[:, 2], np.column_stack([X, np.ones(n)]))
    sgn = np.sign(np.median(depth, axis=1))
    return P * (sgn / np.linalg.norm(P[:, 2, :3], axis=1))[:, None, None]


def camera_parameters(P) -> dict[str, np.ndarray]:
    """Physical parameters of many projection matrices ``P (B, 3, 4)``.

    Decomposes ``M = P[:, :3] = K R`` via ``M Mᵀ = K Kᵀ`` (K upper triangular, positive
    diagonal: the Cholesky factor of the index-reversed matrix) for all items at once.

    Returns
    -------
    dict
        ``fx, fy, f`` (mean of the two), ``cu, cv``, ``skew`` (px), ``R (B, 3, 3)``,
        ``t (B, 3)`` mm and ``source (B, 3)`` mm (``C = -Rᵀ t``).
    """
    P = as_float_array(P, "P")
    if P.ndim == 2:
        P = P[None]
    if P.ndim != 3 or P.shape[1:] != (3, 4):
        raise ValueError(f"P: expected shape (B, 3, 4), got {np.shape(P)}")
    P = P * np.sign(np.linalg.det(P[:, :, :3]))[:, None, None]
    M = P[:, :, :3]
    A = M @ np.swapaxes(M, 1, 2)
    J = np.eye(3)[::-1]
    L = np.linalg.cholesky(J @ A @ J)
    K = J @ L @ J
    Kinv = np.linalg.inv(K)
    R = Kinv @ M
    t = np.einsum("bij,bj->bi", Kinv, P[:, :, 3])
    K = K / K[:, 2:3, 2:3]
    source = -np.einsum("bji,bj->bi", R, t)
    return {"fx": K[:, 0, 0], "fy": K[:, 1, 1], "f": 0.5 * (K[:, 0, 0] + K[:, 1, 1]),
            "cu": K[:, 0, 2], "cv": K[:, 1, 2], "skew": K[:, 0, 1], "R": R, "t": t, "source": source}
