"""Reprojection and 3-D reconstruction error of a calibrated rig (thesis §5.2.2).

* :func:`capture_lattice`: a lattice (default 10 mm) filling the intersection of the X-ray cones
  of all cameras (points in front of every source whose projection falls inside every image).
* :func:`reconstruction_errors`: project lattice points with the true rig, optionally add image
  noise, triangulate them with each estimated rig; the distance to the true point is the
  reconstruction error. Over many noise draws (calibrations), :class:`ErrorMap` keeps the mean and
  maximum per lattice point (Figs. 5.6-5.7).
* :func:`object_reconstruction`: the 3-D error on an independent object: its beads triangulated
  from observed image points, compared with the object geometry after a rigid fit, and the error
  of every inter-bead distance.

Pixels are ``(u, v) = (column, row)``, origin at the centre of the top-left pixel; mm.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .._validate import as_float_array, positive
from ..geometry.camera import Rig
from ..geometry.triangulate import triangulate
from ..markers.pose import rigid_fit

__all__ = ["ErrorMap", "ObjectReconstruction", "capture_lattice", "error_map", "object_reconstruction",
           "reconstruction_errors"]


def capture_lattice(rig: Rig, *, spacing_mm: float = 10.0, margin_px: float = 0.0,
                    bounds=None) -> np.ndarray:
    """``(N, 3)`` lattice points (mm) inside the intersection of every camera's X-ray cone.

    A point belongs to a cone when it lies between the source and the detector (depth in
    ``(0, SID)`` when the pixel size is known) and projects inside the image, ``margin_px`` from
    the border. ``bounds = (lo (3,), hi (3,))`` limits the search box (default: the box spanned by
    the detector corners and the sources, which contains the intersection).
    """
    if not isinstance(rig, Rig):
        raise ValueError(f"rig: expected a Rig, got {type(rig).__name__}")
    step = positive(spacing_mm, "spacing_mm")
    if bounds is None:
        pts = []
        for c in rig:
            far = c.sid if c.pixel_size is not None else 2.0 * np.linalg.norm(c.source)
            pts += [c.source, *c.detector_corners(distance=far)]
        pts = np.asarray(pts)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
    else:
        lo = as_float_array(bounds[0], "bounds[0]", shape=(3,))
        hi = as_float_array(bounds[1], "bounds[1]", shape=(3,))
    axes = [np.arange(np.floor(a / step) * step, b + step / 2, step) for a, b in zip(lo, hi, strict=True)]
    if np.prod([len(a) for a in axes]) > 5e7:
        raise ValueError(f"spacing_mm: {step} mm over the box {lo} - {hi} gives too many points")
    keep = None
    # the x-slices one at a time keep memory small
    out = []
    for x in axes[0]:
        g = np.stack(np.meshgrid([x], axes[1], axes[2], indexing="ij"), -1).reshape(-1, 3)
        keep = np.ones(len(g), bool)
        for c in rig:
            uv, z = c.project(g, return_depth=True)
            far = c.sid if c.pixel_size is not None else np.inf
            keep &= (z > 0) & (z < far)
            keep &= np.all(uv >= margin_px - 0.5, axis=1)
            keep &= np.all(uv <= np.array([c.width, c.height]) - 0.5 - margin_px, axis=1)
        out.append(g[keep])
    return np.concatenate(out)


def reconstruction_errors(true_rig: Rig, estimated: Rig | Sequence[Rig], points, *,
                          image_noise_px: float = 0.0, rng=0) -> np.ndarray:
    """Reconstruction error (mm) of ``points`` for one or more estimated rigs.

    Parameters
    ----------
    true_rig : Rig
        Ground truth; projects the points.
    estimated : Rig or sequence of Rig
        Calibrated rigs (same lab frame) that triangulate them (linear, Hartley-normalised).
    points : (N, 3) array
        Lab points, mm.
    image_noise_px : float
        Gaussian noise (px per axis) added to every projection before triangulation (0: the
        error of the calibration alone).
    rng : int or Generator

    Returns
    -------
    (D, N) array
        Distance between reconstructed and true point for each of the ``D`` rigs, mm.
    """
    X = as_float_array(points, "points", shape=(None, 3))
    rigs = [estimated] if isinstance(estimated, Rig) else list(estimated)
    if not rigs or not all(isinstance(r, Rig) and len(r) == len(true_rig) for r in rigs):
        raise ValueError(f"estimated: expected Rig objects of {len(true_rig)} cameras")
    g = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    uv = true_rig.project(X)
    out = np.empty((len(rigs), len(X)))
    for d, r in enumerate(rigs):
        obs = uv + g.normal(0.0, image_noise_px, uv.shape) if image_noise_px > 0 else uv
        tri = triangulate(r, obs, method="linear")
        out[d] = np.linalg.norm(tri.points - X, axis=1)
    return out


@dataclass(frozen=True, eq=False)
class ErrorMap:
    """Reconstruction error over a lattice and over ``D`` calibrations (noise draws).

    ``points (N, 3)`` mm; ``errors (D, N)`` mm; ``mean``, ``max``, ``rms`` (N,) over the draws.
    """

    points: np.ndarray
    errors: np.ndarray

    @property
    def mean(self) -> np.ndarray:
        return self.errors.mean(axis=0)

    @property
    def max(self) -> np.ndarray:
        return self.errors.max(axis=0)

    @property
    def rms(self) -> np.ndarray:
        return np.sqrt(np.mean(self.errors**2, axis=0))

    def summary(self) -> dict:
        """Overall statistics (mm): RMS over all points and draws, mean/max of the per-point
        mean and max, the 95th percentile, and the number of points and draws."""
        e = self.errors
        return {"n_points": int(e.shape[1]), "n_draws": int(e.shape[0]),
                "rms_mm": float(np.sqrt(np.mean(e**2))), "mean_mm": float(e.mean()),
                "p95_mm": float(np.percentile(e, 95)), "max_mm": float(e.max()),
                "worst_point_mean_mm": float(self.mean.max()),
                "per_draw_rms_mm": [float(x) for x in np.sqrt(np.mean(e**2, axis=1))]}


def error_map(true_rig: Rig, estimated: Sequence[Rig], *, spacing_mm: float = 10.0,
              image_noise_px: float = 0.0, rng=0, points=None) -> ErrorMap:
    """:class:`ErrorMap` over :func:`capture_lattice` (or given ``points``) for the rigs
    ``estimated`` (one per noise draw)."""
    X = capture_lattice(true_rig, spacing_mm=spacing_mm) if points is None else as_float_array(
        points, "points", shape=(None, 3))
    return ErrorMap(X, reconstruction_errors(true_rig, estimated, X, image_noise_px=image_noise_px,
                                             rng=rng))


@dataclass(frozen=True, eq=False)
class ObjectReconstruction:
    """3-D error on an independent object (see :func:`object_reconstruction`).

    ``points (n, 3)`` triangulated (mm, NaN when seen in < 2 views); ``residuals (n,)`` distance
    to the object's geometry after the best rigid fit (mm); ``rms_mm``; ``distance_errors (k,)``
    reconstructed minus true inter-bead distances (mm) over all pairs; ``reprojection_px (n, V)``.
    """

    points: np.ndarray
    residuals: np.ndarray
    rms_mm: float
    distance_errors: np.ndarray
    reprojection_px: np.ndarray


def object_reconstruction(rig: Rig, model_points, uv) -> ObjectReconstruction:
    """Triangulate an independent object's beads and compare them with its known geometry.

    ``model_points (n, 3)`` mm in the object frame; ``uv (V, n, 2)`` px observed (NaN unseen).
    """
    M = as_float_array(model_points, "model_points", shape=(None, 3))
    tri = triangulate(rig, uv, method="optimal")
    fit = rigid_fit(M, tri.points)
    ok = np.all(np.isfinite(tri.points), axis=1)
    i, j = np.triu_indices(len(M), 1)
    keep = ok[i] & ok[j]
    d_est = np.linalg.norm(tri.points[i[keep]] - tri.points[j[keep]], axis=1)
    d_true = np.linalg.norm(M[i[keep]] - M[j[keep]], axis=1)
    return ObjectReconstruction(tri.points, fit.residuals, float(fit.rms), d_est - d_true,
                                tri.reprojection_error)
