"""Image-intensifier distortion models fitted to grid control points (thesis §3.5).

Directions (the same as :class:`core.synthetic.Distortion`)
------------------------------------------------------------
* :meth:`DistortionModel.forward` maps **ideal** (undistorted) pixel positions to **distorted**
  (observed) ones. It is the fitted, closed-form map: as in thesis eq. 3.3 the Vandermonde
  matrix is built on the ideal grid nodes and solved for the detected (noisy) positions, so the
  localisation noise sits in the dependent variable of the least-squares problem. It is also the
  map a dense remap needs (each output pixel looks up where it came from).
* :meth:`DistortionModel.inverse` maps distorted positions to ideal ones (the *correction*). A
  second map of the same family is fitted the other way round as a closed-form first guess,
  then (``refine=True``, default) a few Newton steps on ``forward(x) = q`` make it the exact
  inverse of :meth:`forward` to ~1e-9 px. :meth:`DistortionModel.round_trip_error` reports how far
  the closed-form guess alone is from that.

Pixels are ``(u, v) = (column, row)``, origin at the centre of the top-left pixel. The ideal
positions are in pixels too (see :func:`core.imaging.distortion.ideal_grid`); ``mm_per_px``
converts them to millimetres in the grid's plane.

A model is described by a :class:`ModelSpec` (``"poly(5,5)"``, ``"cheb(15,15)"``,
``"tps"``, ``"tps(0.01)"``, ``"lwm(12)"``) and serialises to plain JSON types.

Large grids
-----------
A polynomial or a local weighted mean is fitted to every point at any size (their cost grows
linearly with the points). A thin-plate spline is a dense ``(n + 3)²`` linear system and every
evaluation sums over all ``n`` centres, so it is fitted to at most :data:`TPS_MAX_POINTS`
points (2,000: ~1 s per map on a 2-core CPU): beyond that, to a spatially even subsample of the
ideal grid (:func:`even_subsample`, seeded). :attr:`DistortionModel.n_fit` records how many
points a model was fitted to and ``n_points`` how many were given.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from .._validate import as_points
from .pointmaps import (
    LocalWeightedMeanMap,
    PolynomialMap,
    ThinPlateSplineMap,
    fit_local_weighted_mean,
    fit_polynomial_map,
    fit_thin_plate_spline,
    map_from_dict,
)
from .polybasis import BASES, check_order

__all__ = ["TPS_MAX_POINTS", "DistortionModel", "ModelSpec", "even_subsample", "fit_distortion"]

_KINDS = ("polynomial", "tps", "lwm")
#: Largest number of control points a thin-plate spline is fitted to (see the module docs).
TPS_MAX_POINTS = 2000
_PREFIX = {"poly": "power", "cheb": "chebyshev", "bern": "bernstein"}


@dataclass(frozen=True)
class ModelSpec:
    """What to fit: a global polynomial, a thin-plate spline or a local weighted mean.

    Parameters
    ----------
    kind : {"polynomial", "tps", "lwm"}
    order : (nx, ny)
        Polynomial orders (``kind="polynomial"``).
    basis : {"power", "chebyshev", "bernstein"}
    terms : {"total", "tensor"} or None
        Polynomial term set (None: "total", "tensor" for Bernstein); see :mod:`polybasis`.
    normalise : bool
        Hartley normalisation of the inputs (power basis; thesis Fig. 3.11 compares both).
    smoothing : float
        Thin-plate spline smoothing (0 = interpolating).
    n_neighbours : int
        Points per local quadratic of the local weighted mean (MATLAB's N, default 12).
    """

    kind: str = "polynomial"
    order: tuple[int, int] = (8, 8)
    basis: str = "power"
    terms: str | None = None
    normalise: bool = True
    smoothing: float = 0.0
    n_neighbours: int = 12

    def __post_init__(self) -> None:
        if self.kind not in _KINDS:
            raise ValueError(f"kind: expected one of {_KINDS}, got {self.kind!r}")
        object.__setattr__(self, "order", check_order(self.order))
        if self.basis not in BASES:
            raise ValueError(f"basis: expected one of {BASES}, got {self.basis!r}")
        if self.terms not in (None, "total", "tensor"):
            raise ValueError(f"terms: expected 'total', 'tensor' or None, got {self.terms!r}")
        if not (np.isfinite(self.smoothing) and self.smoothing >= 0):
            raise ValueError(f"smoothing: expected a number >= 0, got {self.smoothing!r}")
        if int(self.n_neighbours) != self.n_neighbours or self.n_neighbours < 6:
            raise ValueError(f"n_neighbours: expected an integer >= 6, got {self.n_neighbours!r}")

    @classmethod
    def parse(cls, text: str | ModelSpec) -> ModelSpec:
        """Spec from a label: ``poly(5,5)``, ``poly8``, ``cheb(15,15)``, ``bern(6,6)``,
        ``poly(9,9)/raw`` (no normalisation), ``tps``, ``tps(0.01)``, ``lwm``, ``lwm(12)``."""
        if isinstance(text, ModelSpec):
            return text
        t = str(text).strip().lower().replace(" ", "")
        m = re.fullmatch(r"(poly|cheb|bern)\(?(\d+)(?:,(\d+))?\)?(/raw)?", t)
        if m:
            nx = int(m.group(2))
            ny = int(m.group(3)) if m.group(3) else nx
            return cls("polynomial", (nx, ny), _PREFIX[m.group(1)], normalise=m.group(4) is None)
        m = re.fullmatch(r"tps(?:\(([0-9.eE+-]+)\))?", t)
        if m:
            return cls("tps", smoothing=float(m.group(1) or 0.0))
        m = re.fullmatch(r"lwm(?:\((\d+)\))?", t)
        if m:
            return cls("lwm", n_neighbours=int(m.group(1) or 12))
        raise ValueError(f"model: cannot parse {text!r}; expected e.g. 'poly(5,5)', 'cheb(15,15)', "
                         f"'tps', 'tps(0.01)' or 'lwm(12)'")

    @property
    def label(self) -> str:
        """Short name, e.g. ``poly(5,5)``, ``cheb(15,15)``, ``poly(9,9)/raw``, ``tps``, ``lwm(12)``."""
        if self.kind == "polynomial":
            pre = {v: k for k, v in _PREFIX.items()}[self.basis]
            raw = "" if self.normalise or self.basis != "power" else "/raw"
            return f"{pre}({self.order[0]},{self.order[1]}){raw}"
        if self.kind == "tps":
            return "tps" if self.smoothing == 0 else f"tps({self.smoothing:g})"
        return f"lwm({self.n_neighbours})"

    def to_dict(self) -> dict:
        return {"kind": self.kind, "order": list(self.order), "basis": self.basis, "terms": self.terms,
                "normalise": self.normalise, "smoothing": self.smoothing,
                "n_neighbours": self.n_neighbours}

    @classmethod
    def from_dict(cls, d: dict) -> ModelSpec:
        return cls(d["kind"], tuple(d["order"]), d["basis"], d.get("terms"), bool(d["normalise"]),
                   float(d["smoothing"]), int(d["n_neighbours"]))

    def fit_map(self, src, dst):
        """Fit this spec's point map ``src → dst``."""
        if self.kind == "polynomial":
            return fit_polynomial_map(src, dst, self.order, basis=self.basis, terms=self.terms,
                                      normalise=self.normalise)
        if self.kind == "tps":
            return fit_thin_plate_spline(src, dst, smoothing=self.smoothing)
        return fit_local_weighted_mean(src, dst, n_neighbours=self.n_neighbours)


def _jacobian(fmap, x: np.ndarray, h: float = 0.25, fx: np.ndarray | None = None) -> np.ndarray:
    """``d fmap / d x`` at ``x``: analytic for polynomials; else finite differences of ``h`` px,
    one-sided from ``fx = fmap(x)`` when given (two evaluations instead of four: a spline or
    local map costs per evaluated point, and Newton needs only an approximate Jacobian — its
    error, ``h`` times the map's curvature, is ~1e-5 of it for intensifier distortion)."""
    if isinstance(fmap, PolynomialMap):
        return fmap.jacobian(x)
    J = np.empty((len(x), 2, 2))
    for k in range(2):
        e = np.zeros(2)
        e[k] = h
        if fx is None:
            J[:, :, k] = (fmap(x + e) - fmap(x - e)) / (2 * h)
        else:
            J[:, :, k] = (fmap(x + e) - fx) / h
    return J


@dataclass(frozen=True, eq=False)
class DistortionModel:
    """A fitted distortion: closed-form ``forward`` (ideal → distorted), refined ``inverse``.

    Attributes
    ----------
    spec : ModelSpec
    forward_map, inverse_map : point maps
        Fitted ideal → distorted and distorted → ideal maps (the latter is the Newton start).
    n_points : int
        Control points used in the fit.
    mm_per_px : float or None
        Size of one ideal pixel in the grid plane (mm), when known.
    refine : bool
        Newton-refine :meth:`inverse` to the exact inverse of :meth:`forward`.
    n_fit : int or None
        Control points the maps were fitted to, when fewer than ``n_points`` (a subsample,
        see the module docs); None = all of them.
    """

    spec: ModelSpec
    forward_map: PolynomialMap | ThinPlateSplineMap | LocalWeightedMeanMap
    inverse_map: PolynomialMap | ThinPlateSplineMap | LocalWeightedMeanMap
    n_points: int
    mm_per_px: float | None = None
    refine: bool = True
    n_fit: int | None = None

    @property
    def label(self) -> str:
        return self.spec.label

    @property
    def rank(self) -> int | None:
        """Rank of the forward Vandermonde matrix (polynomials), else None."""
        return self.forward_map.rank if isinstance(self.forward_map, PolynomialMap) else None

    @property
    def condition(self) -> float | None:
        """2-norm condition number of the forward Vandermonde matrix (polynomials), else None."""
        return self.forward_map.condition if isinstance(self.forward_map, PolynomialMap) else None

    @property
    def n_params(self) -> int:
        """Fitted numbers per output coordinate (terms, or control points + 3 for a TPS, ...)."""
        m = self.forward_map
        if isinstance(m, PolynomialMap):
            return m.n_terms
        if isinstance(m, ThinPlateSplineMap):
            return len(m.src) + 3
        return 6 * len(m.centers)

    def forward(self, uv_ideal) -> np.ndarray:
        """Distorted pixel positions ``(..., 2)`` of ideal positions ``(..., 2)``."""
        return self.forward_map(uv_ideal)

    def inverse(self, uv_distorted, *, iterations: int = 8, tol_px: float = 1e-9) -> np.ndarray:
        """Ideal (corrected) positions ``(..., 2)`` of distorted positions ``(..., 2)``."""
        q, lead = as_points(uv_distorted, "uv_distorted", 2)
        x = self.inverse_map(q)
        if self.refine:
            # Newton steps on the points not yet within tol_px (a spline or local map costs per
            # evaluated point, and most points converge in a step or two)
            act = np.arange(len(x))
            for _ in range(int(iterations)):
                f = self.forward_map(x[act])
                r = f - q[act]
                busy = np.max(np.abs(r), axis=1, initial=0.0) >= tol_px
                act, r, f = act[busy], r[busy], f[busy]
                if act.size == 0:
                    break
                J = _jacobian(self.forward_map, x[act], fx=f)
                det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
                ok = np.abs(det) > 1e-12
                dx = np.zeros((len(act), 2))
                dx[ok, 0] = (J[ok, 1, 1] * r[ok, 0] - J[ok, 0, 1] * r[ok, 1]) / det[ok]
                dx[ok, 1] = (-J[ok, 1, 0] * r[ok, 0] + J[ok, 0, 0] * r[ok, 1]) / det[ok]
                x[act] -= dx
        return x.reshape(*lead, 2)

    def round_trip_error(self, uv_distorted, *, refined: bool = True) -> np.ndarray:
        """``|forward(inverse(q)) - q|`` in pixels for each point (``refined=False``: the
        closed-form inverse map alone)."""
        q, lead = as_points(uv_distorted, "uv_distorted", 2)
        x = self.inverse(q) if refined else self.inverse_map(q)
        return np.linalg.norm(self.forward_map(x) - q, axis=-1).reshape(lead)

    def with_scale(self, mm_per_px: float | None) -> DistortionModel:
        """The same model with ``mm_per_px`` set."""
        return DistortionModel(self.spec, self.forward_map, self.inverse_map, self.n_points,
                               mm_per_px, self.refine, self.n_fit)

    def to_dict(self) -> dict:
        """Plain-JSON description (spec, both fitted maps, scale)."""
        return {"type": "distortion_model", "spec": self.spec.to_dict(),
                "forward": self.forward_map.to_dict(), "inverse": self.inverse_map.to_dict(),
                "n_points": self.n_points, "mm_per_px": self.mm_per_px, "refine": self.refine,
                "n_fit": self.n_fit}

    @classmethod
    def from_dict(cls, d: dict) -> DistortionModel:
        if d.get("type") != "distortion_model":
            raise ValueError(f"d: expected a dict written by DistortionModel.to_dict, "
                             f"got type {d.get('type')!r}")
        return cls(ModelSpec.from_dict(d["spec"]), map_from_dict(d["forward"]), map_from_dict(d["inverse"]),
                   int(d["n_points"]), None if d.get("mm_per_px") is None else float(d["mm_per_px"]),
                   bool(d.get("refine", True)), None if d.get("n_fit") is None else int(d["n_fit"]))


def even_subsample(points, n: int, *, seed: int = 0) -> np.ndarray:
    """Sorted rows of about ``n`` of ``points (N, 2)`` spread evenly over their extent.

    The bounding box is cut into ~``n`` square bins and one point (drawn with ``seed``) is kept
    per occupied bin; the count is then trimmed or topped up at random to exactly ``n``. All
    rows when ``N <= n``.
    """
    p, _ = as_points(points, "points", 2)
    n = int(n)
    if n < 1:
        raise ValueError(f"n: expected a positive number of points, got {n}")
    if len(p) <= n:
        return np.arange(len(p))
    rng = np.random.default_rng(seed)
    perm = rng.permutation(len(p))
    lo, span = p.min(axis=0), np.ptp(p, axis=0)
    side = max(float(np.sqrt(max(span[0], 1e-9) * max(span[1], 1e-9) / n)), 1e-9)
    cell = np.floor((p[perm] - lo) / side).astype(np.int64)
    key = cell[:, 0] * (int(cell[:, 1].max()) + 1) + cell[:, 1]
    _, first = np.unique(key, return_index=True)
    keep = perm[np.sort(first)]
    if len(keep) > n:
        keep = rng.choice(keep, n, replace=False)
    elif len(keep) < n:
        rest = np.setdiff1d(perm, keep)
        keep = np.concatenate([keep, rng.choice(rest, n - len(keep), replace=False)])
    return np.sort(keep)


def fit_distortion(ideal_uv, distorted_uv, model: str | ModelSpec = "poly(8,8)", *,
                   mm_per_px: float | None = None, refine: bool = True, max_points: int | None = None,
                   seed: int = 0) -> DistortionModel:
    """Fit a distortion model to control points.

    Parameters
    ----------
    ideal_uv : (N, 2) array_like
        Ideal (undistorted) grid positions, pixels.
    distorted_uv : (N, 2) array_like
        Detected (distorted) positions of the same points, pixels.
    model : str or ModelSpec
        E.g. ``"poly(5,5)"``, ``"cheb(15,15)"``, ``"tps"``, ``"lwm(12)"`` (:meth:`ModelSpec.parse`).
    mm_per_px : float, optional
        Ideal pixel size in the grid plane, kept on the model for reports.
    refine : bool
        Newton-refine the inverse (see the module docs).
    max_points : int, optional
        Fit to at most this many points (an even subsample, :func:`even_subsample`); default
        :data:`TPS_MAX_POINTS` for a thin-plate spline, all points for the other models.
        :attr:`DistortionModel.n_fit` says when a subsample was used.
    seed : int
        Seed of the subsample.

    Raises
    ------
    ValueError
        Mismatched or too few points for the model (found vs needed are named).
    """
    spec = ModelSpec.parse(model)
    p, _ = as_points(ideal_uv, "ideal_uv", 2)
    q, _ = as_points(distorted_uv, "distorted_uv", 2)
    if len(p) != len(q):
        raise ValueError(f"ideal_uv, distorted_uv: expected the same number of points, "
                         f"got {len(p)} and {len(q)}")
    cap = (TPS_MAX_POINTS if spec.kind == "tps" else None) if max_points is None else int(max_points)
    if cap is not None and cap < 1:
        raise ValueError(f"max_points: expected a positive number of points, got {max_points!r}")
    n_all, n_fit = len(p), None
    if cap is not None and len(p) > cap:
        keep = even_subsample(p, cap, seed=seed)
        p, q, n_fit = p[keep], q[keep], cap
    fwd = spec.fit_map(p, q)
    inv = spec.fit_map(q, p)
    return DistortionModel(spec, fwd, inv, n_all, None if mm_per_px is None else float(mm_per_px),
                           bool(refine), n_fit)
