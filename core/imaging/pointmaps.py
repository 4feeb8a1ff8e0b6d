"""Fitted 2-D point maps ``R² → R²`` used by the distortion models (thesis §3.5.2).

Three families, each fitted by least squares to control-point pairs ``src → dst`` (pixels):

* :class:`PolynomialMap` — a global polynomial (:mod:`core.imaging.polybasis`) of order
  ``(nx, ny)``, solved by QR factorisation of the Vandermonde matrix of the (optionally
  Hartley-normalised) source points; rank and 2-norm condition number are recorded.
* :class:`ThinPlateSplineMap` — a thin-plate spline (``r² log r`` kernel plus an affine part,
  Bookstein 1989) through the control points, with optional smoothing (0 = interpolating).
* :class:`LocalWeightedMeanMap` — Goshtasby's (1988) local weighted mean, as MATLAB's
  ``fitgeotrans(..., 'lwm', N)``: a 2nd-order polynomial fitted to each control point and its
  ``N - 1`` nearest neighbours, valid within the distance ``R_i`` to the farthest of them, and
  blended with the weight ``1 - 3R² + 2R³`` (``R = distance / R_i``). Outside every support the
  nearest point's polynomial extrapolates.

Every map is a frozen dataclass holding its fitted numbers, evaluates ``(..., 2)`` arrays, and
round-trips through :meth:`to_dict` / :func:`map_from_dict` (plain JSON types).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import RBFInterpolator
from scipy.spatial import cKDTree

from .._validate import as_points
from .polybasis import BASES, Normalisation, check_order, design_matrix, polynomial_terms

__all__ = [
    "LocalWeightedMeanMap",
    "PolynomialMap",
    "ThinPlateSplineMap",
    "fit_local_weighted_mean",
    "fit_polynomial_map",
    "fit_thin_plate_spline",
    "map_from_dict",
]


def _pairs(src, dst) -> tuple[np.ndarray, np.ndarray]:
    s, _ = as_points(src, "src", 2)
    d, _ = as_points(dst, "dst", 2)
    if len(s) != len(d):
        raise ValueError(f"src, dst: expected the same number of points, got {len(s)} and {len(d)}")
    return s, d


def _batched(fn, uv) -> np.ndarray:
    pts, lead = as_points(uv, "uv", 2)
    out = np.empty_like(pts)
    for k in range(0, len(pts), 65536):
        out[k : k + 65536] = fn(pts[k : k + 65536])
    return out.reshape(*lead, 2)


# ---------------------------------------------------------------------------- polynomial
@dataclass(frozen=True, eq=False)
class PolynomialMap:
    """``dst = Σ c_ij B_i(x) B_j(y)`` of normalised source points (see :mod:`polybasis`).

    Attributes
    ----------
    order : (nx, ny)
    basis : {"power", "chebyshev", "bernstein"}
    terms : {"total", "tensor"}
    norm : Normalisation
    coef : (n_terms, 2) float64
        Coefficients of the u (column 0) and v (column 1) outputs, in pixels.
    rank, condition : int, float
        Numerical rank and 2-norm condition number of the fitted Vandermonde matrix.
    """

    order: tuple[int, int]
    basis: str
    terms: str
    norm: Normalisation
    coef: np.ndarray
    rank: int = 0
    condition: float = float("nan")

    def _eval(self, pts: np.ndarray) -> np.ndarray:
        V = design_matrix(self.norm.apply(pts), self.order, basis=self.basis, terms=self.terms,
                          extent=self.norm.extent)
        return V @ self.coef

    def __call__(self, uv) -> np.ndarray:
        """Mapped points ``(..., 2)`` of ``uv (..., 2)`` (pixels, (u, v) = (column, row))."""
        return _batched(self._eval, uv)

    def jacobian(self, uv) -> np.ndarray:
        """``(..., 2, 2)`` Jacobian ``d dst / d src`` (rows: u, v outputs; columns: u, v inputs)."""
        pts, lead = as_points(uv, "uv", 2)
        _, dx, dy = design_matrix(self.norm.apply(pts), self.order, basis=self.basis,
                                  terms=self.terms, extent=self.norm.extent, derivatives=True)
        J = np.stack([dx @ self.coef, dy @ self.coef], axis=-1) * self.norm.scale
        return J.reshape(*lead, 2, 2)

    @property
    def n_terms(self) -> int:
        return int(self.coef.shape[0])

    def on_grid(self, u, v) -> np.ndarray:
        """Map of every point of the regular grid ``u (W,) × v (H,)`` as ``(H, W, 2)``.

        The normalisation is isotropic and separable, so the polynomial factors into
        ``B_y(v) C B_x(u)ᵀ`` per output: ``O((H + W) n + H W n)`` with tiny matrices, instead of a
        ``(H W, n_terms)`` Vandermonde matrix (dense remap tables).
        """
        from .polybasis import _basis_1d

        uu = (np.asarray(u, float) - self.norm.center[0]) * self.norm.scale
        vv = (np.asarray(v, float) - self.norm.center[1]) * self.norm.scale
        nx, ny = self.order
        bx = _basis_1d(uu, nx, self.basis, self.norm.extent[0])[0]
        by = _basis_1d(vv, ny, self.basis, self.norm.extent[1])[0]
        idx = polynomial_terms(self.order, self.terms)
        out = np.empty((vv.size, uu.size, 2))
        for c in range(2):
            C = np.zeros((ny + 1, nx + 1))
            C[idx[:, 1], idx[:, 0]] = self.coef[:, c]
            out[..., c] = np.einsum("vj,ji,ui->vu", by, C, bx, optimize=True)
        return out

    def to_dict(self) -> dict:
        return {"type": "polynomial", "order": list(self.order), "basis": self.basis,
                "terms": self.terms, "norm": self.norm.to_dict(), "coef": self.coef.tolist(),
                "rank": self.rank, "condition": self.condition}


def fit_polynomial_map(src, dst, order, *, basis: str = "power", terms: str | None = None,
                       normalise: bool = True) -> PolynomialMap:
    """Least-squares polynomial ``src → dst`` by QR of the Vandermonde matrix (thesis eq. 3.3).

    Parameters
    ----------
    src, dst : (N, 2) array_like
        Control points (pixels).
    order : int or (nx, ny)
        Polynomial orders in x (u) and y (v).
    basis : {"power", "chebyshev", "bernstein"}
    terms : {"total", "tensor"} or None
        Term set (:func:`polybasis.polynomial_terms`); None = "total", or "tensor" for Bernstein.
    normalise : bool
        Hartley-normalise ``src`` first (centroid to origin, RMS distance √2). Chebyshev and
        Bernstein bases always are, and are then scaled into [-1, 1].

    Raises
    ------
    ValueError
        If there are fewer points than polynomial terms (the message gives both numbers).
    """
    s, d = _pairs(src, dst)
    nx, ny = check_order(order)
    if basis not in BASES:
        raise ValueError(f"basis: expected one of {BASES}, got {basis!r}")
    terms = terms or ("tensor" if basis == "bernstein" else "total")
    n_terms = len(polynomial_terms((nx, ny), terms))
    if len(s) < n_terms:
        raise ValueError(f"points: found {len(s)} grid points, but a ({nx},{ny}) {terms} polynomial needs at "
                         f"least {n_terms} (one per term); lower the order or detect more points")
    if basis == "power":
        norm = Normalisation.hartley(s) if normalise else Normalisation.identity()
    else:
        norm = Normalisation.hartley(s, extent=True)
    V = design_matrix(norm.apply(s), (nx, ny), basis=basis, terms=terms, extent=norm.extent)
    with np.errstate(all="ignore"):
        # plain Householder QR, as MATLAB's mldivide (thesis): no column equilibration, so that
        # normalise=False shows what raw pixel coordinates do to the solution (Fig. 3.11). The
        # right-hand sides ride along as extra columns, so R's last columns are Qᵀd and Q is never
        # formed; V and R have the same singular values (rank, condition).
        n = V.shape[1]
        Ra = np.linalg.qr(np.hstack([V, d]), mode="r")
        R, qtd = Ra[:n, :n], Ra[:n, n:]
        sv = np.linalg.svd(R, compute_uv=False)
        tol = sv.max() * max(V.shape) * np.finfo(float).eps
        rank = int(np.sum(sv > tol))
        cond = float(sv.max() / sv.min()) if sv.min() > 0 else float("inf")
        coef = np.linalg.lstsq(R, qtd, rcond=None)[0]
    return PolynomialMap((nx, ny), basis, terms, norm, coef, rank, cond)


# ---------------------------------------------------------------------------- thin-plate spline
@dataclass(frozen=True, eq=False)
class ThinPlateSplineMap:
    """Thin-plate spline ``src → dst`` (affine part + ``r² log r`` kernels at the sources).

    ``smoothing`` is scipy's ``RBFInterpolator`` smoothing (0 = exact interpolation), applied in
    Hartley-normalised coordinates.
    """

    src: np.ndarray
    dst: np.ndarray
    smoothing: float = 0.0
    norm: Normalisation = field(default_factory=Normalisation)
    _rbf: RBFInterpolator | None = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self._rbf is None:
            rbf = RBFInterpolator(self.norm.apply(self.src), self.dst, kernel="thin_plate_spline",
                                  smoothing=self.smoothing, degree=1)
            object.__setattr__(self, "_rbf", rbf)

    def __call__(self, uv) -> np.ndarray:
        return _batched(lambda p: self._rbf(self.norm.apply(p)), uv)

    def to_dict(self) -> dict:
        return {"type": "thin_plate_spline", "src": self.src.tolist(), "dst": self.dst.tolist(),
                "smoothing": self.smoothing, "norm": self.norm.to_dict()}


def fit_thin_plate_spline(src, dst, *, smoothing: float = 0.0) -> ThinPlateSplineMap:
    """Thin-plate spline through the control points (``smoothing >= 0``)."""
    s, d = _pairs(src, dst)
    if not (np.isfinite(smoothing) and smoothing >= 0):
        raise ValueError(f"smoothing: expected a number >= 0, got {smoothing!r}")
    if len(s) < 3:
        raise ValueError(f"points: found {len(s)} grid points, a thin-plate spline needs at least 3")
    return ThinPlateSplineMap(s.copy(), d.copy(), float(smoothing), Normalisation.hartley(s))


# ---------------------------------------------------------------------------- local weighted mean
def _quad_basis(x: np.ndarray) -> np.ndarray:
    return np.column_stack([np.ones(len(x)), x[:, 0], x[:, 1], x[:, 0] * x[:, 1], x[:, 0] ** 2,
                            x[:, 1] ** 2])


@dataclass(frozen=True, eq=False)
class LocalWeightedMeanMap:
    """Local weighted mean of 2nd-order polynomials (Goshtasby 1988; see the module docs).

    Attributes
    ----------
    centers : (n, 2)  control points in normalised source coordinates
    coef : (n, 6, 2)  each point's quadratic in local coordinates ``x - centers[i]``
    radius : (n,)     support radius of each point (normalised units)
    norm : Normalisation
    """

    centers: np.ndarray
    coef: np.ndarray
    radius: np.ndarray
    n_neighbours: int
    norm: Normalisation
    _tree: cKDTree | None = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self._tree is None:
            object.__setattr__(self, "_tree", cKDTree(self.centers))

    def _eval(self, pts: np.ndarray) -> np.ndarray:
        """Blend of the local quadratics whose support covers each point. The supports are
        found with the k-d tree (the ``k`` nearest centres, ``k`` doubled for the points where
        the k-th is still within the largest radius), so the cost grows with the number of
        points, not with points × centres."""
        x = self.norm.apply(pts)
        num = np.zeros((len(x), 2))
        den = np.zeros(len(x))
        rmax = float(self.radius.max())
        todo = np.arange(len(x))
        k = min(len(self.centers), 4 * self.n_neighbours)
        while todo.size:
            d, j = self._tree.query(x[todo], k, distance_upper_bound=rmax)
            d, j = d.reshape(len(todo), -1), j.reshape(len(todo), -1)
            more = np.isfinite(d[:, -1]) & (k < len(self.centers))
            done = todo[~more]
            dd, jj = d[~more], j[~more]
            hit = np.isfinite(dd)
            hit[hit] = dd[hit] < self.radius[jj[hit]]
            q, c = np.nonzero(hit)
            if q.size:
                jc = jj[q, c]
                R = dd[q, c] / self.radius[jc]
                w = 1 - 3 * R**2 + 2 * R**3
                val = np.einsum("kt,ktc->kc", _quad_basis(x[done[q]] - self.centers[jc]), self.coef[jc])
                den += np.bincount(done[q], w, minlength=len(x))
                num[:, 0] += np.bincount(done[q], w * val[:, 0], minlength=len(x))
                num[:, 1] += np.bincount(done[q], w * val[:, 1], minlength=len(x))
            todo = todo[more]
            k = min(len(self.centers), 2 * k)
        out = np.empty_like(num)
        good = den > 1e-12
        out[good] = num[good] / den[good, None]
        if not np.all(good):  # outside every support: the nearest point's own polynomial
            _, j = self._tree.query(x[~good])
            B = _quad_basis(x[~good] - self.centers[j])
            out[~good] = np.einsum("kt,ktc->kc", B, self.coef[j])
        return out

    def __call__(self, uv) -> np.ndarray:
        return _batched(self._eval, uv)

    def to_dict(self) -> dict:
        return {"type": "local_weighted_mean", "centers": self.centers.tolist(),
                "coef": self.coef.tolist(), "radius": self.radius.tolist(),
                "n_neighbours": self.n_neighbours, "norm": self.norm.to_dict()}


def fit_local_weighted_mean(src, dst, *, n_neighbours: int = 12) -> LocalWeightedMeanMap:
    """Local weighted mean map with ``n_neighbours`` points per local quadratic (>= 6)."""
    s, d = _pairs(src, dst)
    if int(n_neighbours) != n_neighbours or n_neighbours < 6:
        raise ValueError(f"n_neighbours: expected an integer >= 6 (a quadratic has 6 terms), "
                         f"got {n_neighbours!r}")
    n_neighbours = int(n_neighbours)
    if len(s) < n_neighbours:
        raise ValueError(f"points: found {len(s)} grid points, the local weighted mean needs at least "
                         f"n_neighbours = {n_neighbours}")
    norm = Normalisation.hartley(s)
    x = norm.apply(s)
    tree = cKDTree(x)
    dist, nb = tree.query(x, n_neighbours)
    # every point's quadratic at once: least squares by a stacked pseudo-inverse (lstsq's cutoff)
    B = _quad_basis((x[nb] - x[:, None, :]).reshape(-1, 2)).reshape(len(x), n_neighbours, 6)
    coef = np.linalg.pinv(B, rcond=max(B.shape[1:]) * np.finfo(float).eps) @ d[nb]
    return LocalWeightedMeanMap(x, coef, dist[:, -1].copy(), n_neighbours, norm, tree)


# ---------------------------------------------------------------------------- serialisation
def map_from_dict(d: dict):
    """Rebuild a map written by ``to_dict`` (plain JSON types)."""
    kind = d.get("type")
    if kind == "polynomial":
        return PolynomialMap(tuple(int(k) for k in d["order"]), d["basis"], d["terms"],
                             Normalisation.from_dict(d["norm"]), np.asarray(d["coef"], float),
                             int(d.get("rank", 0)), float(d.get("condition", float("nan"))))
    if kind == "thin_plate_spline":
        return ThinPlateSplineMap(np.asarray(d["src"], float), np.asarray(d["dst"], float),
                                  float(d["smoothing"]), Normalisation.from_dict(d["norm"]))
    if kind == "local_weighted_mean":
        return LocalWeightedMeanMap(np.asarray(d["centers"], float), np.asarray(d["coef"], float),
                                    np.asarray(d["radius"], float), int(d["n_neighbours"]),
                                    Normalisation.from_dict(d["norm"]))
    raise ValueError(f"map: unknown map type {kind!r} (expected polynomial, thin_plate_spline or "
                     f"local_weighted_mean)")
