"""A smooth background fitted instead of the final stage's high-pass (``python -m
core.studies.tracking.background_fit``).

The likelihood final stage (:mod:`core.tracking.final_stage`) high-passes the DRRs and the line
integrals by 4 px (1024²) to take out the smooth soft-tissue background; that throws away the
bone's low-frequency information and leaves its spread 1.1–1.7× the Cramér–Rao bound
(:mod:`core.studies.tracking.stage_limits`). Here the same weighted least-squares refinement
(:class:`core.tracking.likelihood_cost.LikelihoodCost`: gain fitted, the neighbours at their poses
subtracted, weights the expected counts, Gauss–Newton, optionally the stage's robust factors and a
second refinement) runs WITHOUT the high-pass and fits instead a smooth background per view over
the region — a Legendre polynomial of total order ``k`` (``leg<k>``) or a tensor cubic B-spline on
``n`` intervals per axis (``bs<n>``) — against the high-pass form (``hp<σ>``: σ in pixels of a
1024² view, scaled with the size; background a constant) on the same frames.

Frames (the acceptance trial, :class:`core.studies.tracking.acceptance.TrackingScene`, with the
veiling glare measured from lead-disc calibration frames and undone as the correction pipeline
does — never the generator's glare):

* ``true``: the trial's 3 %-wrong inverse, then the TRUE residual warp removed
  (:class:`core.studies.tracking.self_calibration.TrueWarp`; study-only oracle);
* ``grid``: the distortion correction fitted to grid frames (``correction="grid"``, the user's
  path, :mod:`core.studies.tracking.grid_correction`);
* ``true_glare``: as ``true`` with the glare left in (how much the log-domain fit needs it undone).

Each frame is synthesised from its line integrals without noise (the estimate's error there is
its *bias*) and with ``--seeds`` noise draws of the trial's chain (the deviations from the
noise-free estimate are its *spread*); every refinement starts from the true pose with the other
bones at their true poses (the bound's assumption). Per frame set, method and bone: the RMS over
frames of the bias, the mean error per axis, the spread and the RMS error of the noisy estimates
(mm, degrees), each over the trial's Cramér–Rao bound
(:func:`core.studies.tracking.acceptance.cramer_rao`, averaged over the frames). Only this study
reads the truth. ``--components-frames``: also :func:`tissue_residual` (why) and
:func:`component_bias` (noise-free image parts) of those frames.

Measured (``resources/benchmarks/tracking_background_fit_cpu.json``, this 2-core CPU machine, 256²,
1 mm voxels, frames 0/6/12/18, 2 noise draws each — 8 samples per bone, so a spread ratio is
±15-25 %; ratios are over the bound, mm / degrees, tibia, talus, calcaneus): NO smooth background
replaces the high-pass.

* Why: over the stage's regions the soft tissue's line integral reaches 2.6-3.2 (the bone's 0.38-
  0.83) and has skin edges and thickness ramps on the bone's own scale; a Legendre background of
  order 2 / 4 / 6 leaves 0.21-0.51 / 0.18-0.28 / 0.11-0.20 of it (RMS, frame 6), a B-spline on 8 /
  16 intervals 0.05-0.09 / 0.02-0.03 — the size of the bone's own low-frequency signal. On
  noise-free frames of bones and tissue alone the high-pass form is 0.003-0.005 mm from the truth,
  polynomial backgrounds of order 0-4 0.4-4.2 mm, ``bs8+r`` 0.02-0.19 mm; the walkway alone is
  absorbed by any background of order >= 2.
* Oracle frames (``true``): the stage's form ``hp4+r`` RMS 2.86/1.21, 1.63/1.62, 1.80/1.51 (bias
  0.97/0.30, 0.35/0.38, 0.46/0.31; spread 2.48/1.24, 1.54/1.82, 1.60/1.44); ``hp8+r`` 2.22/1.46,
  1.60/1.46, 1.75/1.78. Legendre orders 2-6 are biased by 22-315x the bound (mm), ``bs8+r`` 3-8x,
  ``bs16+r`` (361 regressors a view) 1.1-2.4x / 1.3-3.3x with RMS 2.62/3.80, 2.53/1.99, 2.01/2.25:
  worse than the high-pass in every bone.
* Grid-corrected frames (``grid``, the user's path): ``hp4+r`` 3.29/1.28, 1.67/1.57, 2.30/1.39;
  ``bs16+r`` 2.97/3.26, 2.59/1.99, 1.90/2.18; the polynomials as on ``true``.
* The ceiling of an explicit tissue model (probe ``leg4t+r``: the tissue's TRUE line integral a
  regressor with its own gain, order-4 background, no high-pass), against ``hp4+r`` on the same
  frames with 4 draws (``four_draws``, 16 samples per bone): on ``true`` spread 1.61/0.89,
  1.08/1.00, 1.31/1.22 against 2.14/1.20, 1.61/1.63, 1.90/1.82, RMS 2.38/0.92, 1.13/1.04,
  1.56/1.22 against 2.50/1.30, 1.68/1.50, 1.99/1.83; on ``grid`` RMS 3.64/1.18, 1.20/1.08,
  2.31/1.32 against 2.97/1.36, 1.66/1.43, 2.33/1.80 (the tibia and calcaneus biased 1.5-2.7x in
  translation there; the estimated PSF on the DRR, ``leg4tp+r``, changes little). What biases
  them (:mod:`core.studies.tracking.tissue_regressor`): not the neighbours subtracted unblurred
  (the PSF is 0.3 px at 256²; they are now blurred when a PSF is given), but the grid's leftover
  distortion (the tibia's bias doubles from oracle to grid frames in every form) and, without
  high-pass, the calcaneus's bone and skin edges, biased on oracle frames too.
  What the high-pass costs is real — the talus's spread falls to the bound with the tissue known —
  but only a model of the tissue's shape buys it back, not a smooth basis; a user's tissue volume
  at estimated poses does so only under a (wider, 8 px) high-pass (tissue_regressor).
* Veiling glare must be undone for it: measured from disc frames (fraction 0.0497/0.0498, σ 17.0
  px; the generator's 0.05) and undone in ``true`` and ``grid``; left in (``true_glare``) the
  probe's bias grows to 1.7/0.5, 1.5/1.0, 2.5/2.1x while ``hp4+r`` does not move (0.7/0.3,
  0.4/0.4, 0.4/0.3x).

What the device stage (:mod:`core.tracking.engine_likelihood`) would need for ``q`` background
regressors a view (not recommended for the smooth bases): its per-pixel table ``Σ w z zᵀ`` of
``z = (y, D, δ_1…δ_6, 1, u, v, O)`` (12 × 12 in each thread's registers) grows to ``8 + q + 1``
entries; the products among ``(y, O, b_1…b_q)`` do not move with the pose and could be summed
once per frame and per set of weights, leaving ``7 · (9 + q)`` per step (D and the six δ against
everything), and :func:`~core.tracking.engine_likelihood.solve_moments` a ``(1 + q [+ 1])``-square
solve per view; the two blur passes of the high-pass would go. Order-4 Legendre: q = 15; a
tissue regressor: one more entry (like ``O``), rendered per frame at the neighbours' poses or,
for the bones the tissue follows (calcaneus, tibia), with the step's 13 poses.

JSON on stdout (``--out``: also to a file, rewritten after each frame).
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from core.studies.tracking import _study_cli as cli

__all__ = ["FRAME_SETS", "METHODS", "frame_images", "method", "run", "summarise"]

#: frame sets (module docs)
FRAME_SETS = ("true", "grid", "true_glare")

#: methods: ``hp<σ>`` the high-pass form (σ px at 1024², scaled; constant background),
#: ``leg<k>`` a Legendre background of total order k, ``bs<n>`` a cubic B-spline on n intervals
#: per axis, no high-pass; ``+r`` the stage's robust factors (Cauchy 2.5, 2 px) and a second
#: refinement; ``+r<k>`` with threshold k; ``d<px>`` after the base: only the bone's footprint
#: grown by px (at 1024², scaled); ``t`` after the base: the soft tissue's true line integral a
#: regressor with its own coefficient (study probe, :func:`tissue_images`); ``p``: the DRRs
#: blurred by the PSF estimated from pinhole calibration frames (:func:`estimated_psf`)
METHODS = ("hp4+r", "hp4", "hp8+r", "leg2+r", "leg4+r", "leg6+r", "bs8+r", "bs16+r")


def method(name: str, pixels: int) -> tuple[dict, dict]:
    """``(LikelihoodCost options, refine options)`` of a method name (:data:`METHODS`)."""
    base, _, rob = name.partition("+")
    flags = base[len(base.rstrip("tp")):]
    base = base.rstrip("tp")
    dil = None
    if "d" in base.lstrip("bs"):  # a support: the bone's footprint grown by <px> at 1024², scaled
        base, _, d = base.rpartition("d")
        dil = max(1, round(float(d) * pixels / 1024))
    refine = {}
    if rob:
        refine["robust"] = float(rob[1:]) if len(rob) > 1 else 2.5
    if base.startswith("hp"):
        cost = {"highpass_px": float(base[2:]) * pixels / 1024, "background": 0}
    elif base.startswith("leg"):
        cost = {"background": int(base[3:]), "basis": "legendre"}
    elif base.startswith("bs"):
        cost = {"background": int(base[2:]), "basis": "bspline"}
    else:
        raise ValueError(f"method: expected hp<σ>, leg<k> or bs<n> (d<px>) (+r), got {name!r}")
    if dil is not None:
        cost["dilate"] = dil
    if "t" in flags:
        cost["tissue"] = True
    if "p" in flags:
        cost["psf"] = True
    return cost, refine


class _Sources:
    """The frame sets' scenes (built on demand) and their frames from the line integrals."""

    def __init__(self, pixels: int, voxel: float, n_frames: int, seed: int, device) -> None:
        self.kw = {"n_frames": n_frames, "pixels": pixels, "spacing": voxel, "seed": seed,
                   "phase": (0.0, 0.6 * n_frames / 100.0), "device": device}
        self._scenes: dict = {}
        self._warp: dict = {}

    def scene(self, name: str):
        from core.studies.tracking.acceptance import TrackingScene

        key = {"true": ("model", True), "grid": ("grid", True), "true_glare": ("model", False)}[name]
        if key not in self._scenes:
            self._scenes[key] = TrackingScene(correction=key[0], glare=key[1], **self.kw)
        return self._scenes[key]

    def warp(self, name: str):
        from core.studies.tracking.self_calibration import TrueWarp

        ts = self.scene(name)
        if id(ts) not in self._warp:
            self._warp[id(ts)] = TrueWarp(ts)
        return self._warp[id(ts)]


def frame_images(src: _Sources, name: str, L, seed: int | None) -> list[np.ndarray]:
    """Frame set ``name``'s corrected fluence images of line integrals ``L`` (views, H, W);
    ``seed`` None = noise-free (no quanta, no read noise)."""
    ts = src.scene(name)
    out = []
    for v, m in enumerate(ts.scene.imaging):
        mm = m if seed is not None else replace(m, photons_per_pixel=None, read_noise_dn=0.0)
        raw = mm.apply(L[v], rng=None if seed is None else np.random.default_rng([seed, v, 2027]))
        out.append(ts.correct(v, raw))
    if name.startswith("true"):
        out = src.warp(name).frames(lambda i, out=out: out)(0)
    return out


def tissue_images(ts, f: int) -> np.ndarray:
    """``(views, H, W)`` the soft tissue's line integrals of frame ``f`` at its true poses as the
    frame shows them (through the generator's PSF in the fluence domain): the study probe of a
    known tissue shape (method suffix ``t``; the generator's truth, never a user's)."""
    from core.similarity.likelihood import blur
    from core.studies.tracking.stage_limits import _psf

    sc = ts.scene
    P = sc.poses(f)[list(sc.tissue_bones)]
    Lt = ts._scene_renderer._tissue.render(P[None], roi="full").numpy()[0].sum(axis=1)
    return np.stack([-np.log(np.maximum(blur(np.exp(-x), _psf(ts, v)), 1e-12)) for v, x in enumerate(Lt)])


def _crop(img: np.ndarray, roi) -> np.ndarray:
    u0, v0, w, h = (int(x) for x in roi)
    p = max(0, -u0, -v0, u0 + w - img.shape[1], v0 + h - img.shape[0])
    a = np.pad(img, p, mode="edge") if p else img
    return a[v0 + p:v0 + p + h, u0 + p:u0 + p + w]


_PSF: dict = {}


def estimated_psf(ts) -> np.ndarray:
    """The PSF estimated from synthetic pinhole calibration frames of view 0's chain (what a lab
    measures, :func:`core.studies.tracking.bound_gap.estimated_psf`; method suffix ``p``)."""
    if id(ts.scene) not in _PSF:
        from core.studies.tracking.bound_gap import estimated_psf as est

        _PSF[id(ts.scene)] = est(ts)[0]
    return _PSF[id(ts.scene)]


def _fit(ts, frame, f: int, b: int, name: str, pixels: int, margin_px: int, tissue=None) -> np.ndarray:
    from core.studies.tracking.acceptance import pose_errors
    from core.tracking.cost import search_roi, snap_roi
    from core.tracking.likelihood_cost import LikelihoodCost

    P = ts.truth(f)
    m = ts.models[b]
    views = tuple(range(len(ts.scene.rig)))
    roi = snap_roi(search_roi(ts.renderer, P[b], b, views=views, center=m.centroid, reach_mm=1.0,
                              margin_px=margin_px), ts.renderer, views)
    oth = [k for k in range(len(ts.names)) if k != b]
    co, ro = method(name, pixels)
    if co.pop("psf", False):
        co["psf"] = estimated_psf(ts)
    if co.pop("tissue", False):
        co["regressors"] = [_crop(tissue[v], roi[i]) for i, v in enumerate(views)]
    cost = LikelihoodCost(ts.renderer, frame, bone=b, base_pose=P[b], center=m.centroid, roi=roi,
                          others=(P[oth], oth) if oth else None, others_gain=False, **co)
    r = cost.refine(iters=6, **ro)
    return pose_errors(cost.poses(np.asarray(r["x"])[None])[0], P[b], m.centroid)


def tissue_residual(ts, f: int, fits=(("legendre", 2), ("legendre", 4), ("legendre", 6), ("bspline", 8),
                                       ("bspline", 16))) -> dict:
    """Why a smooth background is not enough: per bone and view, the RMS over the stage's region
    of the soft tissue's line integral (frame ``f``, true poses; noise-free, no blur) and of what
    is left of it after an unweighted least-squares fit of each background in ``fits``
    (``(basis, order)``), against the bone's largest line integral there."""
    from core.tracking.cost import search_roi, snap_roi
    from core.tracking.likelihood_cost import background_basis

    sc = ts.scene
    P = sc.poses(f)
    Lt = ts._scene_renderer._tissue.render(P[list(sc.tissue_bones)][None], roi="full").numpy()[0].sum(axis=1)
    Lb = ts._scene_renderer._bones.render(P[None], roi="full").numpy()[0]
    views = tuple(range(len(sc.rig)))
    out = {}
    for b, nm in enumerate(ts.names):
        roi = snap_roi(search_roi(ts.renderer, P[b], b, views=views, center=ts.models[b].centroid,
                                  reach_mm=1.0, margin_px=4), ts.renderer, views)
        rows = []
        for i, v in enumerate(views):
            T = _crop(Lt[v].astype(np.float64), roi[i])
            r = {"region_px": [int(roi[i][2]), int(roi[i][3])], "tissue_max": float(T.max()),
                 "tissue_rms_about_mean": float(T.std()),
                 "bone_max": float(_crop(Lb[v, b].astype(np.float64), roi[i]).max())}
            for basis, k in fits:
                R = background_basis(T.shape, k, basis).reshape(-1, T.size).T
                res = T.ravel() - R @ np.linalg.lstsq(R, T.ravel(), rcond=None)[0]
                r[f"{basis}{k}_residual_rms"] = float(np.sqrt(np.mean(res**2)))
            rows.append(r)
        out[nm] = rows
    return out


def component_bias(ts, f: int, methods, pixels: int, margin_px: int = 4,
                   configs=("bones+tissue", "bones+floor", "all")) -> dict:
    """Per image part (:func:`core.studies.tracking.stage_limits.component_frames`, noise-free)
    and method, each bone's error ``(6,)`` (mm, degrees) from the true pose: which part biases it."""
    from core.studies.tracking.stage_limits import component_frames
    from core.tracking.cost import prepare_frame

    tissue = tissue_images(ts, f) if any(method(m, pixels)[0].get("tissue") for m in methods) else None
    out: dict = {}
    for cfg, imgs in component_frames(ts, f, configs).items():
        fr = prepare_frame(imgs)
        for m in methods:
            out.setdefault(cfg, {})[m] = {
                nm: np.round(_fit(ts, fr, f, b, m, pixels, margin_px, tissue), 5).tolist()
                for b, nm in enumerate(ts.names)}
    return out


def summarise(free, noisy, bound: dict | None) -> dict:
    """Statistics of the noise-free errors ``free (frames, 6)`` and the noisy ones ``noisy
    (frames, seeds, 6)`` (mm, degrees; module docs), over ``bound`` (``rms_mm``, ``rms_deg``,
    ``sigma``) when given."""
    E0 = np.asarray(free, float)
    En = np.asarray(noisy, float)
    dev = (En - E0[:, None]).reshape(-1, 6)
    tot = En.reshape(-1, 6)

    def rms3(X):
        return float(np.sqrt(np.mean(np.sum(X**2, axis=1))))

    s = {"bias_mm": rms3(E0[:, :3]), "bias_deg": rms3(E0[:, 3:]),
         "mean_error": E0.mean(axis=0).round(5).tolist(),
         "spread_mm": rms3(dev[:, :3]), "spread_deg": rms3(dev[:, 3:]),
         "rms_mm": rms3(tot[:, :3]), "rms_deg": rms3(tot[:, 3:]),
         "spread_axis": np.sqrt(np.mean(dev**2, axis=0)).round(5).tolist()}
    if bound:
        for k in ("bias", "spread", "rms"):
            s[f"{k}_over_bound"] = [round(s[f"{k}_mm"] / bound["rms_mm"], 3),
                                    round(s[f"{k}_deg"] / bound["rms_deg"], 3)]
        ratio = np.asarray(s["spread_axis"]) / np.asarray(bound["sigma"])
        s["spread_axis_over_sigma"] = ratio.round(3).tolist()
    return s


def run(*, pixels: int = 256, voxel: float = 1.0, n_frames: int = 20, frames=range(0, 20, 2), seeds: int = 2,
        sets=("true", "grid"), methods=METHODS, bones=None, seed: int = 0, device: str | None = "cpu",
        components_frames=(), component_methods=("hp4+r", "leg0", "leg2", "leg4", "leg4t+r"),
        checkpoint=None) -> dict:
    """Run the study (module docs); returns the JSON-ready results. ``components_frames``: also
    :func:`tissue_residual` and :func:`component_bias` (``component_methods``) of those frames."""
    from core.studies.tracking.acceptance import cramer_rao
    from core.tracking.cost import prepare_frame
    from core.tracking.register import RegistrationOptions

    t0 = time.perf_counter()
    frames = [int(f) for f in frames]
    src = _Sources(pixels, voxel, n_frames, seed, device)
    ts0 = src.scene(sets[0])
    names = ts0.names
    bones = list(range(len(names))) if bones is None else [int(b) for b in bones]
    margin = RegistrationOptions().margin_px
    out = cli.header("core.studies.tracking.background_fit", pixels=pixels, voxel_mm=voxel, frames=frames,
                     seeds=seeds, sets=list(sets),
                     methods={m: dict(zip(("cost", "refine"), method(m, pixels), strict=True))
                              for m in methods},
                     glare_measured=[{"fraction": g.fraction, "sigma_px": g.sigma_px}
                                     for g in src.scene(sets[0]).glare],
                     generator_glare_fraction=[m.glare_fraction for m in ts0.scene.imaging])
    bound = cramer_rao(ts0, frames)
    out["bound"] = bound
    out["setup_s"] = time.perf_counter() - t0
    errs: dict = {}
    for f in frames:  # (no frames: only the parts' test)
        L = ts0.scene.line_integrals(f, renderer=ts0._scene_renderer)
        tissue = tissue_images(ts0, f) if any(method(m, pixels)[0].get("tissue") for m in methods) else None
        for st in sets:
            ts = src.scene(st)
            for s in [None, *range(seeds)]:
                frame = prepare_frame(frame_images(src, st, L, None if s is None else 1000 * f + s))
                for mth in methods:
                    for b in bones:
                        e = _fit(ts, frame, f, b, mth, pixels, margin, tissue)
                        d = errs.setdefault(st, {}).setdefault(mth, {}).setdefault(names[b], {"free": [],
                                                                                             "noisy": []})
                        if s is None:
                            d["free"].append(e)
                            d["noisy"].append([])
                        else:
                            d["noisy"][-1].append(e)
        out["results"] = {st: {mth: {nm: summarise(d["free"], d["noisy"], bound.get(nm))
                                     for nm, d in bm.items()} for mth, bm in sm.items()}
                          for st, sm in errs.items()}
        cli.frame_done(out, f, t0, checkpoint, frames[: frames.index(f) + 1])
    for f in components_frames:
        out.setdefault("tissue_residual", {})[str(f)] = tissue_residual(ts0, f)
        out.setdefault("components", {})[str(f)] = component_bias(ts0, f, component_methods, pixels, margin)
        out["total_s"] = time.perf_counter() - t0
        if checkpoint:
            checkpoint(out)
    return out


def main(argv=None) -> int:
    p = cli.parser("core.studies.tracking.background_fit", __doc__)
    cli.add_scene(p, frames="0,2,4,6,8,10,12,14,16,18", sets="true,grid")
    p.add_argument("--methods", default=",".join(METHODS))
    p.add_argument("--bones", default="", help=cli.BONES_HELP)
    p.add_argument("--components-frames", default="", help="frames of the noise-free parts' test")
    p.add_argument("--component-methods", default="hp4+r,leg0,leg2,leg4,leg4t+r")
    cli.add_output(p)
    a = p.parse_args(argv)
    res = run(pixels=a.pixels, voxel=a.voxel, n_frames=a.n_frames, frames=cli.ints(a.frames), seeds=a.seeds,
              sets=cli.names(a.sets), methods=cli.names(a.methods), bones=cli.ints(a.bones) or None,
              components_frames=cli.ints(a.components_frames),
              component_methods=cli.names(a.component_methods), checkpoint=cli.checkpoint(a))
    return cli.finish(res, a)


if __name__ == "__main__":
    raise SystemExit(main())
