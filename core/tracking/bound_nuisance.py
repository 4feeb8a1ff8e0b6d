"""Cramér–Rao bound of a bone's pose with the soft tissue unknown: a smooth nuisance field per view.

:func:`core.tracking.bound.pose_bound` takes everything else in the beam as known — the other bones
and the soft tissue's and walkway's line integrals — so it is optimistic: no tracker knows the
tissue. Here the tissue is an unknown *nuisance*: per view, a field ``b_v(u, v) = Σ_k η_k B_k(u, v)``
added to the line integral (``∂L/∂η_k = B_k``), plus, optionally, a gain on the bone's own line
integral (``∂L/∂g = DRR``, the bone's attenuation scale the stage fits; an offset — unknown fluence
— is in every basis below). The Fisher information of ``(θ, η)`` is :func:`pose_bound`'s sum over
all the parameters; the pose's bound is the inverse of the Schur complement

    J_θθ − J_θη J_ηη⁻¹ J_ηθ  =  Gᵀ W G − Gᵀ W B (Bᵀ W B)⁺ Bᵀ W G

(``G`` the pose derivatives, ``B`` the nuisance's basis images, ``W = N e^{-L}``): the information
left in the part of each derivative image that no nuisance field can imitate. The views'
nuisances are independent, so the complements add over views. Never below the known-tissue bound;
equal to it where the basis is W-orthogonal to the derivatives; infinite where a pose derivative is
in the basis's span.

Bases (:func:`spline_factors`, :func:`lowpass_factors`), both separable ``B_{ik} = b_i(y) c_k(x)``:

* ``"spline"``: tensor cubic B-splines with knots every ``spacing_px`` pixels of the view (knots at
  multiples of it from the view's pixel 0, so the model is the view's, not the region's): a smooth
  tissue of scale ``spacing_px``;
* ``"lowpass"``: the stage's model class (:mod:`core.tracking.final_stage`, which high-passes both
  images by ``σ``): what its high-pass removes — the cosine modes (DCT-II) of the region whose
  frequency the Gaussian low-pass keeps to at least ``keep`` (0.5: where the high-pass leaves
  less than half of it; ``f ≤ sqrt(ln(1/keep) / 2π²) / σ`` cycles per pixel).

The field is fitted over the bone's region grown by ``grow_px`` (pixels with no pose derivative
still pin the nuisance down; growing it by three knot spacings instead of two moves the ratio by
≤ 0.4 %, instead of one by ≤ 1.1 %).
:func:`nuisance_bound` also gives the linearised bias of the
efficient estimator of that model when the true background is not in the basis: with ``r`` the
true background (e.g. the tissue's and walkway's line integral), ``δθ = J_s⁻¹ G̃ᵀ W r``, ``G̃`` the
derivatives with the nuisance W-projected out — what a too-coarse basis costs.

Study: :mod:`core.studies.tracking.tissue_bound`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .bound import PoseBound, _derivatives, _from_covariance, _inverse

__all__ = ["NuisanceBound", "lowpass_factors", "nuisance_bound", "nuisance_bounds", "nuisance_information",
           "spline_factors"]


def _bspline3(t: np.ndarray) -> np.ndarray:
    d = np.abs(t)
    return np.where(d < 1, (4 - 6 * d**2 + 3 * d**3) / 6, np.where(d < 2, (2 - d) ** 3 / 6, 0.0))


def _spline_1d(start: int, n: int, spacing: float) -> np.ndarray:
    """``(n, m)`` cubic B-splines with knots at multiples of ``spacing`` (pixel units) at pixel
    centres ``start … start + n - 1``: the splines whose support meets them."""
    t = (start + np.arange(n)) / float(spacing)
    ks = np.arange(int(np.floor(t[0])) - 1, int(np.floor(t[-1])) + 3)
    B = _bspline3(t[:, None] - ks[None, :])
    return B[:, np.any(B > 0, axis=0)]


def spline_factors(roi, spacing_px: float):
    """``(B_y (h, m_y), B_x (w, m_x), None)``: the separable factors of the tensor cubic B-splines
    with knots every ``spacing_px`` pixels of the view over ``roi = (u0, v0, w, h)`` (every pair)."""
    if not spacing_px > 0:
        raise ValueError(f"spacing_px: expected a positive spacing, got {spacing_px!r}")
    u0, v0, w, h = (int(a) for a in roi)
    return _spline_1d(v0, h, spacing_px), _spline_1d(u0, w, spacing_px), None


def lowpass_factors(roi, sigma_px: float, keep: float = 0.5):
    """``(C_y (h, m_y), C_x (w, m_x), mask (m_y, m_x))``: the DCT-II modes of the region ``roi``
    (``cos(π k (x + ½) / n)``, unit norm) whose frequency ``f = sqrt(f_x² + f_y²)``, ``f = k / 2n``
    cycles per pixel, a Gaussian low-pass of ``sigma_px`` keeps to at least ``keep``
    (``exp(-2π² σ² f²) ≥ keep``); ``mask`` selects the pairs."""
    if not sigma_px > 0 or not 0 < keep < 1:
        raise ValueError(f"sigma_px, keep: expected sigma_px > 0 and 0 < keep < 1, got {sigma_px!r}, "
                         f"{keep!r}")
    _, _, w, h = (int(a) for a in roi)
    fc = np.sqrt(np.log(1.0 / keep) / (2 * np.pi**2)) / float(sigma_px)

    def modes(n):
        k = np.arange(min(n, int(np.floor(2 * n * fc)) + 1))
        C = np.cos(np.pi * np.outer(np.arange(n) + 0.5, k) / n)
        return C / np.linalg.norm(C, axis=0), k / (2.0 * n)

    Cy, fy = modes(h)
    Cx, fx = modes(w)
    return Cy, Cx, (fy[:, None] ** 2 + fx[None, :] ** 2) <= fc**2


class _Nuisance:
    """The nuisance of one view: ``B`` the separable basis (factors, optional pair ``mask``) and
    ``extra`` images, under pixel weights ``w``; :meth:`inner` is ``⟨A, C⟩_W`` with the nuisance
    W-projected out of both."""

    def __init__(self, w: np.ndarray, factors, extra: np.ndarray | None = None):
        By, Bx, mask = factors
        self.w, self.By, self.Bx = w, By, Bx
        my, mx = By.shape[1], Bx.shape[1]
        self.sel = np.ones(my * mx, bool) if mask is None else np.asarray(mask, bool).ravel()
        T = np.einsum("xk,xl,yx->ykl", Bx, Bx, w, optimize=True)
        M = np.einsum("yi,yj,ykl->ikjl", By, By, T, optimize=True).reshape(my * mx, my * mx)
        M = M[np.ix_(self.sel, self.sel)]
        self.extra = None if extra is None or len(extra) == 0 else np.asarray(extra, float)
        if self.extra is not None:
            E = self.extra
            Mte = self._tensor(E)
            Mee = np.einsum("ayx,yx,byx->ab", E, w, E)
            M = np.block([[M, Mte], [Mte.T, Mee]])
        d = np.diag(M).copy()
        seen = d > 0  # a basis image no weighted pixel sees carries nothing
        s = np.zeros_like(d)
        s[seen] = 1.0 / np.sqrt(d[seen])
        Ms = M * s[:, None] * s[None, :]  # unit W-norms: a spline barely inside the region counts in full
        self.s, self.chol = s, None
        self.size = int(M.shape[0])
        try:  # well conditioned (the usual case): a Cholesky factor
            import scipy.linalg as sl

            c = sl.cho_factor(Ms, lower=True)
            dg = np.diag(c[0])
            if dg.min() ** 2 > 1e-10 * dg.max() ** 2:
                self.chol = c
                return
        except np.linalg.LinAlgError:
            pass
        ev, V = np.linalg.eigh(0.5 * (Ms + Ms.T))
        ok = ev > 1e-10 * ev.max()  # only combinations the basis repeats are dropped
        self.V, self.ev = V[:, ok], ev[ok]

    def _tensor(self, A: np.ndarray) -> np.ndarray:
        """``(m, a)``: ``Bᵀ W A`` for images ``A (a, h, w)`` over the selected pairs."""
        X = np.einsum("yi,ayx,xk->ika", self.By, A * self.w, self.Bx, optimize=True)
        return X.reshape(-1, A.shape[0])[self.sel]

    def cross(self, A: np.ndarray) -> np.ndarray:
        X = self._tensor(A)
        if self.extra is not None:
            X = np.vstack([X, np.einsum("eyx,yx,ayx->ea", self.extra, self.w, A)])
        return X

    def inner(self, A: np.ndarray, C: np.ndarray) -> np.ndarray:
        """``(a, c)``: ``Aᵀ W C − Aᵀ W B (Bᵀ W B)⁺ Bᵀ W C``."""
        full = np.einsum("ayx,yx,cyx->ac", A, self.w, C)
        XA, XC = self.s[:, None] * self.cross(A), self.s[:, None] * self.cross(C)
        if self.chol is not None:
            import scipy.linalg as sl

            return full - XA.T @ sl.cho_solve(self.chol, XC)
        XA, XC = self.V.T @ XA, self.V.T @ XC
        return full - (XA / self.ev[:, None]).T @ XC


def nuisance_information(G: np.ndarray, w: np.ndarray, factors, extra=None) -> tuple[np.ndarray, np.ndarray]:
    """``(J, J_s)`` of parameters whose derivative images are ``G (p, h, w)`` under pixel weights
    ``w (h, w)``: the full information ``Gᵀ W G`` and its Schur complement with the nuisance of
    basis ``factors`` (:func:`spline_factors`, :func:`lowpass_factors`) and ``extra (q, h, w)``
    images (module docs)."""
    G = np.asarray(G, float)
    nu = _Nuisance(np.asarray(w, float), factors, extra)
    Js = nu.inner(G, G)
    return np.einsum("ayx,yx,cyx->ac", G, nu.w, G), 0.5 * (Js + Js.T)


@dataclass(frozen=True)
class NuisanceBound:
    """:func:`nuisance_bound`'s answer.

    Attributes
    ----------
    known : PoseBound
        The bound with the tissue known (:func:`core.tracking.bound.pose_bound`'s).
    nuisance : PoseBound
        With the nuisance unknown: ``information`` the Schur complement summed over views,
        ``covariance`` its inverse (``inf`` where singular).
    bias : (6,) array or None
        The linearised bias (mm ×3, degrees ×3) when ``residual`` was given.
    parameters : int
        Nuisance parameters over the views.
    """

    known: PoseBound
    nuisance: PoseBound
    bias: np.ndarray | None
    parameters: int

    def ratio(self) -> tuple[float, float]:
        """The nuisance bound over the known-tissue bound (mm, degrees)."""
        return self.nuisance.rms_mm / self.known.rms_mm, self.nuisance.rms_deg / self.known.rms_deg


def nuisance_bound(renderer, bone: int, pose, center, *, line_integral: Sequence[np.ndarray],
                   quanta_per_pixel, basis: str = "spline", spacing_px: float = 8.0, sigma_px: float = 1.0,
                   keep: float = 0.5, gain: bool = True, grow_px: int | None = None,
                   residual: Sequence[np.ndarray] | None = None, views: Sequence[int] | None = None,
                   step=(0.1, 0.1), margin_px: int = 6) -> NuisanceBound:
    """Cramér–Rao bound of ``bone``'s pose with a smooth nuisance field per view unknown (module docs).

    Parameters
    ----------
    renderer, bone, pose, center, line_integral, quanta_per_pixel, views, step, margin_px
        As :func:`core.tracking.bound.pose_bound`.
    basis : {"spline", "lowpass"}
        The nuisance: cubic B-splines every ``spacing_px`` pixels, or the modes a Gaussian low-pass
        of ``sigma_px`` keeps to at least ``keep`` (the high-pass stage's removed part).
    gain : bool
        Also an unknown gain on the bone's line integral, per view.
    grow_px : int, optional
        The region of the nuisance's fit: the box of the pixels where the bone's line integral
        changes with its pose, grown by ``margin_px`` plus this many pixels (clipped to the view);
        default ``2 · spacing_px`` (spline) or ``3 · sigma_px`` (lowpass), at least 4.
    residual : sequence of (H, W) arrays, optional
        The true background per camera (what the nuisance stands for): adds the linearised
        ``bias`` of the estimator of that model.
    """
    model = {"basis": basis, "spacing_px": spacing_px, "sigma_px": sigma_px, "keep": keep, "gain": gain}
    return nuisance_bounds(renderer, bone, pose, center, {"m": model}, line_integral=line_integral,
                           quanta_per_pixel=quanta_per_pixel, grow_px=grow_px, residual=residual, views=views,
                           step=step, margin_px=margin_px)["m"]


def _grow(m: dict) -> int:
    if m.get("basis", "spline") == "spline":
        return max(4, int(np.ceil(2 * float(m.get("spacing_px", 8.0)))))
    return max(4, int(np.ceil(3 * float(m.get("sigma_px", 1.0)))))


def nuisance_bounds(renderer, bone: int, pose, center, models: dict, *, line_integral: Sequence[np.ndarray],
                    quanta_per_pixel, grow_px: int | None = None,
                    residual: Sequence[np.ndarray] | None = None, views: Sequence[int] | None = None,
                    step=(0.1, 0.1), margin_px: int = 6) -> dict:
    """:func:`nuisance_bound` for several nuisance ``models`` (``{label: {"basis", "spacing_px",
    "sigma_px", "keep", "gain"}}``, its keywords) from one rendering of the derivatives: ``{label:
    NuisanceBound}``. Each model's region is the box of the pixels where the bone's line integral
    changes, grown by ``margin_px`` plus ``grow_px`` (default the model's own, :func:`nuisance_bound`)."""
    models = {k: dict(m) for k, m in models.items()}
    for k, m in models.items():
        if m.get("basis", "spline") not in ("spline", "lowpass"):
            raise ValueError(f"basis: expected 'spline' or 'lowpass', got {m.get('basis')!r} ({k})")
    grows = {k: max(int(grow_px), 0) if grow_px is not None else _grow(m) for k, m in models.items()}
    views, N, D = _derivatives(renderer, bone, pose, center, line_integral=line_integral,
                               quanta_per_pixel=quanta_per_pixel, views=views, step=step,
                               margin_px=margin_px + max(grows.values()))
    J = np.zeros((6, 6))
    acc = {k: [np.zeros((6, 6)), np.zeros(6), 0] for k in models}
    pixels = 0
    for v, roi, Dv, Lv in D:
        q = N[v] * np.exp(-Lv)
        u0, v0, w, h = roi
        J += np.einsum("ayx,yx,cyx->ac", Dv, q, Dv)
        seen = np.any(Dv != 0, axis=0)
        pixels += int(np.count_nonzero(seen))
        if not seen.any():
            continue
        ys, xs = np.nonzero(seen)
        drr = None
        if any(m.get("gain", True) for m in models.values()):
            drr = renderer.render(np.asarray(pose, float)[None, None], views=[v], bones=[bone],
                                  roi=np.array([[[u0, v0, w, h]]])[None]).numpy()[0, 0, 0, :h, :w]
            drr = drr.astype(float)
        r = None if residual is None else np.asarray(residual[v], float)[v0:v0 + h, u0:u0 + w]
        for k, m in models.items():
            g = margin_px + grows[k]
            y0, y1 = max(ys.min() - g, 0), min(ys.max() + 1 + g, h)
            x0, x1 = max(xs.min() - g, 0), min(xs.max() + 1 + g, w)
            sub = (u0 + x0, v0 + y0, x1 - x0, y1 - y0)
            spline = m.get("basis", "spline") == "spline"
            factors = (spline_factors(sub, float(m.get("spacing_px", 8.0))) if spline
                       else lowpass_factors(sub, float(m.get("sigma_px", 1.0)), float(m.get("keep", 0.5))))
            cut = (slice(y0, y1), slice(x0, x1))
            nu = _Nuisance(q[cut], factors, drr[cut][None] if m.get("gain", True) else None)
            Dk = Dv[:, y0:y1, x0:x1]
            Jv = nu.inner(Dk, Dk)
            acc[k][0] += 0.5 * (Jv + Jv.T)
            if r is not None:
                acc[k][1] += nu.inner(Dk, r[cut][None])[:, 0]
            acc[k][2] += nu.size
    known = _from_covariance(J, _inverse(J), pixels)
    out = {}
    for k, (Js, score, size) in acc.items():
        C = _inverse(Js)
        bias = None
        if residual is not None:
            bias = C @ score if np.all(np.isfinite(C)) else np.full(6, np.inf)
        out[k] = NuisanceBound(known=known, nuisance=_from_covariance(Js, C, pixels), bias=bias,
                               parameters=size)
    return out
