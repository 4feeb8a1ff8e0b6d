"""Screen pose estimators by their linearised bias and spread (``python -m
core.studies.tracking.spread_screen``), instead of tracking whole trials.

Around the true pose ``θ₀`` an M-estimator that minimises ``C(θ; y)`` lands, to first order, at
``θ₀ - H⁻¹ g(y)`` (``g`` the cost's gradient at ``θ₀``, ``H`` its Hessian there): on the noise-free
frame that is its *bias*, over noise draws of the frame its *spread*. Per bone and candidate
(:class:`Candidate`, :func:`parse`) the screen takes this step from the truth on the noise-free
frame and on ``draws`` noisy frames of the acceptance trial's chain (:class:`~core.studies.tracking.
acceptance.TrackingScene` with the grid-estimated distortion correction and the measured glare
undone, as the stage's GPU runs, :mod:`core.studies.tracking.tissue_tibia`), every other bone at
its true pose and subtracted, and predicts the RMS error over the frames and draws divided by the
Cramér–Rao bound of the same frames (:func:`~core.studies.tracking.acceptance.cramer_rao`, the
acceptance study's frames 0, 10, …, 90). No search runs.

* Likelihood-stage candidates (``kind="wls"``): the step is the stage's own Gauss–Newton step
  (:func:`wls_step`: the formulas of :func:`core.tracking.likelihood_solve.solve_moments`, the
  gain, offset and regressors fitted linearly and projected out) computed on the host from the
  13-pose design rendered once per bone-frame; the weights the expected counts of the
  unsubtracted line integrals (Gaussian 2 px, as :meth:`~core.tracking.engine_likelihood.
  LikelihoodEngine.set_frame`), the rim band of :func:`core.tracking.likelihood_rim.rim_keep`, the
  2 mm tissue (:func:`~core.studies.tracking.tissue_regressor.user_tissue` ``"fine"``) through the
  estimated PSF, and the robust round (:func:`core.tracking.final_stage.robust_factors` of the
  residual at the truth, then the step again with the factors: the robust refinement's optimum
  to first order). Costs linear in the image after a fixed filter: the Monte-Carlo over draws is
  the exact noise covariance's estimate.
* GC (``kind="gc"``, the tracker's cost, :data:`core.tracking.cost.DEFAULT_TERMS`): the gradient
  by central differences of the cost (13 poses rendered once, scored against every draw), the
  Hessian from the 73-pose quadratic design of :func:`~core.studies.tracking.bound_gap.local_newton`
  on the noise-free frame.

Sizes: the high-pass σ, the DoG's inner σ and the design's steps are given at 1024² and scaled
with ``pixels``. Results: per bone and candidate ``rms``, ``bias`` (the draws' per-frame means)
and ``spread`` (mm, °), their ratios to the bound (``over_bound`` …), per-axis values.

Measured (``resources/benchmarks/tracking_spread_screen_h100.json``, one NVIDIA H100, 1024², frames
0-80 every 20th, 8 draws; ``tracking_spread_screen_cpu.json``, this 2-core x86_64 machine, 512²):
the screen does not validate. Predicted against the tracked ratios (three bones jointly, 100
frames, × the bound mm/°): the stage at 4 px tibia 1.38/0.64, talus 1.09/0.97, calcaneus 0.96/0.94
(tracked 1.56/1.42, 1.38/1.29, 1.21/1.38); at 8 px with the 2 mm tissue and the rim band
1.25/0.73, 0.95/0.86, 0.89/0.85 (tracked 1.41/1.34, 1.15/1.19, 1.11/1.31): 13-27 % low in mm and
33-122 % in degrees; 512² gives the same within 12 %, the neighbours at the tracker's poses
(``nbr``) within 0.01. GC's linearisation fails outright (its cost is rough on the voxel scale:
three-point Hessians indefinite, the quadratic over ±0.1 mm/° gave the tibia 2.01/4.70). The gap is
the estimator's, not the noise model's: the host step equals the device stage's step within
1.5e-6, but refined to convergence on the same draws (:mod:`core.studies.tracking.spread_screen_check`,
512², frame 50) the stage's spread is 1.2-1.5× the linearised one (its rotation about the tibia's
long axis most; the stage at 8 px with the tissue and the band then 1.53/1.35, 1.12/1.36,
1.21/1.17 on that frame, near its tracked ratios), and the ranking changes with it: edge weights
(``edge1``), which the screen put 10-14 % below the stage in mm and 3-9 % in degrees for every bone,
refine to no gain (tibia 1.52/1.46, talus 1.14/1.31, calcaneus 1.27/1.21). A screen of this cost has
to refine per draw.

JSON on stdout (``--out``: also to a file, rewritten as it goes).
"""

from __future__ import annotations

import platform
import time
from dataclasses import dataclass, replace

import numpy as np

from core.studies.tracking import _study_cli as cli

__all__ = ["Candidate", "main", "parse", "screen", "wls_step"]


@dataclass(frozen=True)
class Candidate:
    """One estimator (:func:`parse` reads its name). ``kind`` ``"wls"`` (the likelihood stage's
    model) or ``"gc"`` (the tracker's cost). WLS: ``highpass`` the high-pass σ (px at 1024²; 0:
    none), ``inner`` a difference of Gaussians' inner σ (px at 1024²; 0: a plain high-pass),
    ``poly`` Legendre polynomials up to that order fitted as regressors (the projection orthogonal
    to a low-order subspace; -1: none, only the offset), ``weights`` ``"counts"`` (the stage's),
    ``"flat"`` or ``"edge"`` (the counts times ``(|∇D|/median)^edge_power`` of the bone's
    high-passed DRR, clipped to [0.1, 10]), ``tissue`` the 2 mm tissue regressor, ``rim`` the rim
    band's σ multiple (None: none), ``robust`` the robust round's threshold (None: none),
    ``binning`` 2: 2×2 pixels averaged (a half-resolution stage); ``nbr``: the neighbours subtracted
    at the tracker's poses of the frame (:data:`EST_JSON`'s per-frame errors, three bones jointly)
    instead of the truth — the joint stage's situation, their errors leaking in; ``newton``: the
    step's matrix χ²'s Hessian from a quadratic fit instead of Gauss–Newton's ``JᵀWJ`` (the stage's
    own; :func:`_wls_steps`)."""

    name: str
    kind: str = "wls"
    highpass: float = 4.0
    inner: float = 0.0
    poly: int = -1
    weights: str = "counts"
    edge_power: float = 1.0
    tissue: bool = False
    rim: float | None = None
    robust: float | None = 2.5
    binning: int = 1
    nbr: bool = False
    newton: bool = False


def parse(name: str) -> Candidate:
    """A candidate from its name, ``+``-separated tokens: ``gc``; ``hp<σ>`` (σ px at 1024²),
    ``dog<inner>`` (with ``hp<σ>``), ``poly<order>`` (``hp0`` for no high-pass), ``flat``,
    ``edge<power>``, ``tissue``, ``rim`` / ``rim<k>``, ``norobust``, ``bin2``, ``nbr``, ``newton``. E.g.
    ``hp8+tissue+rim`` (the stage's best measured), ``hp4`` (its default)."""
    c = Candidate(name)
    for t in name.split("+"):
        if t == "gc":
            c = replace(c, kind="gc")
        elif t.startswith("hp"):
            c = replace(c, highpass=float(t[2:]))
        elif t.startswith("dog"):
            c = replace(c, inner=float(t[3:]))
        elif t.startswith("poly"):
            c = replace(c, poly=int(t[4:]))
        elif t == "flat":
            c = replace(c, weights="flat")
        elif t.startswith("edge"):
            c = replace(c, weights="edge", edge_power=float(t[4:] or 1.0))
        elif t == "tissue":
            c = replace(c, tissue=True)
        elif t.startswith("rim"):
            c = replace(c, rim=float(t[3:] or 3.0))
        elif t == "norobust":
            c = replace(c, robust=None)
        elif t.startswith("bin"):
            c = replace(c, binning=int(t[3:]))
        elif t == "nbr":
            c = replace(c, nbr=True)
        elif t == "newton":
            c = replace(c, newton=True)
        else:
            raise ValueError(f"candidate {name!r}: unknown token {t!r}")
    if c.binning not in (1, 2):
        raise ValueError(f"candidate {name!r}: binning 1 or 2, got {c.binning}")
    return c


# ---------------------------------------------------------------------- the WLS step
def _gauss(a, s):
    from scipy import ndimage

    return ndimage.gaussian_filter(a, s, mode="nearest", truncate=4.0) if s > 0 else a


def _filter(a, c: Candidate, scale: float):
    """``a (…, h, w)`` through the candidate's filter: ``a - G_σ a`` or ``G_inner a - G_σ a``."""
    s, si = c.highpass * scale, c.inner * scale
    if s <= 0:
        return a
    lead = a.shape[:-2]
    A = a.reshape(-1, *a.shape[-2:])
    out = np.stack([(_gauss(x, si) if si > 0 else x) - _gauss(x, s) for x in A])
    return out.reshape(*lead, *a.shape[-2:])


def _legendre(shape, order: int) -> list:
    from core.tracking.likelihood_cost import background_basis

    return [] if order < 1 else list(background_basis(shape, order, "legendre")[1:])


def wls_step(D, dD, y, w, extra=()) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One view's variable-projection Gauss–Newton terms at the design's centre: ``(JJ, Jr, e)``
    with ``δ = (Σ JJ)⁻¹ Σ Jr`` the step (:func:`core.tracking.likelihood_solve.solve_moments`'s
    formulas), ``e`` the weighted residual image ``√w (y - A coef)`` (0 where ``w`` is). ``D`` the
    (filtered) DRR at the centre, ``dD (6, h, w)`` its derivatives, ``y`` the (filtered) line
    integrals, ``w`` the weights, ``extra`` more regressor images; the offset always fitted."""
    sel = w.ravel() > 0
    sw = np.sqrt(w.ravel()[sel])
    A = np.column_stack([D.ravel()[sel], np.ones(sel.sum()), *[x.ravel()[sel] for x in extra]]) * sw[:, None]
    Q, T = np.linalg.qr(A)
    yw = y.ravel()[sel] * sw
    coef = np.linalg.solve(T, Q.T @ yw)
    r = yw - Q @ (Q.T @ yw)
    J = dD.reshape(6, -1)[:, sel] * sw * coef[0]
    J = J - (J @ Q) @ Q.T
    e = np.zeros(y.size)
    e[sel] = r
    return J @ J.T, J @ r, e.reshape(y.shape)


def _bin(a, k: int):
    """``a (…, h, w)`` averaged over ``k × k`` blocks (the edge cut)."""
    if k == 1:
        return a
    h, w = (a.shape[-2] // k) * k, (a.shape[-1] // k) * k
    a = a[..., :h, :w]
    return a.reshape(*a.shape[:-2], h // k, k, w // k, k).mean(axis=(-3, -1))


class _ViewData:
    """One view's region of one bone-frame: the design's DRRs, the neighbours' DRRs, the tissue
    regressor, the rim band (all fixed over the draws)."""

    def __init__(self, D, others, tissue, keep, others_est=None, Dq=None) -> None:
        self.D, self.others, self.tissue, self.keep = D, others, tissue, keep
        self.Dq = Dq  # the DRRs of the 73-pose quadratic design (_design)
        self.others_est = others_est  # the neighbours' DRRs at the tracker's poses
        self.cache: dict = {}  # the candidates' model terms (_model_terms)


def _model_terms(vd: _ViewData, c: Candidate, sc: float, h: float) -> tuple:
    """The candidate's filtered DRR, its derivatives, its extra regressors and edge factor over one
    view's region (kept in ``vd``: they do not change between the draws)."""
    key = (c.highpass, c.inner, c.binning, c.poly, c.tissue, c.weights, c.edge_power)
    hit = vd.cache.get(key)
    if hit is None:
        k = c.binning
        Df = _filter(_bin(vd.D, k), c, sc)
        dD = (Df[1:7] - Df[7:13]) / (2 * h)
        extra = list(_legendre(Df.shape[1:], c.poly))
        if c.tissue:
            extra.append(_filter(_bin(vd.tissue, k), c, sc))
        edge = None
        if c.weights == "edge":  # the bone's edges: the smoothed gradient of its filtered DRR
            gv, gu = np.gradient(_gauss(Df[0], 1.0))
            g = np.hypot(gu, gv)
            edge = np.clip((g / max(float(np.median(g)), 1e-12)) ** c.edge_power, 0.1, 10.0)
        hit = vd.cache[key] = (Df[0], dD, extra, edge)
    return hit


def _wls_round(c: Candidate, views: list, frames_y: list, scale: float, h: float) -> tuple:
    """The candidate's terms on one frame (``frames_y`` per view ``(y, mask)``: the region's line
    integrals, usable pixels) after its robust round: per view ``(D0, dD, y, w, extra)`` and the
    summed ``(JJ, Jr)`` of :func:`wls_step` (``-2 Jr`` the gradient of χ² at the truth)."""
    from core.tracking.final_stage import robust_factors

    k = c.binning
    sc = scale / k
    terms = []
    for vd, (y0, m) in zip(views, frames_y, strict=True):
        w = np.exp(-_gauss(y0.astype(np.float64), 2.0)) * m  # the expected counts (set_frame's)
        kp = vd.keep.get((c.rim, c.highpass)) if c.rim is not None else None
        if kp is not None:
            w = w * kp
        y = y0 - (vd.others_est if c.nbr else vd.others)
        if k > 1:
            w, y = _bin(w, k) * k * k, _bin(y, k)
            w = w * (_bin(m.astype(float), k) > 0.999)
        D0, dD, extra, edge = _model_terms(vd, c, sc, h)
        if c.weights == "flat":
            w = (w > 0).astype(float)
        elif c.weights == "edge":
            w = w * edge
        terms.append([D0, dD, _filter(y, c, sc), w, extra])
    out = [wls_step(D0, dD, yf, w, extra) for D0, dD, yf, w, extra in terms]
    if c.robust is not None:  # the robust round: factors of the residual at the truth, the step again
        for t, o in zip(terms, out, strict=True):
            t[3] = t[3] * robust_factors(o[2][None], (t[3] > 0)[None], c.robust, sigma_px=2.0)[0]
        out = [wls_step(D0, dD, yf, w, extra) for D0, dD, yf, w, extra in terms]
    return terms, sum(o[0] for o in out), sum(o[1] for o in out)


def _chi2_design(c: Candidate, views: list, terms: list, scale: float) -> np.ndarray:
    """χ² (gain and regressors fitted) of the design's poses (:attr:`_ViewData.Dq`) on ``terms``'
    line integrals and weights, summed over the views."""
    k = c.binning
    tot = 0.0
    for vd, (_, _, yf, w, extra) in zip(views, terms, strict=True):
        key = ("q", c.highpass, c.inner, k)
        Dq = vd.cache.get(key)
        if Dq is None:
            Dq = vd.cache[key] = _filter(_bin(vd.Dq, k), c, scale / k)
        sel = w.ravel() > 0
        sw = np.sqrt(w.ravel()[sel])
        F = np.column_stack([np.ones(sel.sum()), *[x.ravel()[sel] for x in extra]]) * sw[:, None]
        Q = np.linalg.qr(F)[0]
        yP = yf.ravel()[sel] * sw
        yP = yP - Q @ (Q.T @ yP)
        DP = Dq.reshape(len(Dq), -1)[:, sel] * sw
        DP = DP - (DP @ Q) @ Q.T
        tot = tot + float(yP @ yP) - (DP @ yP) ** 2 / np.sum(DP**2, axis=1)
    return np.asarray(tot)


def _wls_steps(c: Candidate, views: list, regions: list, scale: float, h: float, Xq) -> np.ndarray:
    """``(len(regions), 6)`` the candidate's linearised estimate's offsets from the truth (mm, °),
    one per frame of ``regions`` (the noise-free one first): ``-H⁻¹ g`` with ``g = -2 Jr`` the exact
    gradient of χ² (variable projection) on that frame and ``H`` the Hessian of χ² from the
    least-squares quadratic through the design ``Xq`` on the noise-free frame, weighted as the
    first noisy draw (its robust factors) where the candidate's ``newton``, else Gauss–Newton's
    ``2 JᵀWJ`` (the stage's own step matrix: :func:`wls_step`)."""
    rounds = [_wls_round(c, views, rg, scale, h) for rg in regions]
    if not c.newton:
        return np.array([np.linalg.solve(JJ, Jr) for _, JJ, Jr in rounds])
    free = rounds[0][0]
    ws = rounds[min(1, len(rounds) - 1)][0]
    terms = [(D0, dD, yf, t[3], extra) for (D0, dD, yf, _, extra), t in zip(free, ws, strict=True)]
    _, H = _quadratic(np.asarray(Xq), _chi2_design(c, views, terms, scale))
    return np.array([np.linalg.solve(H / 2, Jr) for _, _, Jr in rounds])


# ---------------------------------------------------------------------- GC
def _design(h: float) -> np.ndarray:
    """The 73-pose quadratic design (:func:`~core.studies.tracking.bound_gap.local_newton`'s):
    the centre, ``±h`` on each axis and ``(±h, ±h)`` on each pair."""
    E = np.eye(6) * h
    X = [np.zeros(6)] + [E[i] for i in range(6)] + [-E[i] for i in range(6)]
    for i in range(6):
        for j in range(i + 1, 6):
            X += [E[i] + E[j], E[i] - E[j], -E[i] + E[j], -E[i] - E[j]]
    return np.array(X)


def _quadratic(X: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(g, H)`` of the least-squares quadratic through the costs ``c`` of the poses ``X`` (GC's
    cost is rough on the scale of a voxel: finite differences of three points are not its trend)."""
    iu = np.triu_indices(6)
    Q = np.stack([X[:, i] * X[:, j] * (0.5 if i == j else 1.0) for i, j in zip(*iu, strict=True)], axis=1)
    A = np.column_stack([np.ones(len(X)), X, Q])
    coef = np.linalg.lstsq(A, c, rcond=None)[0]
    H = np.zeros((6, 6))
    H[iu] = coef[7:]
    H = H + np.triu(H, 1).T
    return coef[1:7], H


# ---------------------------------------------------------------------- the screen
def _chain(ts, L, f: int, draw: int | None) -> list:
    """Frame ``f``'s corrected fluence images (the trial's chain, glare undone, grid correction);
    ``draw`` None: noise-free, else an independent noise draw."""
    out = []
    for v, m in enumerate(ts.scene.imaging):
        mm = m if draw is not None else replace(m, photons_per_pixel=None, read_noise_dn=0.0)
        rng = None if draw is None else np.random.default_rng([int(ts.scene.seed), 0x5C2EE, f, v, draw])
        out.append(np.asarray(ts.correct(v, mm.apply(L[v], rng=rng)), np.float32))
    return out


def _bone_frame(ts, P, frames_imgs, b: int, cands, *, T, scale: float, h: float, rims, P_est=None) -> dict:
    """Per candidate ``(draws + 1, 6)`` steps (the noise-free frame's first) of bone ``b`` at the true
    poses ``P``; ``T (views, H, W)`` the tissue regressor as the frame shows it; ``P_est`` the
    tracker's poses (``nbr`` candidates' neighbours)."""
    from core.geometry.transforms import pose_from_params
    from core.studies.tracking.background_fit import _crop
    from core.tracking.cost import RegistrationCost, fluoro_rois, prepare_frame, search_roi, snap_roi
    from core.tracking.likelihood_rim import rim_keep

    views = (0, 1)
    m = ts.models[b]
    oth = [k for k in range(len(ts.names)) if k != b]
    roi = snap_roi(search_roi(ts.renderer, P[b], b, views=views, center=m.centroid, reach_mm=1.0,
                              margin_px=4), ts.renderer, views)
    fr = [prepare_frame(im) for im in frames_imgs]
    X = np.concatenate([np.zeros((1, 6)), np.eye(6) * h, -np.eye(6) * h])
    out = {}
    wls = [c for c in cands if c.kind == "wls"]
    if wls:
        p = np.concatenate([X[:, :3], np.radians(X[:, 3:])], axis=1)
        Pd = pose_from_params(p, center=m.centroid, base=P[b])
        roi_arg = np.asarray(roi)[None, :, None, :]
        Dall = ts.renderer.render(Pd[:, None], views=views, bones=[b], roi=roi_arg).numpy()[:, :, 0]
        Xq = _design(2 * h)
        Dq = None
        if any(c.newton for c in wls):
            pq = np.concatenate([Xq[:, :3], np.radians(Xq[:, 3:])], axis=1)
            Dq = ts.renderer.render(pose_from_params(pq, center=m.centroid, base=P[b])[:, None], views=views,
                                    bones=[b], roi=roi_arg).numpy()[:, :, 0]
        Oall = ts.renderer.render(P[oth][None], views=views, bones=oth, roi=roi_arg).numpy()[0].sum(axis=1)
        Oest = Oall if P_est is None else ts.renderer.render(P_est[oth][None], views=views, bones=oth,
                                                             roi=roi_arg).numpy()[0].sum(axis=1)
        cap = (max(int(r[3]) for r in roi), max(int(r[2]) for r in roi))
        keeps = {(k, hp): rim_keep(fr[0], views, roi, k * hp * scale, cap) for k, hp in rims}
        vds = []
        for i, _ in enumerate(views):
            wd, ht = int(roi[i][2]), int(roi[i][3])
            keep = {key: None if kk is None else kk[i, :ht, :wd].astype(float) for key, kk in keeps.items()}
            vds.append(_ViewData(Dall[:, i, :ht, :wd].astype(np.float64),
                                 Oall[i, :ht, :wd].astype(np.float64), _crop(T[i], roi[i]), keep,
                                 Oest[i, :ht, :wd].astype(np.float64),
                                 None if Dq is None else Dq[:, i, :ht, :wd].astype(np.float64)))
        regions = [[(y.astype(np.float64), mk) for y, mk in zip(*fluoro_rois(ts.renderer, f_, views=views,
                                                                             roi=roi), strict=True)]
                   for f_ in fr]
        for c in wls:
            out[c.name] = _wls_steps(c, vds, regions, scale, h, Xq)
    for c in (c for c in cands if c.kind == "gc"):
        costs = [RegistrationCost(ts.renderer, f_, bone=b, base_pose=P[b], center=m.centroid, roi=roi,
                                  others=((P if P_est is None or not c.nbr else P_est)[oth], oth))
                 for f_ in fr]
        Xq = _design(2 * h)
        batch = ts.renderer.render(costs[0].poses(Xq)[:, None], views=views, bones=[b], roi=costs[0]._roi_arg)
        fits = [_quadratic(Xq, 1.0 - np.asarray(cst.metrics[0].evaluate(batch).pose, float)) for cst in costs]
        H0 = fits[0][1]
        out[c.name] = -np.linalg.solve(H0, np.array([g for g, _ in fits]).T).T
    return out


def _summary(D: np.ndarray, bound: dict) -> dict:
    """``D (frames, draws + 1, 6)``: RMS over the noisy draws, their bias (the per-frame means) and
    spread about it, and the noise-free frame's step (a robust round's factors on a noise-free
    frame see the structure alone, so its step is not the noisy frames' bias)."""
    def rms(E):
        E = np.asarray(E).reshape(-1, 3)
        return float(np.sqrt(np.mean(np.sum(E**2, axis=1))))

    noisy, free = D[:, 1:], D[:, 0]
    n = noisy.shape[1]
    mean = noisy.mean(1)
    dev = (noisy - mean[:, None]) * np.sqrt(n / max(n - 1, 1))  # (n - 1 per frame)
    r = {"rms": [rms(noisy[..., :3]), rms(noisy[..., 3:])], "bias": [rms(mean[:, :3]), rms(mean[:, 3:])],
         "spread": [rms(dev[..., :3]), rms(dev[..., 3:])],
         "noise_free": [rms(free[:, :3]), rms(free[:, 3:])],
         "spread_axes": np.sqrt(np.mean(dev.reshape(-1, 6) ** 2, axis=0)).tolist(),
         "bias_axes": np.sqrt(np.mean(mean**2, axis=0)).tolist()}
    r["over_bound"] = [r["rms"][0] / bound["rms_mm"], r["rms"][1] / bound["rms_deg"]]
    r["bias_over_bound"] = [r["bias"][0] / bound["rms_mm"], r["bias"][1] / bound["rms_deg"]]
    r["spread_over_bound"] = [r["spread"][0] / bound["rms_mm"], r["spread"][1] / bound["rms_deg"]]
    r["bound_axes"] = bound.get("sigma")
    return {k: None if v is None else [round(float(x), 5) for x in v] for k, v in r.items()}


#: the tracker's per-frame errors (three bones jointly, the acceptance trial at 1024², one NVIDIA
#: H200) that ``nbr`` candidates place the neighbours by
EST_JSON = "resources/benchmarks/tracking_tissue_stage_h200.json"


def _est_errors(path: str) -> dict:
    from core.studies.tracking.tissue_tibia import _est_errors as est

    return est(path)


def _tracked(ts, P, est: dict, f: int) -> np.ndarray:
    """The bones' poses as the tracker had them in frame ``f`` (its errors ``est`` applied)."""
    from core.studies.tracking.tissue_tibia import _moved

    return np.stack([_moved(P[b], est[nm][f], ts.models[b].centroid) for b, nm in enumerate(ts.names)])


DEFAULT_CANDIDATES = ("gc", "hp4", "hp8", "hp8+tissue", "hp8+tissue+rim")


def screen(*, pixels: int = 512, voxel: float = 0.5, frames=range(0, 100, 10), bones=(0, 1, 2),
           draws: int = 30, candidates=DEFAULT_CANDIDATES, device: str | None = "cpu",
           checkpoint=None) -> dict:
    """The screen (module docs); JSON-ready. ``candidates``: names (:func:`parse`)."""
    from core.render import DRRRenderer
    from core.studies.tracking.acceptance import cramer_rao
    from core.studies.tracking.background_fit import _Sources, estimated_psf
    from core.studies.tracking.tissue_regressor import regressor_images, user_tissue

    t0 = time.perf_counter()
    cands = [parse(c) for c in candidates]
    frames = [int(f) for f in frames]
    src = _Sources(pixels, voxel, 100, 0, device)
    ts = src.scene("grid")
    sc = ts.scene
    psf = np.asarray(estimated_psf(ts), float)
    scale = pixels / 1024
    h = 0.05 * 1024 / pixels  # the design's half-steps (mm, °), scaled as the pixel
    tissue_r = DRRRenderer(sc.rig, [v.to_attenuation(sc.tissue_transfer) for v in user_tissue(sc, "fine")],
                           device=device)
    rims = sorted({(c.rim, c.highpass) for c in cands if c.kind == "wls" and c.rim is not None})
    est = _est_errors(EST_JSON) if any(c.nbr for c in cands) else {}
    if any(c.nbr for c in cands) and not all(nm in est for nm in ts.names):
        raise FileNotFoundError(f"nbr: the tracker's errors of {EST_JSON} are missing")
    out = {"study": "core.studies.tracking.spread_screen", "machine": platform.machine(), "device": device,
           "pixels": pixels, "voxel_mm": voxel, "frames": frames, "draws": draws, "correction": "grid",
           "glare_undone": True, "candidates": [c.__dict__ for c in cands], "design_step": h}
    bound = cramer_rao(ts, frames)
    out["bound"] = {nm: {"rms_mm": v["rms_mm"], "rms_deg": v["rms_deg"], "sigma": v["sigma"]}
                    for nm, v in bound.items()}
    out["setup_s"] = time.perf_counter() - t0
    steps: dict = {}
    for fi, f in enumerate(frames):
        L = sc.line_integrals(f, renderer=ts._scene_renderer)
        imgs = [_chain(ts, L, f, d) for d in [None, *range(draws)]]
        P = ts.truth(f)
        P_est = _tracked(ts, P, est, f) if est else None
        Lt = tissue_r.render(P[list(sc.tissue_bones)][None], roi="full").numpy()[0].astype(np.float64)
        T = regressor_images(Lt, psf, False)[:, 0]
        for b in bones:
            nm = ts.names[b]
            res = _bone_frame(ts, P, imgs, b, cands, T=T, scale=scale, h=h, rims=rims, P_est=P_est)
            for k, v in res.items():
                steps.setdefault(nm, {}).setdefault(k, []).append(v)
        out["frames_done"] = frames[: fi + 1]
        out["results"] = {nm: {k: _summary(np.array(v), out["bound"][nm]) for k, v in d.items()}
                          for nm, d in steps.items()}
        out["steps"] = {nm: {k: np.round(np.array(v)[:, 0], 6).tolist() for k, v in d.items()}
                        for nm, d in steps.items()}
        out["total_s"] = time.perf_counter() - t0
        print(f"frame {f} done {out['total_s']:.0f}s", flush=True)
        if checkpoint:
            checkpoint(out)
    out["table"] = table(out)
    return out


def table(res: dict) -> list[str]:
    """One line per candidate: each bone's predicted RMS over the bound, mm / °."""
    names = list(res.get("results", {}))
    cands = [c["name"] for c in res.get("candidates", [])]
    lines = []
    for c in cands:
        parts = []
        for nm in names:
            r = res["results"][nm].get(c)
            if r:
                parts.append(f"{nm} {r['over_bound'][0]:.2f}/{r['over_bound'][1]:.2f}")
        lines.append(f"{c}: " + ", ".join(parts))
    return lines


def main(argv=None) -> int:
    p = cli.parser("core.studies.tracking.spread_screen", __doc__)
    p.add_argument("--pixels", type=int, default=512)
    p.add_argument("--voxel", type=float, default=0.5)
    p.add_argument("--frames", default=",".join(map(str, range(0, 100, 10))))
    p.add_argument("--bones", default="0,1,2")
    p.add_argument("--draws", type=int, default=30)
    p.add_argument("--candidates", default=",".join(DEFAULT_CANDIDATES))
    p.add_argument("--device", default="cpu")
    cli.add_output(p)
    a = p.parse_args(argv)
    res = screen(pixels=a.pixels, voxel=a.voxel, frames=cli.ints(a.frames), bones=cli.ints(a.bones),
                 draws=a.draws, candidates=cli.names(a.candidates), device=a.device,
                 checkpoint=cli.checkpoint(a))
    return cli.finish(res, a)


if __name__ == "__main__":
    raise SystemExit(main())
