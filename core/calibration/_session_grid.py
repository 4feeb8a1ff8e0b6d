"""Distortion of one view from several grid frames (private to :mod:`core.calibration.session`).

Each grid frame is detected and indexed (:mod:`core.imaging.grid_detection`,
:mod:`core.imaging.grid_indexing`); frames of the same placement (the grid left where it was)
are merged by averaging each hole's position, so that the fit sees every hole once.

The ideal grid of a placement is a similarity of its lattice, ``c + a (i + i j)`` (complex
notation). Its scale, rotation and position are first fitted to the central cells
(:func:`core.imaging.distortion.ideal_grid`), then refined with the fitted model: each
placement's similarity is re-fitted to all its holes corrected by the model, and all ideal
grids are re-scaled and turned so that the model's Jacobian at the reference centre is the
identity (the corrected image has the raw image's pixel size and orientation at the centre).
A few rounds converge. This keeps the corrected pixel size independent of how large the central
region is (a pincushion magnifies the central cells by ~0.1 %, which would go straight into the
focal length).

Pixels are ``(u, v) = (column, row)``, origin at the centre of the top-left pixel; mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..imaging.distortion import ideal_grid
from ..imaging.distortion_eval import AUTO_MODELS, ResidualStats, residual_stats, select_model
from ..imaging.distortion_models import TPS_MAX_POINTS, DistortionModel, ModelSpec, fit_distortion
from ..imaging.grid_detection import detect_grid_points
from ..imaging.grid_indexing import index_grid


class GridFrameError(ValueError):
    """A grid frame in which no grid could be found (``frame`` is its index)."""

    def __init__(self, frame: int, message: str):
        super().__init__(message)
        self.frame = frame


@dataclass(frozen=True, eq=False)
class Placement:
    """Holes of one grid placement: lattice indices, detected (distorted) positions, the frames."""

    ij: np.ndarray
    distorted_uv: np.ndarray
    frames: tuple[int, ...]
    sim: complex  # ideal = origin + sim * (i + 1j j)
    origin: complex

    def ideal(self) -> np.ndarray:
        z = self.origin + self.sim * (self.ij[:, 0] + 1j * self.ij[:, 1])
        return np.column_stack([z.real, z.imag])


@dataclass(frozen=True, eq=False)
class GridFit:
    """The distortion of one view: model, table of candidates, residuals, the points used."""

    model: DistortionModel
    spec: ModelSpec
    table: list
    residuals: ResidualStats
    ideal_uv: np.ndarray
    distorted_uv: np.ndarray
    placement: np.ndarray  # (n,) index of the placement of each point
    n_frames: int
    n_placements: int
    mm_per_px: float
    notes: list


def detect_frame(image: np.ndarray, k: int, *, pitch_mm: float, feature_px: float, center) -> Placement:
    """Detect and index one (flatfield-corrected) grid frame; :class:`GridFrameError` if no grid."""
    try:
        pts = detect_grid_points(image, feature_diameter_px=feature_px, polarity="auto")
        idx = index_grid(pts.uv, origin_uv=center, min_points=25)
        g = ideal_grid(idx, pitch_mm=pitch_mm, center_uv=center)
    except ValueError as exc:
        raise GridFrameError(k, f"no distortion grid found ({exc})") from None
    a = g.step_px * np.exp(1j * g.angle_rad)
    return Placement(g.ij, g.distorted_uv, (k,), complex(a), complex(g.origin_uv[0] + 1j * g.origin_uv[1]))


def merge_placements(frames: list[Placement], *, tol_px: float = 1.0) -> list[Placement]:
    """Group frames of the same placement (ideal positions within ``tol_px``) and average them."""
    groups: list[list[Placement]] = []
    trees: list[cKDTree] = []
    for p in frames:
        zp = p.ideal()
        for grp, tree in zip(groups, trees, strict=True):
            if np.median(tree.query(zp)[0]) < tol_px:  # p's holes land on q's: same placement
                grp.append(p)
                break
        else:
            groups.append([p])
            trees.append(cKDTree(zp))
    out = []
    for grp, tree in zip(groups, trees, strict=True):
        ref = grp[0]
        acc = {tuple(c): [uv] for c, uv in zip(ref.ij, ref.distorted_uv, strict=True)}
        for p in grp[1:]:
            d, k = tree.query(p.ideal())
            for n, (dd, kk) in enumerate(zip(d, k, strict=True)):
                if dd < 0.25 * abs(ref.sim):
                    acc[tuple(ref.ij[kk])].append(p.distorted_uv[n])
        ij = np.array(list(acc.keys()), int)
        uv = np.array([np.mean(v, axis=0) for v in acc.values()])
        out.append(Placement(ij, uv, tuple(f for p in grp for f in p.frames), ref.sim, ref.origin))
    return out


def _similarity(ij: np.ndarray, uv: np.ndarray) -> tuple[complex, complex]:
    w = ij[:, 0] + 1j * ij[:, 1]
    z = uv[:, 0] + 1j * uv[:, 1]
    A = np.column_stack([w, np.ones_like(w)])
    a, b = np.linalg.lstsq(A, z, rcond=None)[0]
    return complex(a), complex(b)


def _jacobian_similarity(model: DistortionModel, c: np.ndarray, h: float = 2.0) -> complex:
    """The similarity part ``s e^{iθ}`` of the forward map's Jacobian at ``c``."""
    e1, e2 = np.array([h, 0.0]), np.array([0.0, h])
    pts = np.array([c + e1, c - e1, c + e2, c - e2])
    f = model.forward(pts)
    du = (f[0] - f[1]) / (2 * h)
    dv = (f[2] - f[3]) / (2 * h)
    # J = [[a, -b], [b, a]] closest: a = (J00 + J11)/2, b = (J10 - J01)/2
    a = 0.5 * (du[0] + dv[1])
    b = 0.5 * (du[1] - dv[0])
    return complex(a, b)


def fit_view(placements: list[Placement], *, model: str | ModelSpec, pitch_mm: float, center,
             n_frames: int, rounds: int = 3, folds: int = 5, seed: int = 0) -> GridFit:
    """Choose (``model="auto"``) and fit the distortion model of one view (module docs)."""
    c = np.asarray(center, float)
    rng = np.random.default_rng(seed)
    notes: list[str] = []
    pl = list(placements)

    def pooled():
        ideal = np.concatenate([p.ideal() for p in pl])
        dist = np.concatenate([p.distorted_uv for p in pl])
        lab = np.concatenate([np.full(len(p.ij), k) for k, p in enumerate(pl)])
        return ideal, dist, lab

    mm_per_px = pitch_mm / abs(pl[0].sim)
    # a mid-order polynomial refines the ideal grids; the chosen model is fitted to the result
    ref_spec = ModelSpec.parse("poly(6,6)")
    n_in = sum(len(p.ij) for p in pl)
    for _ in range(int(rounds)):
        ideal, dist, _ = pooled()
        m = fit_distortion(ideal, dist, ref_spec if len(ideal) >= 60 else "poly(3,3)", mm_per_px=mm_per_px)
        new = []
        for p in pl:
            # holes far off the smooth map (a hole cut by the field's rim, a merged or stray
            # detection) would pull every model: drop those beyond 5 robust sigma
            r = np.linalg.norm(m.inverse(p.distorted_uv) - p.ideal(), axis=1)
            keep = r <= max(5.0 * np.median(r) / 1.1774, 0.05)
            a, b = _similarity(p.ij[keep], m.inverse(p.distorted_uv[keep]))
            new.append(Placement(p.ij[keep], p.distorted_uv[keep], p.frames, a, b))
        pl = new
        J = _jacobian_similarity(m, c)  # forward Jacobian; ideal' = c + J (ideal - c)
        cz = complex(c[0], c[1])
        pl = [Placement(p.ij, p.distorted_uv, p.frames, J * p.sim, cz + J * (p.origin - cz)) for p in pl]
        mm_per_px = pitch_mm / abs(pl[0].sim)
    ideal, dist, lab = pooled()
    if len(ideal) < n_in:
        notes.append(f"{n_in - len(ideal)} of {n_in} grid points left out: farther than 5 robust "
                     "standard deviations from the smooth correction")
    table: list = []
    if isinstance(model, str) and model == "auto":
        sub = np.arange(len(ideal))
        if len(ideal) > TPS_MAX_POINTS:
            # every candidate is cross-validated on one subsample (the spline's cost grows as n²)
            sub = np.sort(rng.choice(len(ideal), TPS_MAX_POINTS, replace=False))
            notes.append(f"cross-validation on {TPS_MAX_POINTS} of {len(ideal)} grid points (a random "
                         "subsample; the thin-plate spline is fitted to an even subsample of as many)")
        try:
            spec, table = select_model(ideal[sub], dist[sub], AUTO_MODELS, folds=folds, seed=seed,
                                       mm_per_px=mm_per_px)
        except ValueError:
            raise ValueError("no candidate distortion model could be fitted to the grid points") from None
    else:
        spec = ModelSpec.parse(model)
    try:
        fitted = fit_distortion(ideal, dist, spec, mm_per_px=mm_per_px, seed=seed)
    except ValueError as exc:
        raise ValueError(f"model {spec.label}: cannot be fitted to {len(ideal)} grid points "
                         f"({exc})") from None
    if fitted.n_fit is not None:
        notes.append(f"{spec.label} fitted to an even subsample of {fitted.n_fit} of {len(ideal)} grid "
                     "points")
    res = residual_stats(fitted, dist, ideal, mm_per_px=mm_per_px)
    return GridFit(fitted, spec, table, res, ideal, dist, lab, n_frames, len(pl), mm_per_px, notes)
