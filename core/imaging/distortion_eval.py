"""How good is a distortion model: residuals, bead-lattice errors, cross-validation (thesis §3.5.2–3).

* :func:`residual_stats` / :func:`residual_table` — the detected grid points warped to their
  corrected positions (:meth:`DistortionModel.inverse`) against the ideal grid: mean, RMS, SD,
  max and min of the distances (thesis Table 3.1), in pixels and millimetres.
* :func:`lattice_errors` / :func:`evaluate_lattice` — an independent bead lattice corrected by the
  model: errors of the inter-marker distances along lattice rows and columns against their
  nominal values (k × pitch, Table 3.2) and of the 90° angles between lattice vectors
  (Table 3.3). Angles are kept in radians; ``to_dict`` reports degrees.
* :func:`cross_validate` / :func:`select_model` — K-fold cross-validation on held-out grid points:
  a model is chosen by how well it predicts points it was not fitted to, not by its residual
  (which only falls with the order and rewards over-fitting, thesis (20,20)). On large grids
  (tens of thousands of points) the thin-plate spline is fitted to an even subsample of each
  fold's training points (its table row says so); the other models use every point.
* :func:`condition_sweep` — rank, condition number and residual of polynomial models over a range
  of orders, with and without Hartley normalisation (thesis Fig. 3.11).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .._validate import as_points, positive
from .distortion_models import DistortionModel, ModelSpec, fit_distortion
from .pointmaps import fit_polynomial_map
from .polybasis import polynomial_terms

__all__ = [
    "AUTO_MODELS",
    "LatticeErrors",
    "ResidualStats",
    "condition_sweep",
    "cross_validate",
    "evaluate_lattice",
    "lattice_errors",
    "residual_stats",
    "residual_table",
    "select_model",
]


@dataclass(frozen=True)
class ResidualStats:
    """Distances between corrected and ideal grid points (pixels; ``mm_per_px`` converts)."""

    n: int
    mean: float
    rms: float
    sd: float
    max: float
    min: float
    mm_per_px: float | None = None

    @classmethod
    def of(cls, d: np.ndarray, mm_per_px: float | None = None) -> ResidualStats:
        d = np.asarray(d, float)
        sd = float(d.std(ddof=1)) if d.size > 1 else 0.0
        return cls(int(d.size), float(d.mean()), float(np.sqrt(np.mean(d**2))), sd, float(d.max()),
                   float(d.min()), mm_per_px)

    def to_dict(self) -> dict:
        keys = ("mean", "rms", "sd", "max", "min")
        out: dict = {"n": self.n, "px": {k: getattr(self, k) for k in keys}}
        if self.mm_per_px is not None:
            out["mm"] = {k: getattr(self, k) * self.mm_per_px for k in keys}
        return out


def residual_stats(model: DistortionModel, distorted_uv, ideal_uv, *,
                   mm_per_px: float | None = None) -> ResidualStats:
    """Table 3.1 statistics of ``|model.inverse(distorted_uv) - ideal_uv|``."""
    q, _ = as_points(distorted_uv, "distorted_uv", 2)
    p, _ = as_points(ideal_uv, "ideal_uv", 2)
    if len(p) != len(q):
        raise ValueError(f"distorted_uv, ideal_uv: expected equal lengths, got {len(q)} and {len(p)}")
    scale = model.mm_per_px if mm_per_px is None else mm_per_px
    return ResidualStats.of(np.linalg.norm(model.inverse(q) - p, axis=1), scale)


def residual_table(models: Sequence[DistortionModel], distorted_uv, ideal_uv, *,
                   mm_per_px: float | None = None) -> list[dict]:
    """One Table 3.1 row per model: label, parameters, rank, condition, residuals (px and mm)."""
    rows = []
    for m in models:
        st = residual_stats(m, distorted_uv, ideal_uv, mm_per_px=mm_per_px)
        rows.append({"model": m.label, "n_params": m.n_params, "rank": m.rank, "condition": m.condition,
                     **st.to_dict()})
    return rows


# ---------------------------------------------------------------------------- bead lattice
@dataclass(frozen=True, eq=False)
class LatticeErrors:
    """Inter-marker distance (mm) and right-angle (rad) errors of a corrected bead lattice."""

    distance_error_mm: np.ndarray
    nominal_mm: np.ndarray
    angle_error_rad: np.ndarray

    @staticmethod
    def _stats(e: np.ndarray) -> dict:
        if e.size == 0:
            return {"n": 0, "rms": float("nan"), "mean": float("nan"), "sd": float("nan")}
        return {"n": int(e.size), "rms": float(np.sqrt(np.mean(e**2))), "mean": float(e.mean()),
                "sd": float(e.std(ddof=1)) if e.size > 1 else 0.0, "max_abs": float(np.abs(e).max())}

    @property
    def distance_rms_mm(self) -> float:
        return float(np.sqrt(np.mean(self.distance_error_mm**2)))

    @property
    def angle_rms_rad(self) -> float:
        return float(np.sqrt(np.mean(self.angle_error_rad**2)))

    def to_dict(self) -> dict:
        """Table 3.2 (distances, mm) and Table 3.3 (angles, degrees) statistics."""
        return {"distance_mm": self._stats(self.distance_error_mm),
                "angle_deg": self._stats(np.degrees(self.angle_error_rad))}

    @classmethod
    def concatenate(cls, parts: Sequence[LatticeErrors]) -> LatticeErrors:
        return cls(np.concatenate([p.distance_error_mm for p in parts]),
                   np.concatenate([p.nominal_mm for p in parts]),
                   np.concatenate([p.angle_error_rad for p in parts]))


def lattice_errors(corrected_uv, ij, *, pitch_mm: float, mm_per_px: float,
                   max_steps: int = 5) -> LatticeErrors:
    """Distance and angle errors of lattice points at corrected pixel positions.

    Distances: every pair in the same lattice row or column ``k = 1..max_steps`` cells apart
    (nominal ``k × pitch_mm``; thesis: 20–100 mm). Angles: at every point, the angle between the
    vectors to the points ``a`` cells along ``i`` and ``b`` cells along ``j`` (``a, b`` in
    ``1..max_steps``, either sign), nominally 90°.
    """
    uv, _ = as_points(corrected_uv, "corrected_uv", 2)
    ij = np.asarray(ij, int)
    if ij.shape != uv.shape:
        raise ValueError(f"ij: expected shape {uv.shape}, got {ij.shape}")
    pitch, s = positive(pitch_mm, "pitch_mm"), positive(mm_per_px, "mm_per_px")
    xy = uv * s
    pos = {tuple(c): k for k, c in enumerate(ij)}
    dist, nom, ang = [], [], []
    for (i, j), a in pos.items():
        for k in range(1, int(max_steps) + 1):
            for d in ((k, 0), (0, k)):
                b = pos.get((i + d[0], j + d[1]))
                if b is not None:
                    dist.append(np.linalg.norm(xy[b] - xy[a]) - k * pitch)
                    nom.append(k * pitch)
        for si in (-1, 1):
            for sj in (-1, 1):
                for ka in range(1, int(max_steps) + 1):
                    pa = pos.get((i + si * ka, j))
                    if pa is None:
                        continue
                    for kb in range(1, int(max_steps) + 1):
                        pb = pos.get((i, j + sj * kb))
                        if pb is None:
                            continue
                        va, vb = xy[pa] - xy[a], xy[pb] - xy[a]
                        c = np.dot(va, vb) / (np.linalg.norm(va) * np.linalg.norm(vb))
                        ang.append(np.arccos(np.clip(c, -1, 1)) - np.pi / 2)
    return LatticeErrors(np.asarray(dist), np.asarray(nom), np.asarray(ang))


def evaluate_lattice(model: DistortionModel, lattices: Sequence[tuple], *, pitch_mm: float,
                     mm_per_px: float | None = None, max_steps: int = 5) -> LatticeErrors:
    """Correct one or more bead-lattice images' points with ``model`` and pool their errors.

    ``lattices`` is a sequence of ``(distorted_uv (n, 2), ij (n, 2))`` — e.g. the lattice imaged
    at several places on the intensifier (thesis §3.5.2).
    """
    s = model.mm_per_px if mm_per_px is None else mm_per_px
    if s is None:
        raise ValueError("mm_per_px: the model has no scale; pass mm_per_px")
    parts = [lattice_errors(model.inverse(uv), ij, pitch_mm=pitch_mm, mm_per_px=s, max_steps=max_steps)
             for uv, ij in lattices]
    return LatticeErrors.concatenate(parts)


# ---------------------------------------------------------------------------- model selection
#: Candidate models of the automatic choice (:func:`select_model`; ``model="auto"``).
AUTO_MODELS = ("poly(4,4)", "poly(5,5)", "poly(6,6)", "poly(7,7)", "poly(8,8)", "lwm(12)", "tps")


def cross_validate(ideal_uv, distorted_uv, models: Sequence[str | ModelSpec], *, folds: int = 5,
                   seed: int = 0, mm_per_px: float | None = None,
                   max_points: int | None = None) -> list[dict]:
    """K-fold cross-validation of model specs on grid points.

    Each fold's held-out points are corrected by a model fitted to the others; the table gives
    per model the RMS and mean held-out error (px, and mm when ``mm_per_px`` is given), the
    training points per fold (``n_train``), the points the model was fitted to (``n_fit``:
    fewer for a thin-plate spline on a large grid, see :mod:`distortion_models`; then ``note``
    says so) and the time taken (``seconds``). A spec that cannot be fitted on a fold (too few
    points) gets ``inf`` and the reason. ``max_points`` is passed to
    :func:`~core.imaging.distortion_models.fit_distortion` (default: its per-model cap).
    """
    p, _ = as_points(ideal_uv, "ideal_uv", 2)
    q, _ = as_points(distorted_uv, "distorted_uv", 2)
    if len(p) != len(q):
        raise ValueError(f"ideal_uv, distorted_uv: expected equal lengths, got {len(p)} and {len(q)}")
    if int(folds) != folds or not 2 <= folds <= len(p):
        raise ValueError(f"folds: expected an integer in 2..{len(p)}, got {folds!r}")
    order = np.random.default_rng(seed).permutation(len(p))
    parts = np.array_split(order, int(folds))
    rows = []
    for m in models:
        spec = ModelSpec.parse(m)
        err, why, n_fit = [], None, []
        n_train = len(p) - min(len(t) for t in parts)
        t0 = time.perf_counter()
        for k, test in enumerate(parts):
            train = np.setdiff1d(order, test)
            try:
                mod = fit_distortion(p[train], q[train], spec, max_points=max_points, seed=seed + k)
            except ValueError as exc:
                why = str(exc)
                break
            n_fit.append(mod.n_fit or len(train))
            err.append(np.linalg.norm(mod.inverse(q[test]) - p[test], axis=1))
        if why is not None:
            rows.append({"model": spec.label, "rms_px": float("inf"), "mean_px": float("inf"), "error": why,
                         "n_train": n_train})
            continue
        e = np.concatenate(err)
        row = {"model": spec.label, "rms_px": float(np.sqrt(np.mean(e**2))), "mean_px": float(e.mean())}
        if mm_per_px is not None:
            row["rms_mm"], row["mean_mm"] = row["rms_px"] * mm_per_px, row["mean_px"] * mm_per_px
        row.update(n_train=n_train, n_fit=int(max(n_fit)), seconds=time.perf_counter() - t0)
        if max(n_fit) < n_train:
            row["note"] = (f"fitted to an even subsample of {max(n_fit)} of the (up to) {n_train} "
                           f"training points of each fold (size cap of this model)")
        rows.append(row)
    return rows


def select_model(ideal_uv, distorted_uv, models: Sequence[str | ModelSpec] = AUTO_MODELS, *,
                 folds: int = 5, seed: int = 0, mm_per_px: float | None = None,
                 max_points: int | None = None) -> tuple[ModelSpec, list[dict]]:
    """The spec with the lowest cross-validated RMS error, and the whole table.

    The default candidates are :data:`AUTO_MODELS`; the chosen row has ``"chosen": True``. On
    large grids the thin-plate spline is fitted to a subsample (the row's ``note`` says so, and
    :func:`~core.imaging.distortion_models.fit_distortion` does the same for the final fit).
    """
    rows = cross_validate(ideal_uv, distorted_uv, models, folds=folds, seed=seed, mm_per_px=mm_per_px,
                          max_points=max_points)
    best = min(range(len(rows)), key=lambda k: rows[k]["rms_px"])
    if not np.isfinite(rows[best]["rms_px"]):
        raise ValueError("models: none of the candidate models could be fitted to these points")
    rows[best]["chosen"] = True
    return ModelSpec.parse(models[best]), rows


def condition_sweep(ideal_uv, distorted_uv, orders: Sequence[int] = tuple(range(2, 21)), *,
                    bases: Sequence[str] = ("power",), normalise: Sequence[bool] = (True, False),
                    terms: str | None = None) -> list[dict]:
    """Rank, condition number and forward residual of ``(n, n)`` polynomials (thesis Fig. 3.11).

    The forward map (ideal → distorted, eq. 3.3) is fitted for each order, basis and
    normalisation; ``mean_residual_px`` is the mean ``|forward(ideal) - distorted|``. Orders with
    more terms than points are listed with ``"error"`` and no numbers. Normalisation applies to
    the power basis (the other bases are always normalised).
    """
    p, _ = as_points(ideal_uv, "ideal_uv", 2)
    q, _ = as_points(distorted_uv, "distorted_uv", 2)
    rows = []
    for basis in bases:
        for norm in normalise if basis == "power" else (True,):
            for n in orders:
                t = terms or ("tensor" if basis == "bernstein" else "total")
                row = {"order": int(n), "basis": basis, "normalise": bool(norm), "terms": t,
                       "n_terms": len(polynomial_terms((n, n), t)), "n_points": len(p)}
                try:
                    m = fit_polynomial_map(p, q, (n, n), basis=basis, terms=t, normalise=norm)
                except ValueError as exc:
                    row["error"] = str(exc)
                    rows.append(row)
                    continue
                with np.errstate(all="ignore"):
                    r = np.linalg.norm(m(p) - q, axis=1)
                row.update(rank=m.rank, condition=m.condition, mean_residual_px=float(np.mean(r)),
                           rms_residual_px=float(np.sqrt(np.mean(r**2))))
                rows.append(row)
    return rows
