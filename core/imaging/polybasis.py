"""Two-variable polynomial bases for global distortion models (thesis §3.5.2, eq. 3.2–3.3).

Terms
-----
A model of order ``(nx, ny)`` uses the monomials ``x^i y^j`` with ``i <= nx``, ``j <= ny`` and,
with ``terms="total"`` (default), ``i + j <= max(nx, ny)``: for ``nx == ny == n`` this is the
total-degree-``n`` polynomial (``(n + 1)(n + 2) / 2`` terms), identical to MATLAB's
``fitgeotrans`` "polynomial" models the thesis reproduced for n = 3, 4 (Table 3.1), and with
231 terms at n = 20, which over-fits ~250 grid points as the thesis found. ``terms="tensor"``
drops the total-degree limit: the full tensor product of eq. 3.2, ``(nx + 1)(ny + 1)`` terms.
Columns are ordered as in eq. 3.3: the x power varies fastest.

Bases
-----
The same polynomial space can be spanned by different bases; only the conditioning differs:

* ``"power"``: ``x^i y^j``.
* ``"chebyshev"``: ``T_i(x') T_j(y')``, with ``(x', y')`` the normalised coordinates scaled by
  the per-axis extent of the fitted points so they lie in [-1, 1].
* ``"bernstein"``: ``b_{i,nx}(s) b_{j,ny}(t)`` on ``s = (x' + 1) / 2`` in [0, 1]. Bernstein
  polynomials are a basis of the *full* tensor space, so ``terms="total"`` is not defined for
  them (a :class:`ValueError` says so).

Normalisation (Hartley 1997, "In defense of the eight-point algorithm")
------------------------------------------------------------------------
:class:`Normalisation` moves the centroid of the input points to the origin and scales them so
their RMS distance from it is √2, before any power is taken. Without it, pixel coordinates of
~100–1000 raised to the 15th power make the Vandermonde matrix numerically singular (thesis
Fig. 3.11).
"""

from __future__ import annotations

from dataclasses import dataclass
from math import comb

import numpy as np

from .._validate import as_points

__all__ = [
    "BASES",
    "Normalisation",
    "design_matrix",
    "polynomial_terms",
]

BASES = ("power", "chebyshev", "bernstein")
TERMS = ("total", "tensor")


def check_order(order, name: str = "order") -> tuple[int, int]:
    """``(nx, ny)`` from an int or a pair of ints in 1..30."""
    o = (order, order) if np.isscalar(order) else tuple(order)
    if len(o) != 2 or not all(isinstance(k, int | np.integer) and 1 <= k <= 30 for k in o):
        raise ValueError(f"{name}: expected an order n or a pair (nx, ny) of integers in 1..30, "
                         f"got {order!r}")
    return int(o[0]), int(o[1])


def polynomial_terms(order, terms: str = "total") -> np.ndarray:
    """``(n_terms, 2)`` exponent pairs ``(i, j)`` of the model, x power varying fastest."""
    nx, ny = check_order(order)
    if terms not in TERMS:
        raise ValueError(f"terms: expected one of {TERMS}, got {terms!r}")
    cap = max(nx, ny) if terms == "total" else nx + ny
    return np.array([(i, j) for j in range(ny + 1) for i in range(nx + 1) if i + j <= cap], dtype=int)


@dataclass(frozen=True)
class Normalisation:
    """Isotropic similarity ``x = (uv - center) * scale`` applied to points before a fit.

    ``extent`` (per axis, in normalised units) maps the points into [-1, 1] for the
    Chebyshev and Bernstein bases; it is 1 for the power basis.
    """

    center: tuple[float, float] = (0.0, 0.0)
    scale: float = 1.0
    extent: tuple[float, float] = (1.0, 1.0)

    @classmethod
    def hartley(cls, uv, *, extent: bool = False) -> Normalisation:
        """Centroid to the origin, RMS distance √2 (``extent=True`` also records the half-range)."""
        pts, _ = as_points(uv, "uv", 2)
        c = pts.mean(axis=0)
        rms = np.sqrt(np.mean(np.sum((pts - c) ** 2, axis=1)))
        if not rms > 0:
            raise ValueError("uv: all points coincide; cannot normalise")
        s = np.sqrt(2.0) / rms
        e = (1.0, 1.0)
        if extent:
            half = np.abs((pts - c) * s).max(axis=0)
            e = tuple(float(max(h, 1e-12)) for h in half)
        return cls((float(c[0]), float(c[1])), float(s), e)

    @classmethod
    def identity(cls) -> Normalisation:
        """No normalisation (raw pixel coordinates), as in the thesis's dashed curves."""
        return cls()

    def apply(self, uv) -> np.ndarray:
        """Normalised ``(N, 2)`` coordinates of ``uv (..., 2)`` (flattened)."""
        pts, _ = as_points(uv, "uv", 2)
        return (pts - np.asarray(self.center)) * self.scale

    def to_dict(self) -> dict:
        return {"center": list(self.center), "scale": self.scale, "extent": list(self.extent)}

    @classmethod
    def from_dict(cls, d: dict) -> Normalisation:
        return cls(tuple(float(x) for x in d["center"]), float(d["scale"]),
                   tuple(float(x) for x in d.get("extent", (1.0, 1.0))))


def _basis_1d(t: np.ndarray, n: int, basis: str, extent: float) -> tuple[np.ndarray, np.ndarray]:
    """Values and derivatives (w.r.t. ``t``) of the n + 1 one-variable basis functions, ``(N, n+1)``."""
    N = t.shape[0]
    val = np.empty((N, n + 1))
    der = np.empty((N, n + 1))
    if basis == "power":
        val[:, 0], der[:, 0] = 1.0, 0.0
        for k in range(1, n + 1):
            val[:, k] = val[:, k - 1] * t
            der[:, k] = k * val[:, k - 1]
        return val, der
    x = t / extent
    if basis == "chebyshev":
        # T_k and U_{k-1}: dT_k/dx = k U_{k-1}
        val[:, 0], der[:, 0] = 1.0, 0.0
        u_prev, u_cur = np.zeros(N), np.ones(N)  # U_{-1}, U_0
        if n >= 1:
            val[:, 1], der[:, 1] = x, 1.0
        for k in range(2, n + 1):
            val[:, k] = 2 * x * val[:, k - 1] - val[:, k - 2]
            u_prev, u_cur = u_cur, 2 * x * u_cur - u_prev  # U_{k-1}
            der[:, k] = k * u_cur
        return val, der / extent
    if basis == "bernstein":
        s = (x + 1.0) / 2.0
        one = 1.0 - s
        for k in range(n + 1):
            c = comb(n, k)
            val[:, k] = c * s**k * one ** (n - k)
            # d/ds b_{k,n} = n (b_{k-1,n-1} - b_{k,n-1})
            a = comb(n - 1, k - 1) * s ** (k - 1) * one ** (n - k) if k >= 1 else 0.0
            b = comb(n - 1, k) * s**k * one ** (n - 1 - k) if k <= n - 1 else 0.0
            der[:, k] = n * (a - b)
        return val, der / (2.0 * extent)
    raise ValueError(f"basis: expected one of {BASES}, got {basis!r}")


def design_matrix(xy: np.ndarray, order, *, basis: str = "power", terms: str = "total",
                  extent=(1.0, 1.0), derivatives: bool = False):
    """Vandermonde-type matrix ``V (N, n_terms)`` of normalised points ``xy (N, 2)`` (eq. 3.3).

    With ``derivatives=True`` also returns ``dV/dx`` and ``dV/dy`` (same shape), for Jacobians.
    """
    nx, ny = check_order(order)
    if basis not in BASES:
        raise ValueError(f"basis: expected one of {BASES}, got {basis!r}")
    if basis == "bernstein" and terms != "tensor":
        raise ValueError("terms: the Bernstein basis spans the full tensor space; use terms='tensor'")
    xy = np.asarray(xy, dtype=float)
    idx = polynomial_terms((nx, ny), terms)
    bx, dbx = _basis_1d(xy[:, 0], nx, basis, float(extent[0]))
    by, dby = _basis_1d(xy[:, 1], ny, basis, float(extent[1]))
    V = bx[:, idx[:, 0]] * by[:, idx[:, 1]]
    if not derivatives:
        return V
    return V, dbx[:, idx[:, 0]] * by[:, idx[:, 1]], bx[:, idx[:, 0]] * dby[:, idx[:, 1]]
