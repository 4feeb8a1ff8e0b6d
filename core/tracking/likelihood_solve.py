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

__all__ = ["StepTables", "inv6", "solve6", "solve_moments", "solve_tables"]

#: :meth:`~core.tracking.engine_likelihood.LikelihoodEngine.step_result` takes the host's tables through
#: :func:`solve_tables` (the pinned table's numpy view kept; the entries gathered with one index array from
#: above the diagonal, no mirror; the differences' scales applied in two products; the stacked solves
#: through :func:`numpy.linalg.solve`'s own gufunc, called as it calls it, both under one error state;
#: ``"lin"`` and ``"M"`` made where read) and :meth:`~core.tracking.engine_likelihood.LikelihoodEngine.
#: refine_steps` solves and inverts its 6×6 system through numpy's gufuncs (:func:`solve6`, :func:`inv6`):
#: the same LAPACK calls and operations on the same values, the same results to the bit (tests: 3600
#: random tables of every model; stages at 128², ``core.studies.tracking.stage_exact``), fewer numpy
#: calls: 50 → 30 µs a table on this 2-core x86_64 machine; on one NVIDIA H100's host (``stage_one_bone``'s
#: profile, 3.2 tables a bone-frame) the step results' host time besides their waits 0.69 → 0.39 ms a
#: bone-frame. Off: the table copied, mirrored with :func:`numpy.triu`, :func:`solve_moments` (through
#: :func:`numpy.linalg.solve`) and :func:`numpy.linalg.solve` / :func:`numpy.linalg.inv`, as before.
LEAN_SOLVES = True


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


def solve_tables(T: np.ndarray, h: np.ndarray, background: int = 0, others: bool = False, extra: int = 0,
                 tri: bool = False) -> dict:
    """:func:`solve_moments` of the host's flat tables ``T (views, nz²)`` (the step's pinned copy; ``tri``:
    only the entries on and above the diagonal summed, zeros below) with ``"M"`` the ``(views, nz, nz)``
    tables, mirrored — :data:`LEAN_SOLVES`' path: the entries gathered from above the diagonal (where the
    mirror's ``0 + u`` is ``u``: a table summed from zero holds no -0), the differences' scales applied in
    two products of every gathered entry, ``"lin"`` and ``"M"`` made where they are read
    (:class:`StepTables`): the same operations on the same values as :func:`numpy.triu`'s mirror and
    :func:`solve_moments`, the same results to the bit."""
    extra = int(extra)
    nz = NZ + extra
    n = T.shape[0]
    Tf = np.array(T, dtype=np.float64).reshape(n, nz * nz)  # (a copy: the pinned table is written again)
    if not LEAN_SOLVES or _ul is None:  # (as before: mirrored with numpy.triu, solve_moments)
        M = Tf.reshape(n, nz, nz)
        if tri:
            M += np.swapaxes(np.triu(M, 1), 1, 2)
        out = solve_moments(M, h, background, others, extra)
        out["M"] = M
        return out
    pl = _plan(int(background), bool(others), extra, np.asarray(h, dtype=float))
    ix = pl.index
    e, p = ix.ends, len(ix.slot)
    X = Tf[:, pl.upper if tri else ix.all]
    G = X[:, :e[0]].reshape(n, p, p)
    b = X[:, e[0]:e[1]]
    Y = X[:, e[1]:] * pl.sa  # s_k times each difference's entry (D_k A, D_k D_l, D_k y) ...
    Y *= pl.sb  # ... and D_k D_l's times s_l (the others' times 1: exact)
    r = e[2] - e[1]
    MDA = Y[:, :r].reshape(n, 6, p)
    MDD = Y[:, r:r + 36].reshape(n, 6, 6)
    MDy = Y[:, r + 36:]
    with np.errstate(call=_singular, invalid="call", over="ignore", divide="ignore", under="ignore"):
        coef = _ul.solve(G, b[..., None], signature="dd->d")[..., 0]  # (views, p)
        beta = _ul.solve(G, MDA.transpose(0, 2, 1), signature="dd->d")  # (views, p, 6)
    chi2 = float((Tf[:, 0] - np.einsum("vi,vi->v", coef, b)).sum())
    a = coef[:, 0]
    JJ = ((a * a)[:, None, None] * (MDD - MDA @ beta)).sum(axis=0)
    Jr = (a[:, None] * (MDy - (MDA @ coef[..., None])[..., 0])).sum(axis=0)
    return StepTables(JJ=0.5 * (JJ + JJ.T), Jr=Jr, chi2=max(chi2, 0.0),
                      _tables=(Tf, nz, tri, coef, beta, pl.s, ix, extra))


class StepTables(dict):
    """:func:`solve_tables`' result: ``"lin"`` (the linear fit and projections the residual kernels read)
    and ``"M"`` (the tables, mirrored) made the first time they are read (``s["lin"]``), from the kept
    copy and solves (``"_tables"``); the same values as :func:`solve_moments`' and the mirror's."""

    def __missing__(self, key):
        Tf, nz, tri, coef, beta, s, ix, extra = self["_tables"]
        n = len(Tf)
        if key == "lin":
            na = NA + extra
            v = np.zeros((n, na + 7 + 6 * na))
            v[:, ix.slot] = coef
            v[:, na] = coef[:, 0]
            v[:, na + 1:na + 7] = s
            v[:, ix.beta] = beta.reshape(n, -1)
        elif key == "M":
            v = Tf.reshape(n, nz, nz).copy()
            if tri:
                v += np.swapaxes(np.triu(v, 1), 1, 2)
        else:
            raise KeyError(key)
        self[key] = v
        return v


def solve6(JJ: np.ndarray, Jr: np.ndarray) -> np.ndarray:
    """``numpy.linalg.solve(JJ, Jr)`` (float64, one system) through its gufunc under its error state: the
    same LAPACK solve and values, a singular system's LinAlgError (:data:`LEAN_SOLVES`)."""
    if _ul is None or not LEAN_SOLVES:
        return np.linalg.solve(JJ, Jr)
    with np.errstate(call=_singular, invalid="call", over="ignore", divide="ignore", under="ignore"):
        return _ul.solve1(JJ, Jr, signature="dd->d")


def inv6(JJ: np.ndarray) -> np.ndarray:
    """``numpy.linalg.inv(JJ)`` (float64) through its gufunc under its error state (:func:`solve6`)."""
    if _ul is None or not LEAN_SOLVES:
        return np.linalg.inv(JJ)
    with np.errstate(call=_singular, invalid="call", over="ignore", divide="ignore", under="ignore"):
        return _ul.inv(JJ, signature="d->d")


class _Plan(NamedTuple):
    index: _Index
    upper: np.ndarray  # the gathered places (:attr:`_Index.all`), those below the diagonal their mirrors'
    s: np.ndarray  # 1 / 2h
    sa: np.ndarray  # s_k of each gathered difference entry (D_k A, D_k D_l, D_k y)
    sb: np.ndarray  # s_l of D_k D_l's, 1 of the others


_PLANS: dict = {}


def _plan(background: int, others: bool, extra: int, h: np.ndarray) -> _Plan:
    """:func:`solve_tables`' places and scales for a model and half-steps (kept: the steps' ``h`` repeat)."""
    key = (background, others, extra, h.tobytes())
    hit = _PLANS.get(key)
    if hit is None:
        ix = _indices(background, others, extra)
        nz, p = NZ + extra, len(ix.slot)
        i, j = np.tril_indices(nz, -1)
        s = 1.0 / (2.0 * h)
        sa = np.concatenate([np.repeat(s, p), np.repeat(s, 6), s])
        sb = np.concatenate([np.ones(6 * p), np.tile(s, 6), np.ones(6)])
        if len(_PLANS) >= 64:
            _PLANS.clear()
        flat = np.arange(nz * nz)
        flat[i * nz + j] = j * nz + i  # (each place below the diagonal its mirror's above it)
        hit = _PLANS[key] = _Plan(ix, flat[ix.all], s, sa, sb)
    return hit


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
