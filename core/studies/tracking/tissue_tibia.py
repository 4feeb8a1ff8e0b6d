"""Why the soft-tissue regressor costs the tibia in tracking (``python -m
core.studies.tracking.tissue_tibia``).

The likelihood final stage's tissue regressor (:attr:`core.tracking.final_stage.FinalModel.tissue`;
:mod:`core.studies.tracking.tissue_stage`) took the talus to 1.17/1.18× its Cramér–Rao bound at the
8 px high-pass but the tibia from 1.72/1.46 to 1.92/1.66 (one NVIDIA H200, 1024², three bones
jointly). Hypotheses: (a) the tissue is rendered at the tracker's estimate of the tibia's pose and
its own pose derivative is left out of the step, so a wrong pose pulls the estimate; (b) the 4 mm
resampling is too coarse for the shank's skin; (c) the tissue's gain, nearly collinear with the
tibia, is poorly determined; (d) something specific to the size.

:func:`bias` (``--bias``, CPU): the first-order bias of each bone's stage (a Gauss–Newton step of
the stage's model — gain, constant and the tissue's free gain fitted linearly, the neighbours
subtracted at gain 1, weights the expected counts, high-pass σ ``highpass`` px at 1024² scaled —
from the TRUE pose: ``(JᵀJ)⁻¹ Jᵀ r``) on NOISE-FREE grid-corrected frames of the 100-frame
acceptance trial (so frame ``f`` is the same phase of stance as the GPU trial's), without a tissue
regressor (``none``) and with each volume of :func:`~core.studies.tracking.tissue_regressor.
user_tissue` (``exact`` the generator's 3 mm volume, ``fine`` 2 mm, ``coarse`` 4 mm), rendered at
the true poses through the estimated PSF. For the bones a tissue part follows (tibia, calcaneus)
also: ``<kind>_deriv`` — the tissue's own pose derivative (the parts following the bone rendered at
the step's 13 poses) added to the bone's in the step (hypothesis a's remedy); ``<kind>_est`` — the
tissue rendered at the TRACKER's poses of that frame (``est_json``: the per-frame errors of the
tracker run of ``resources/benchmarks/tracking_tissue_stage_h200.json``, three bones jointly, the
poses the device stage renders it at). On frames 0 and 50 of the tibia a full refinement
(:class:`~core.tracking.likelihood_cost.LikelihoodCost`, 6 steps) gave the same signs and sizes
(below; up to 13 µm apart).

:func:`run` (GPU): the acceptance trial tracked with the stage at the 8 px high-pass, three bones
jointly (``three``) and the tibia alone (``tibia``: only the shank part follows a tracked bone),
per-bone stage settings (:attr:`~core.tracking.final_stage.FinalModel.bones`): no tissue, the 4 mm
tissue for every bone, the tissue for every bone but the tibia (``BoneStage(tissue=False)``), that
with the tibia's own 4 px high-pass, the 2 mm tissue for every bone. Per run as
:mod:`core.studies.tracking.tissue_stage` (its ``_record``).

Measured (this 2-core CPU machine, :func:`bias`, 256², 1 mm voxels, frames 0, 10, …, 90, high-pass
2 px; ``resources/benchmarks/tracking_tissue_tibia_cpu.json``), RMS over the frames of the bias,
µm / millidegrees (the bound of these frames, for scale: tibia 18 µm / 111 mdeg):

* At this size the tibia's bias is not the tissue's: ``none`` 37.8 / 68.7, ``exact`` 37.7 / 55.4, ``fine``
  37.2 / 63.7 — even the generator's own volume at the true poses takes nothing off its
  translation (that bias is the grid correction's leftover distortion,
  :mod:`core.studies.tracking.tissue_regressor`). The 4 mm volume adds an error of its own:
  ``coarse`` 46.0 / 87.2. Its change against ``none`` in x over frames 0, 10, …, 90 is −15, −11,
  6, 12, 17, 18, 17, 11, 9, 2 µm — the H200's tracking (``hp8_tissue`` − ``hp8``, same frames,
  1024²) −11, −8, 6, 16, 17, 18, 15, 8, 8, 1 µm. The degradation in tracking is this
  pose-dependent offset, reproduced from the true poses at a quarter of the size (so not
  hypothesis d). :func:`core.studies.tracking.tissue_stage.probe` missed it because its 20-frame
  trial spans only the first 11 % of stance (this trial's frames 0-19), where the offset is
  negative and cancelled the tibia's positive bias (its mean x error 20 → 7 µm with the tissue).
  Over the 100 tracked frames a 5th-order polynomial in the frame index explains 91 % of the
  offset's variance in x and y, the tracker's own errors 29-32 %. The 4 mm volume's line integral
  differs from the generator's volume's by 0.006-0.008 RMS in the high-passed band over the
  tibia's two regions (frame 50) — a quarter to a third of the tibia's own high-passed DRR there
  (0.024-0.028) — in stripes from the resampling of the 3 mm grid and at the smoothed skin and
  the cut top of the shank; where these cross the shaft's edges and the malleoli they move the
  tibia (each pixel's share of the bias, ``(JᵀJ)⁻¹ Jᵀ``, is largest along the shaft's edges).
* Not the gain (c): the 4 mm volume's fitted gain is 1.22-1.26 per view (``exact`` 1.01-1.02, the
  high-passed band of a smoother volume is weaker), yet held at 1 a full refinement (6 steps,
  :class:`~core.tracking.likelihood_cost.LikelihoodCost`) gives the same (x at frames 0 / 50: 1.4
  / 62.1 µm against −2.1 / 67.0 with the gain free, ``none`` 15.3 / 41.7; the first-order bias:
  −1.3 / 54.3 and 13.5 / 36.0).
* Not the estimated poses (a): rendered at the H200 tracker's poses of the same frames
  (``coarse_est``) 46.1 / 87.1 against 46.0 / 87.2 at the true poses (the pull matrix's entries
  are 0.03 or less on average over the frames, 0.04-0.08 at most); the tissue's own pose
  derivative in the step makes every volume worse (``coarse_deriv`` 56.6 / 208.1, ``exact_deriv``
  44.0 / 85.7; the calcaneus 288-357 µm): the step then takes pose information from the tissue's
  skin, which no user's volume has exactly.
* Not the ray step: in a side check (same frames; the tissue projected out after the fit, where
  ``coarse`` gave 47.0 / 88.7 and ``none`` 37.8 / 68.7) the 4 mm volume rendered with a 0.5 mm
  step instead of its 4 mm gave 48.0 / 84.2; smoothed by 2 / 4 / 8 px (at 1024²) 46.4 / 44.5 /
  40.7 µm — towards ``none`` as its high-passed band fades.
* The talus's bias is the tissue's: ``none`` 43.1 / 224.8, ``exact`` 16.1 / 66.2, ``fine`` 16.9 /
  72.8, ``coarse`` 24.0 / 107.6 (bound 48 µm / 211 mdeg); the calcaneus ``none`` 37.5 / 75.1,
  ``exact`` 36.8 / 45.2, ``fine`` 33.0 / 49.5, ``coarse`` 33.2 / 59.7.
* 512² (0.5 mm voxels, tibia and talus, same frames; in the JSON under ``size_512``): the tibia
  ``none`` 93.9 / 117.4, ``exact`` 91.9 / 102.7, ``fine`` 91.5 / 107.2, ``coarse`` 92.2 / 127.0
  (frames 70-90 carry a grid bias of 60-200 µm there; over frames 0-60 ``none`` 26.8 / 65.7,
  ``exact`` 21.8 / 48.4, ``fine`` 24.1 / 49.3, ``coarse`` 30.3 / 74.4: at this size some of the
  tibia's bias is the tissue's, and still the 4 mm volume adds more than it takes); the talus
  ``none`` 18.5 / 111.0, ``exact`` 8.2 / 21.0, ``fine`` 6.1 / 22.9, ``coarse`` 7.8 / 38.6; the
  tibia's ``coarse_est`` 92.1 / 126.8 against ``coarse`` 92.2 / 127.0.

So the tibia gains little from a tissue model and the user's 4 mm volume costs it more than that,
while the talus (and the calcaneus's rotation) gain much: the remedy is a finer (2 mm) volume,
which does not cost the tibia and brings the talus near the exact volume's bias, or, per bone,
the tissue regressor off for the tibia (``FinalModel(tissue=…, bones={tibia:
BoneStage(tissue=False)})``).

Confirmed in tracking (:func:`run`, one NVIDIA H200, ``resources/benchmarks/
tracking_tissue_tibia_h200.json``; 1024², 100 frames, grid correction, the stage at the 8 px
high-pass; RMS over the bound mm/°, tibia, talus, calcaneus; frames over 4× the bound, all silent,
in brackets where any):

* three bones jointly: no tissue 1.72/1.45 (2), 1.31/1.32, 1.16/1.42; the 4 mm tissue for every
  bone 1.92/1.66 (2), 1.17/1.18, 1.15/1.35 (the earlier measurement, to 0.01); the same without
  it in the tibia's stage 1.72/1.45 (2), 1.17/1.18, 1.15/1.35 — the tibia back where it was, the
  talus's gain kept; with the tibia's own 4 px high-pass as well 1.56/1.42, 1.17/1.19, 1.15/1.34,
  no frame over 4×; the 2 mm tissue for every bone 1.54/1.36 (1), 1.15/1.19, 1.12/1.30 — the
  best of all for every bone, the tibia too. The stage 18.6 / 19.6 / 19.2 / 17.1 / 19.5 ms per
  bone-frame.
* a second call (``second_call`` in the JSON; the stage of 0bd08eb, with its blurred design
  differences): the 2 mm tissue again 1.54/1.36 (1), 1.15/1.19, 1.12/1.30; with the tibia's own
  4 px high-pass 1.54/1.41, 1.15/1.20, 1.11/1.29 and no frame over 4×; that without the tissue in
  the tibia's stage 1.56/1.42, 1.15/1.19, 1.11/1.29. The stage 19.4 / 17.2 / 17.0 ms.
* the tibia alone (its shank tissue only): no tissue 1.87/1.67 (3), the 4 mm tissue 2.02/1.74
  (3), the 2 mm tissue 1.70/1.62 (3), the 4 px high-pass without tissue 1.51/1.53 (none).
* the talus's confidence covers less with any tissue: 2σ holds in 79 % (4 mm) and 76 % (2 mm) of
  its frames against 93 % without.

* with the stage's band at the round field's rim (``_rim`` labels, ``FinalModel(rim_sigmas=3.0)``,
  the 2 mm tissue; measured again after its fix on one NVIDIA H100,
  ``resources/benchmarks/tracking_rim_band_fixed_h100.json``): three jointly tibia 1.54/1.36 (1) →
  1.41/1.34, talus 1.15/1.19 unchanged, calcaneus 1.12/1.30 → 1.11/1.31; the tibia alone 1.70/1.62
  (3) → 1.45/1.68 (1); with the tibia's stage at 4 px jointly 1.54/1.41 → 1.53/1.40, alone
  1.47/1.53 → 1.47/1.50 — opt-in, and why: :mod:`core.tracking.likelihood_rim` (the first run,
  ``tracking_rim_band_h200.json``, had also banded a dense overlap inside the field). A ``_rim``
  run records its band caches' counts (``rim_cache``).

What to use: a tissue volume of 2 mm (``tissue_regressor.user_tissue("fine")``: the lab's soft
tissue at 2 mm, not 4), for every bone, the tibia's stage at 4 px (``BoneStage(highpass_px=4.0)``:
the same ratios within 0.05, no frame over 4×); with only a 4 mm volume, the tissue off in the
tibia's stage (``BoneStage(highpass_px=4.0, tissue=False)``). The tibia stays at 1.5× its bound
in translation with any of them, the rotations at 1.2-1.4×. Nothing in the stage's tissue
path (:mod:`core.tracking.likelihood_tissue`) was wrong: the regressor is rendered and fitted as
intended, and the error is the volume's.

JSON on stdout (``--out``: also to a file, rewritten as it goes).
"""

from __future__ import annotations

import json
import platform
import time
from dataclasses import replace

import numpy as np

from core.studies.tracking import _study_cli as cli

__all__ = ["bias", "main", "run"]

#: the tracker's per-frame errors :func:`bias` renders the tissue at (``_est`` variants)
EST_JSON = "resources/benchmarks/tracking_tissue_stage_h200.json"


def _est_errors(path: str = EST_JSON) -> dict:
    """Per bone name the ``(frames, 6)`` errors (mm, degrees) of the tracker run (no stage, three
    bones jointly) of ``path``, or {} where it is missing."""
    try:
        with open(path) as fh:
            d = json.load(fh)
    except OSError:
        return {}
    t = d.get("three", {}).get("tracker", {})
    return {nm: np.asarray(v["error"], float) for nm, v in t.items() if isinstance(v, dict) and "error" in v}


def _moved(P: np.ndarray, e: np.ndarray, center: np.ndarray) -> np.ndarray:
    """``P`` moved by the error ``e`` (mm at ``center``, degrees): the pose whose
    :func:`~core.studies.tracking.acceptance.pose_errors` against ``P`` is ``e``."""
    from core.geometry.transforms import pose_from_params

    p = np.r_[e[:3], np.radians(e[3:])]
    return pose_from_params(p[None], center=center, base=P)[0]


def _view_terms(cost, D, T, v: int, roi, hp: float, h: float):
    """One view's projected Jacobians and residual at the true pose: ``(JD, JT, r)`` (``JT`` None
    without a tissue; ``T`` the tissue regressor images of the 13 poses (or one), as the frame shows
    them, full frame)."""
    from core.similarity.likelihood import highpass
    from core.studies.tracking.background_fit import _crop

    Dv = cost._filtered(D[v]).astype(float)
    dD = (Dv[1:7] - Dv[7:13]) / (2 * h)
    W = cost.weights[v]
    sel = W > 0
    sw = np.sqrt(W[sel])
    cols = [Dv[0][sel], np.ones(sel.sum())]
    Tc = None
    if T is not None:
        Tc = np.stack([highpass(_crop(t, roi).astype(np.float64), hp).astype(float) for t in T])
        cols.append(Tc[0][sel])
    A = np.column_stack(cols) * sw[:, None]
    Q, _ = np.linalg.qr(A)
    y = cost.fluoro_rois[v][sel] * sw
    coef = np.linalg.lstsq(A, y, rcond=None)[0]
    r = y - Q @ (Q.T @ y)
    JD = dD[:, sel] * sw * coef[0]
    JD = JD - (JD @ Q) @ Q.T
    JT = None
    if Tc is not None and len(Tc) == 13:
        JT = (Tc[1:7] - Tc[7:13])[:, sel] / (2 * h) * sw * coef[2]
        JT = JT - (JT @ Q) @ Q.T
    return JD, JT, r, coef


def bias(*, pixels: int = 256, voxel: float = 1.0, frames=range(0, 100, 10), bones=(0, 1, 2),
         kinds=("exact", "fine", "coarse"), highpass: float = 8.0, device: str | None = "cpu",
         est_json: str = EST_JSON, checkpoint=None) -> dict:
    """The first-order bias of each bone's stage from the true pose on noise-free grid frames, per
    tissue volume (module docs; study only: reads the truth). Per bone and variant: the bias per
    frame (µm, millidegrees), its RMS over the frames, the fitted tissue gains; ``pull`` (bones a
    tissue part follows): the mean over the frames of ``M`` — a tissue rendered at the bone's pose
    off by ``d`` moves the estimate by ``-M d`` to first order."""
    from core.render import DRRRenderer
    from core.studies.tracking.acceptance import cramer_rao
    from core.studies.tracking.background_fit import _Sources, estimated_psf, frame_images
    from core.studies.tracking.tissue_regressor import regressor_images, user_tissue
    from core.tracking.cost import prepare_frame, search_roi, snap_roi
    from core.tracking.likelihood_cost import LikelihoodCost

    t0 = time.perf_counter()
    frames = [int(f) for f in frames]
    src = _Sources(pixels, voxel, 100, 0, device)
    ts = src.scene("grid")
    sc = ts.scene
    psf = np.asarray(estimated_psf(ts), float)
    hp = highpass * pixels / 1024
    views = tuple(range(len(sc.rig)))
    tb = list(sc.tissue_bones)
    est = _est_errors(est_json)
    rend = {k: DRRRenderer(sc.rig, [v.to_attenuation(sc.tissue_transfer) for v in user_tissue(sc, k)],
                           device=device) for k in kinds}
    out = {"study": "core.studies.tracking.tissue_tibia --bias", "machine": platform.machine(),
           "pixels": pixels, "voxel_mm": voxel, "frames": frames, "highpass_px_at_1024": highpass,
           "kinds": list(kinds),
           "est_json": est_json if est else None}
    bound = cramer_rao(ts, frames)
    out["bound"] = {nm: {"rms_mm": v["rms_mm"], "rms_deg": v["rms_deg"]} for nm, v in bound.items()}
    out["setup_s"] = time.perf_counter() - t0
    h = 0.05
    X = np.concatenate([np.zeros((1, 6)), np.eye(6) * h, -np.eye(6) * h])
    B: dict = {}
    gains: dict = {}
    pulls: dict = {}
    for fi, f in enumerate(frames):
        L = sc.line_integrals(f, renderer=ts._scene_renderer)
        fr = prepare_frame(frame_images(src, "grid", L, None))
        P = ts.truth(f)
        Pt = P[tb]
        for b in bones:
            nm, m = ts.names[b], ts.models[b]
            oth = [k for k in range(len(ts.names)) if k != b]
            roi = snap_roi(search_roi(ts.renderer, P[b], b, views=views, center=m.centroid, reach_mm=1.0,
                                      margin_px=4), ts.renderer, views)
            cost = LikelihoodCost(ts.renderer, fr, bone=b, base_pose=P[b], center=m.centroid, roi=roi,
                                  others=(P[oth], oth), others_gain=False, highpass_px=hp, background=0)
            D = cost._render(X)
            Pb = cost.poses(X)
            follows = b in tb

            def solve(terms, key, nm=nm):
                JJ = sum(J @ J.T for J, _ in terms)
                Jr = sum(J @ r for J, r in terms)
                B.setdefault(nm, {}).setdefault(key, []).append(1000 * np.linalg.solve(JJ, Jr))

            solve([_view_terms(cost, D, None, v, roi[i], hp, h)[::2] for i, v in enumerate(views)], "none")
            for k in kinds:
                if follows:
                    Pk = np.stack([np.stack([Pb[i] if tb[j] == b else Pt[j] for j in range(len(tb))])
                                   for i in range(13)])
                else:
                    Pk = Pt[None]
                Lt = rend[k].render(Pk, roi="full").numpy().astype(np.float64)  # (poses, views, parts, H, W)
                terms = [_view_terms(cost, D, [regressor_images(Lt[j, v:v + 1], psf, False)[0, 0]
                                               for j in range(len(Pk))], v, roi[i], hp, h)
                         for i, v in enumerate(views)]
                solve([(JD, r) for JD, _, r, _ in terms], k)
                gains.setdefault(nm, {}).setdefault(k, []).append([round(float(c[2]), 4) for *_, c in terms])
                if not follows:
                    continue
                solve([(JD + JT, r) for JD, JT, r, _ in terms], k + "_deriv")
                JJ = sum(JD @ JD.T for JD, *_ in terms)
                pulls.setdefault(nm, {}).setdefault(k, []).append(
                    np.linalg.solve(JJ, sum(JD @ JT.T for JD, JT, *_ in terms)))
                if est and all(ts.names[tb[j]] in est for j in range(len(tb))):
                    Pe = np.stack([_moved(P[tb[j]], est[ts.names[tb[j]]][f], ts.models[tb[j]].centroid)
                                   for j in range(len(tb))])
                    Le = rend[k].render(Pe[None], roi="full").numpy().astype(np.float64)
                    terms = [_view_terms(cost, D, [regressor_images(Le[0, v:v + 1], psf, False)[0, 0]], v,
                                         roi[i], hp, h) for i, v in enumerate(views)]
                    solve([(JD, r) for JD, _, r, _ in terms], k + "_est")
        res = {}
        for nm, d in B.items():
            res[nm] = {}
            for key, E in d.items():
                E = np.asarray(E)
                res[nm][key] = {"rms_um": round(float(np.sqrt(np.mean(np.sum(E[:, :3] ** 2, 1)))), 2),
                                "rms_mdeg": round(float(np.sqrt(np.mean(np.sum(E[:, 3:] ** 2, 1)))), 2),
                                "mean": E.mean(0).round(2).tolist(), "per_frame": E.round(2).tolist()}
                g = gains.get(nm, {}).get(key)
                if g:
                    res[nm][key]["tissue_gain_per_view"] = g
            for k, M in pulls.get(nm, {}).items():
                res[nm].setdefault("pull", {})[k] = {"mean": np.mean(M, axis=0).round(4).tolist(),
                                                     "max_abs": round(float(np.max(np.abs(M))), 4)}
        out["results"] = res
        out["frames_done"] = frames[: fi + 1]
        out["total_s"] = time.perf_counter() - t0
        print(f"frame {f} done {out['total_s']:.0f}s: " + "; ".join(
            f"{nm} " + " ".join(f"{k} {v['rms_um']:.1f}/{v['rms_mdeg']:.1f}"
                                for k, v in d.items() if "rms_um" in v)
            for nm, d in res.items()), flush=True)
        if checkpoint:
            checkpoint(out)
    return out


def _rim_stats(renderer) -> dict:
    """The band caches' counts (:class:`core.tracking.likelihood_rim.RimCache`) summed over the
    stage's engines of ``renderer``."""
    from core.tracking.engine_likelihood import _CACHE
    from core.tracking.likelihood_rim import _CACHES

    tot = {"hits": 0, "patched": 0, "built": 0}
    for eng in _CACHE.get(renderer, {}).values():
        c = _CACHES.get(eng)
        for k, v in ({} if c is None else c.stats()).items():
            tot[k] += v
    return tot


def run(*, device: str | None = None, frames: int = 100, pixels: int = 1024, voxel: float = 0.5,
        workers: int = 0, cases=("three", "tibia"), correction: str = "grid", warm_frames: int = 3,
        labels=None, checkpoint=None) -> dict:
    """The trial tracked with the stage's per-bone tissue settings (module docs); JSON-ready.
    ``labels``: the runs (default: those of the module docs; also ``hp8_tissue_fine_tibia_hp4``,
    ``hp8_tissue_fine_not_tibia_tibia_hp4``: the 2 mm tissue with the tibia's own 4 px high-pass,
    with and without the tissue in its stage; each label with ``_rim`` appended: the same with
    ``FinalModel(rim_sigmas=3.0)``, the band at the round field's rim). Given ``labels``, the
    tibia alone runs each of them too."""
    import core.tracking.final_stage as fst
    from core.render import DRRRenderer
    from core.studies.tracking.ml_cost import _scene
    from core.studies.tracking.tissue_stage import table, timed_run, tissue_model
    from core.tracking.final_stage import BoneStage
    from core.tracking.trial import TrackingOptions, track

    n = int(frames)
    t0 = time.perf_counter()
    ts, out, bound = _scene(n, pixels, voxel, device, workers,
                            {"study": "core.studies.tracking.tissue_tibia", "correction": correction,
                             "glare_undone": True}, glare=True, correction=correction)
    plain = fst.MODEL
    coarse = tissue_model(ts, kind="coarse", base=plain)
    fine = tissue_model(ts, kind="fine", base=plain)
    tib = ts.names.index("tibia")
    models = {"hp8": plain, "hp8_tissue": coarse,
              "hp8_tissue_not_tibia": replace(coarse, bones={tib: BoneStage(tissue=False)}),
              "hp8_tissue_not_tibia_tibia_hp4": replace(coarse, bones={tib: BoneStage(highpass_px=4.0,
                                                                                      tissue=False)}),
              "hp8_tissue_fine": fine,
              "hp8_tissue_fine_tibia_hp4": replace(fine, bones={tib: BoneStage(highpass_px=4.0)}),
              "hp8_tissue_fine_not_tibia_tibia_hp4": replace(fine, bones={tib: BoneStage(highpass_px=4.0,
                                                                                         tissue=False)})}
    for k in list(models):  # the same with the stage's band at the round field's rim (FinalModel.rim_sigmas)
        models[k + "_rim"] = replace(models[k], rim_sigmas=3.0)
    default = ("hp8", "hp8_tissue", "hp8_tissue_not_tibia", "hp8_tissue_not_tibia_tibia_hp4",
               "hp8_tissue_fine")
    labels = default if labels is None else tuple(labels)
    models = {k: models[k] for k in labels}
    out["models"] = {k: m.to_dict() for k, m in models.items()}
    out["setup_s"] = time.perf_counter() - t0
    for case in cases:
        bones = [0, 1, 2] if case == "three" else [tib]
        names = [ts.names[b] for b in bones]
        ms = [ts.models[b] for b in bones]
        r = DRRRenderer(ts.scene.rig, [m.volume.to_attenuation(ts.scene.bone_transfer) for m in ms],
                        device=ts.device)
        kf = {m.name: {0: ts.truth(0)[b]} for m, b in zip(ms, bones, strict=True)}
        base = TrackingOptions(mode="joint" if case == "three" else "sequential")
        o = replace(base, registration=replace(base.registration, search="newton", final_highpass_px=8.0),
                    refine_likelihood=True)
        runs = [(k, m) for k, m in models.items()
                if case == "three" or labels != default or k in ("hp8", "hp8_tissue", "hp8_tissue_fine")]
        if case == "tibia" and labels == default:
            runs.append(("hp4", replace(plain)))
        c: dict = {"mode": base.mode, "bones": names}
        hp4 = replace(o, registration=replace(o.registration, final_highpass_px=4.0))
        for label, m in runs:  # warm-up (compilation, buffers), not timed
            oo = hp4 if label == "hp4" else o
            with fst.final_model(m):
                track(r, ms, ts.frames, range(min(n, warm_frames)), keyframes=kf, options=oo)
        for label, m in runs:
            oo = hp4 if label == "hp4" else o
            before = _rim_stats(r)
            c[label] = timed_run(ts, r, ms, kf, oo, m, n, names, bound, f"{case} {label}")
            if label.endswith("_rim"):  # the band's regions of the timed run: from its cache, updated, built
                c[label]["rim_cache"] = {k: v - before[k] for k, v in _rim_stats(r).items()}
            out[case] = c
            out["total_s"] = time.perf_counter() - t0
            if checkpoint:
                checkpoint(out)
    out["table"] = [ln.replace("sequential", "tibia") for ln in table({"three": out.get("three"),
                                                                      "sequential": out.get("tibia")})]
    return out


def main(argv=None) -> int:
    p = cli.parser("core.studies.tracking.tissue_tibia", __doc__)
    p.add_argument("--bias", action="store_true", help="the CPU bias study (bias())")
    p.add_argument("--device", default=None)
    p.add_argument("--frames", default=None,
                   help="--bias: frame indices (default 0,10,…,90); else a count (100)")
    p.add_argument("--pixels", type=int, default=None, help="default 256 (--bias) or 1024")
    p.add_argument("--voxel", type=float, default=None, help="default 1.0 (--bias) or 0.5")
    p.add_argument("--bones", default="0,1,2", help="--bias: bone indices")
    p.add_argument("--kinds", default="exact,fine,coarse", help="--bias: tissue volumes")
    p.add_argument("--highpass", type=float, default=8.0, help="--bias: σ px at 1024² (scaled)")
    p.add_argument("--workers", type=int, default=0)
    p.add_argument("--cases", default="three,tibia")
    p.add_argument("--labels", default="", help="the runs (run(); default those of the module docs)")
    cli.add_output(p)
    a = p.parse_args(argv)
    checkpoint = cli.checkpoint(a)
    if a.bias:
        fr = a.frames or ",".join(map(str, range(0, 100, 10)))
        res = bias(pixels=a.pixels or 256, voxel=a.voxel or 1.0, frames=cli.ints(fr), bones=cli.ints(a.bones),
                   kinds=cli.names(a.kinds), highpass=a.highpass, device=a.device or "cpu",
                   checkpoint=checkpoint)
    else:
        res = run(device=a.device, frames=int(a.frames or 100), pixels=a.pixels or 1024, voxel=a.voxel or 0.5,
                  workers=a.workers, cases=cli.names(a.cases), labels=cli.names(a.labels) or None,
                  checkpoint=checkpoint)
    return cli.finish(res, a)


if __name__ == "__main__":
    raise SystemExit(main())
