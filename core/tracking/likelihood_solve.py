"""The host's half of a likelihood final-stage step (:meth:`core.tracking.engine_likelihood.
LikelihoodEngine.step`): the weighted products table ``M = Σ w z zᵀ`` of each view's region,
``z = (y, D(x), δ_1 … δ_6, 1, u, v, O[, T_1 … T_q])`` (``δ_k`` the central differences of the
high-passed DRRs, ``O`` the neighbours', ``T`` extra regressors), solved in float64 with
``A = (D, 1[, u, v][, O][, T])``::

    coef = (AᵀWA)⁻¹ AᵀWy        χ² = yᵀWy - coefᵀ AᵀWy        D_k = δ_k / 2h_k
    β_k  = (AᵀWA)⁻¹ AᵀW D_k     JᵀWJ = a² (D_kᵀWD_l - D_kᵀWA β_l)     JᵀWr = a (D_kᵀWy - D_kᵀWA coef)

(``a = coef₀``; the Jacobian of the residual with the linear parameters projected out, Golub–
Pereyra), the step ``δ = (JᵀWJ)⁻¹ JᵀWr`` summed over views — the same arithmetic as
:func:`core.similarity.likelihood.wls_gauss_newton_step` without the pixels on the host.
:mod:`core.tracking.engine_likelihood` re-exports :func:`solve_moments`."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .likelihood_kernels import NA, NZ

try:  # numpy.linalg.solve's gufunc, called as it calls it
    from numpy.linalg import _umath_linalg as _ul
except ImportError:  # pragma: no cover
    _ul = None

__all__ = ["solve_moments"]

#: :func:`solve_moments` gathers the table's entries with one index array and calls the stacked solve's
#: gufunc itself, as :func:`numpy.linalg.solve` calls it (the same LAPACK solve under the same error
#: state, without its checks), both solves under one error state: the same values to the bit (1,800
#: random tables of every model), 95 → 84 µs a call on this 2-core x86_64 machine. Off: through
#: :func:`numpy.linalg.solve` and an index array per block, as before.
DIRECT_SOLVES = True


def solve_moments(M: np.ndarray, h: np.ndarray, background: int = 0, others: bool = False,
                  extra: int = 0) -> dict:
    """The variable-projection Gauss–Newton quantities of the moment tables ``M (views, 12 + extra,
    12 + extra)`` (module docs) with half-steps ``h (6,)``: ``{"JJ", "Jr", "chi2"}`` summed over
    views and, per view, ``lin (views, 42)`` (``(views, na + 7 + 6 na)``, ``na = 5 + extra``: the
    linear fit and projections :func:`residual_kernel` reads). ``others``: the neighbours' DRRs a
    regressor with a gain of their own; ``extra``: the tables' extra regressors (entries 12 … of
    ``z``, :func:`~core.tracking.likelihood_kernels.regressor_kernels`), each with its own
    coefficient. The views at once (stacked solves and products; the same values to 4e-16, in half
    the time of a loop over the views); the tables' entries taken by flat index arrays made once per
    model (:func:`_indices`; the same arithmetic and values to the bit, 149 → 130 µs a call on a 2-core
    x86_64 CPU)."""
    extra = int(extra)
    nz, na = NZ + extra, NA + extra
    M = np.asarray(M, dtype=np.float64).reshape(-1, nz, nz)
    n = len(M)
    ix = _indices(int(background), bool(others), extra)
    Mf = M.reshape(n, nz * nz)
    s = 1.0 / (2.0 * np.asarray(h, dtype=float))
    if DIRECT_SOLVES and _ul is not None:
        X = Mf[:, ix.all]  # (the entries at once; the same values)
        e, p = ix.ends, len(ix.slot)
        G = X[:, :e[0]].reshape(n, p, p)
        b = X[:, e[0]:e[1]]
        MDA = s[None, :, None] * X[:, e[1]:e[2]].reshape(n, 6, p)
        MDD = s[None, :, None] * X[:, e[2]:e[3]].reshape(n, 6, 6) * s[None, None, :]
        MDy = s[None, :] * X[:, e[3]:e[4]]
        with np.errstate(call=_singular, invalid="call", over="ignore", divide="ignore", under="ignore"):
            coef = _ul.solve(G, b[..., None], signature="dd->d")[..., 0]  # (views, p)
            beta = _ul.solve(G, MDA.transpose(0, 2, 1), signature="dd->d")  # (views, p, 6)
    else:
        G = Mf[:, ix.G]  # (views, p, p)
        b = Mf[:, ix.b]
        coef = np.linalg.solve(G, b[..., None])[..., 0]  # (views, p)
        MDA = s[None, :, None] * Mf[:, ix.DA]  # (views, 6, p)
        MDD = s[None, :, None] * Mf[:, ix.DD] * s[None, None, :]
        MDy = s[None, :] * Mf[:, ix.Dy]
        beta = np.linalg.solve(G, MDA.transpose(0, 2, 1))  # (views, p, 6)
    chi2 = float(np.sum(M[:, 0, 0] - np.einsum("vi,vi->v", coef, b)))
    a = coef[:, 0]
    JJ = ((a * a)[:, None, None] * (MDD - MDA @ beta)).sum(axis=0)
    Jr = (a[:, None] * (MDy - (MDA @ coef[..., None])[..., 0])).sum(axis=0)
    lin = np.zeros((n, na + 7 + 6 * na))
    lin[:, ix.slot] = coef
    lin[:, na] = a
    lin[:, na + 1:na + 7] = s
    lin[:, ix.beta] = beta.reshape(n, -1)
    return {"JJ": 0.5 * (JJ + JJ.T), "Jr": Jr, "chi2": max(chi2, 0.0), "lin": lin}


def _singular(err, flag):
    """:func:`numpy.linalg.solve`'s error for a singular matrix (its gufunc's ``invalid`` flag)."""
    raise np.linalg.LinAlgError("Singular matrix")


class _Index(NamedTuple):
    G: np.ndarray  # (p, p) flat places of A's products in a table
    b: np.ndarray  # (p,) of Aᵀy
    DA: np.ndarray  # (6, p) of the differences' products with A
    DD: np.ndarray  # (6, 6) of theirs
    Dy: np.ndarray  # (6,) of theirs with y
    slot: list  # A's columns' places in lin's coefficients
    beta: np.ndarray  # (p * 6,) β's places in lin
    all: np.ndarray  # G, b, DA, DD, Dy's places one after another (flat)
    ends: tuple  # where each of them ends in ``all``


_INDEX: dict = {}


def _indices(background: int, others: bool, extra: int) -> _Index:
    """:func:`solve_moments`' places in a flat table (kept per model: index arrays are made once)."""
    key = (background, others, extra)
    hit = _INDEX.get(key)
    if hit is None:
        nz, na = NZ + extra, NA + extra
        bg = [8] if background == 0 else [8, 9, 10]
        ai = np.array([1, *bg, *([11] if others else []), *range(NZ, nz)])
        # their places in A = (D, 1, u, v, O, T_1 … T_extra)
        slot = [0, *range(1, len(bg) + 1), *([4] if others else []), *range(NA, na)]
        di = np.arange(2, 8)
        beta = (na + 7 + 6 * np.asarray(slot)[:, None] + np.arange(6)[None, :]).ravel()
        parts = (ai[:, None] * nz + ai[None, :], ai * nz, di[:, None] * nz + ai[None, :],
                 di[:, None] * nz + di[None, :], di * nz)
        ends = tuple(int(x) for x in np.cumsum([q.size for q in parts]))
        hit = _INDEX[key] = _Index(*parts, slot, beta, np.concatenate([q.ravel() for q in parts]), ends)
    return hit
