"""What limits each bone's per-frame error under the likelihood final stage on the acceptance trial
(``python -m core.studies.tracking.stage_limits``).

One scene (:class:`core.studies.tracking.acceptance.TrackingScene`: tibia, talus, calcaneus,
soft-tissue envelope, walkway, the fluoroscope chain, frames undistorted with the 3 %-wrong
inverse), three measurements; only this study reads the truth:

* ``tracked`` (``--track LABEL=VARIANT,…``): the trial tracked jointly (Gauss–Newton search, the
  final stage, :func:`core.tracking.trial.track`), per bone the RMS error, the mean error per axis
  (``bias``) and the spread about it, each over the Cramér–Rao bound
  (:func:`core.studies.tracking.acceptance.cramer_rao`, every tenth frame), the lag-1
  autocorrelation and the frames over 4× the bound left unflagged
  (:func:`core.studies.tracking.ml_cost.silent_failures`);
* ``ablation`` (``--ablate VARIANT,…``): the stage alone from the TRUE poses with the neighbours at
  their true poses subtracted, on the noisy frames of ``--ablate-frames``: the same statistics
  without the tracker's start or the neighbours' errors;
* ``components`` (``--components-frames``): noise-free frames of the image's parts — ``bones``,
  ``bones+tissue``, ``bones+floor`` (the walkway), ``all``, ``all/blur`` (PSF, glare, roll-off),
  ``all/full`` (the trial's chain with the 3 %-wrong inverse), ``all/full/true`` (and the true
  residual warp removed) — and the stage's converged error from the true pose in each: its bias
  from that part alone.

A variant (:data:`VARIANTS`, ``+``-joined) sets the stage's :class:`core.tracking.final_stage.
FinalModel` (robust threshold and kind, the factors' window, rounds, support), its registration
options (high-pass σ, the neighbours' own gain, ROI margin) or, as study probes, the generator's
PSF on the DRRs (``psf``), no neighbours subtracted (``noothers``), frames with the TRUE residual
warp removed (``true``, :class:`core.studies.tracking.self_calibration.TrueWarp`), no stage
(``nostage``).

Measured (``resources/benchmarks/tracking_stage_limits_h200.json``, one NVIDIA H200, 1024², 0.5 mm,
100 frames, three bones jointly): the default stage tibia 2.16/1.46× its bound (mm/°), talus
1.39/1.31, calcaneus 1.90/1.40, tibia frames 30 and 55 silent. The calcaneus's translation is
biased by (+0.030, +0.021, +0.015) mm (in each fifth of the trial +0.016 to +0.040 in x, lag-1
autocorrelation 0.08-0.15): 1.48× its bound from the bias alone, 1.19× from the spread; the
tibia's by (+0.006, -0.020, -0.010) mm, 1.55× from the bias. On noise-free frames (10, 50, 90)
the stage's bias from the soft tissue, the walkway, blur and glare together is at most 0.007 mm /
0.06° for any bone (the walkway alone 0); the trial's chain with the 3 %-wrong inverse moves the
calcaneus by up to 0.043 mm and the tibia by up to 0.032 mm, and with the true residual warp
removed both are back within 0.007 mm: the residual distortion is the whole translation bias.
Tracked on frames with the true residual removed: tibia 1.52/1.39, talus 1.38/1.29, calcaneus
1.19/1.33, no silent frame; the biases are ≤ 0.12× the bound in translation (≤ 0.28× in
rotation) and the errors are spread, 1.1-1.7× the bound's σ per axis. Of the stage's options
there, a high-pass σ of 6 px (instead of 4) gave tibia 1.47/1.37, talus 1.27/1.28, calcaneus
1.13/1.32: the talus's and calcaneus's translation lower (paired bootstrap over the frames, 95 %
intervals 0.87-0.96 and 0.92-0.99 of the 4 px RMS), the rest within noise; the neighbours' own
gain changed the ratios by ≤ 0.02. From the true
poses (10 frames, so ±15 % on a ratio) no robust kind, threshold, window, rounds, support mask,
the PSF or dropping the neighbours lowered the spread, and without the robust weights the tibia's
translation error doubled (1.64 → 3.42×). On those 10 frames the tracked runs' RMS is within 4 %
of the stage's from the truth in translation and 0-13 % above it in rotation (the same mean
errors): the tracker's start and the neighbours' tracked poses matter little; the stage's own
optimum sets the error. That spread is what the 4 px high-pass costs: the linearised noise-only
spread of the same estimator (:func:`core.studies.tracking.bound_gap.wls_spread`,
``tracking_bound_gap_cpu.json``, 1024², frame blurred) is tibia 1.41/1.36×, talus 1.30/1.25×,
calcaneus 1.19/1.21× the bound at 4 px (1.16/1.21, 1.17/1.13, 1.10/1.10 at 8 px) against the
measured 1.52/1.39, 1.38/1.27, 1.18/1.30. A wider high-pass lets the soft tissue in: on
noise-free 512² frames of bones, tissue and walkway through the blur and glare (this 2-core CPU
machine, frames 10 and 50, the JSON's ``cpu_highpass_bias_512``) the talus's bias from the true
pose is 0.003-0.013 mm at σ 2 px (4 px at 1024²), 0.013-0.031 at 3, 0.026-0.059 at 4 and up to
0.25 mm / 1.3° at 8 px; the calcaneus's 0.002-0.034 mm, the tibia's ≤ 0.011 mm.

On the trial's grid-corrected frames (``ml_cost --final --correction grid --final-variants 6:-``,
``resources/benchmarks/tracking_grid_stage_modes_h200.json``, one NVIDIA H200, 100 frames) the
6 px high-pass repeats this jointly (tibia 1.52/1.42, talus 1.27/1.26, calcaneus 1.15/1.35 against
1.50/1.42, 1.38/1.31, 1.20/1.36 at 4 px) but not for a bone tracked alone: tibia 1.60/1.56 against
1.48/1.53, talus 1.61/1.55 against 1.50/1.50 (one frame over 4× its bound, silent), calcaneus
1.11/1.32 against 1.19/1.33.

JSON to ``--out`` (rewritten after each part).
"""

from __future__ import annotations

import argparse
import platform
import time
from dataclasses import replace

import numpy as np

__all__ = ["COMPONENTS", "VARIANTS", "Variant", "bone_stats", "component_frames", "main", "run",
           "stage_from_truth", "variant"]

#: the stage's variants (:func:`variant` joins them with ``+``)
VARIANTS: dict[str, dict] = {
    "default": {}, "plain": {"robust": None},
    "noothers": {"noothers": True}, "gain": {"gain": True},
    "hp2": {"hp": 2.0}, "hp3": {"hp": 3.0}, "hp4": {"hp": 4.0}, "hp6": {"hp": 6.0}, "hp8": {"hp": 8.0},
    "hp12": {"hp": 12.0}, "hp16": {"hp": 16.0},
    "r1.5": {"robust": 1.5}, "r2": {"robust": 2.0}, "r4": {"robust": 4.0},
    "huber": {"kind": "huber"}, "rounds2": {"rounds": 2}, "rsig1": {"rsig": 1.0}, "rsig4": {"rsig": 4.0},
    "support2": {"support": 2.0}, "support6": {"support": 6.0},
    "margin0": {"margin": 0}, "margin16": {"margin": 16},
    "psf": {"psf": True}, "true": {"frames": "true"}, "nostage": {"stage": False},
}

#: the noise-free component frames of :func:`component_frames`
COMPONENTS = ("bones", "bones+tissue", "bones+floor", "all", "all/blur", "all/full", "all/full/true")


def variant(name: str) -> dict:
    """The settings of ``name``: :data:`VARIANTS` entries joined by ``+`` (later ones win)."""
    spec: dict = {}
    for part in name.split("+"):
        if part not in VARIANTS:
            raise ValueError(f"variant: unknown part {part!r} (expected one of {sorted(VARIANTS)})")
        spec.update(VARIANTS[part])
    return spec


def _psf(ts, view: int = 0) -> np.ndarray:
    """The generator's Gaussian PSF of ``view`` (study probe: the truth)."""
    s = float(ts.scene.imaging[view].psf_sigma_px)
    r = max(1, int(np.ceil(3 * s)))
    g = np.exp(-0.5 * (np.arange(-r, r + 1) / s) ** 2)
    g /= g.sum()
    return np.outer(g, g)


class Variant:
    """Inside ``with``: the final stage's model of ``spec`` (:func:`variant`) as
    :data:`core.tracking.final_stage.MODEL` and the study probes patched in; ``options`` the
    joint tracking options (Gauss–Newton search, the stage with ``spec``'s registration options)."""

    def __init__(self, spec: dict, ts=None) -> None:
        from core.tracking.final_stage import FinalModel
        from core.tracking.trial import TrackingOptions

        self.spec, self.ts = dict(spec), ts
        self.model = FinalModel(robust=spec.get("robust", 2.5), robust_kind=spec.get("kind", "cauchy"),
                                robust_sigma_px=spec.get("rsig", 2.0), support_px=spec.get("support"),
                                rounds=spec.get("rounds", 1))
        base = TrackingOptions(mode="joint")
        plain = replace(base, registration=replace(base.registration, search="newton"))
        reg = replace(plain.registration, final_highpass_px=spec.get("hp", 4.0),
                      final_others_gain=spec.get("gain", False),
                      margin_px=spec.get("margin", plain.registration.margin_px))
        self.options = plain if spec.get("stage") is False else replace(plain, registration=reg,
                                                                         refine_likelihood=True)

    def __enter__(self) -> Variant:
        import core.tracking.final_stage as fst
        from core.tracking.engine_likelihood import LikelihoodEngine

        self._saved = (fst.likelihood_engine, LikelihoodEngine.set_frame)
        make, set_frame = self._saved
        if self.spec.get("psf"):
            P = _psf(self.ts)
            fst.likelihood_engine = lambda *a, **k: make(*a, **{**k, "psf": P})
        if self.spec.get("noothers"):
            def alone(eng, frame, **k):
                return set_frame(eng, frame, **{**k, "others": None})

            LikelihoodEngine.set_frame = alone
        self._block = fst.final_model(self.model)
        self._block.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        import core.tracking.final_stage as fst
        from core.tracking.engine_likelihood import LikelihoodEngine

        self._block.__exit__(*exc)
        fst.likelihood_engine, LikelihoodEngine.set_frame = self._saved


def stage_from_truth(ts, frame, f: int, spec: dict) -> dict:
    """Per bone the error ``(6,)`` (mm, degrees) of the final stage of ``spec`` started from the
    true pose of frame ``f`` with the other bones at their true poses subtracted (``frame``: the
    prepared :class:`~core.tracking.cost.FrameImages`)."""
    import core.tracking.final_stage as fst
    from core.studies.tracking.acceptance import pose_errors
    from core.tracking.cost import search_roi, snap_roi

    P = ts.truth(f)
    out = {}
    with Variant(spec, ts) as v:
        o = v.options.registration
        for b, nm in enumerate(ts.names):
            m = ts.models[b]
            views = tuple(range(len(ts.scene.rig)))
            roi = snap_roi(search_roi(ts.renderer, P[b], b, views=views, center=m.centroid, reach_mm=1.0,
                                      margin_px=o.margin_px), ts.renderer, views)
            oth = [k for k in range(len(ts.names)) if k != b]
            eng = fst.likelihood_engine(ts.renderer, bone=b, views=views, highpass_px=o.final_highpass_px,
                                        others_gain=o.final_others_gain)
            eng.set_frame(frame, base_pose=P[b], center=m.centroid, roi=roi, others=(P[oth], oth))
            r = fst._refine(eng, o, fst.MODEL)
            out[nm] = pose_errors(eng.poses(np.asarray(r["x"])[None])[0], P[b], m.centroid)
    return out


def bone_stats(E, bound: dict | None = None) -> dict:
    """RMS error of ``E (frames, 6)`` (mm, degrees; rows with a NaN left out), its mean per axis
    (``mean_error``; ``bias_*`` its norm) and the RMS spread about it (``rms² = bias² + spread²``),
    over ``bound`` (``rms_mm``, ``rms_deg``) when given; lag-1 autocorrelation per axis."""
    E = np.asarray(E, dtype=float)
    ok = np.all(np.isfinite(E), axis=1)
    E = E[ok]
    mu = E.mean(axis=0)
    X = E - mu
    s = {"mean_error": mu.round(5).tolist(), "std_error": E.std(axis=0).round(5).tolist(),
         "rms_mm": float(np.sqrt(np.mean(np.sum(E[:, :3] ** 2, axis=1)))),
         "rms_deg": float(np.sqrt(np.mean(np.sum(E[:, 3:] ** 2, axis=1)))),
         "bias_mm": float(np.linalg.norm(mu[:3])), "bias_deg": float(np.linalg.norm(mu[3:])),
         "spread_mm": float(np.sqrt(np.mean(np.sum(X[:, :3] ** 2, axis=1)))),
         "spread_deg": float(np.sqrt(np.mean(np.sum(X[:, 3:] ** 2, axis=1)))),
         "n": len(E), "missing": int((~ok).sum())}
    if len(E) > 2:
        ac = (X[1:] * X[:-1]).sum(0) / np.maximum((X * X).sum(0), 1e-30)
        s["lag1_autocorrelation"] = ac.round(3).tolist()
    if bound:
        for k in ("rms", "bias", "spread"):
            s[f"{k}_over_bound"] = [round(s[f"{k}_mm"] / bound["rms_mm"], 3),
                                    round(s[f"{k}_deg"] / bound["rms_deg"], 3)]
    return s


def component_frames(ts, f: int, configs=COMPONENTS, true_warp=None) -> dict:
    """Noise-free flatfield-normalised frames of frame ``f``'s image parts (module docs), per
    config; ``true_warp``: a :class:`~core.studies.tracking.self_calibration.TrueWarp` of ``ts``
    (made when a config needs one)."""
    from core.studies.tracking.bound_gap import synth

    sr, sc = ts._scene_renderer, ts.scene
    P = sc.poses(f)
    Lb = sr._bones.render(P[None], roi="full").numpy()[0].sum(axis=1).astype(np.float64)
    Pt = P[list(sc.tissue_bones)][None]
    Lt = sr._tissue.render(Pt, roi="full").numpy()[0].sum(axis=1).astype(np.float64)
    L = sc.line_integrals(f, renderer=sr).astype(np.float64)
    parts = {"bones": Lb, "tissue": Lt, "floor": L - Lb - Lt}
    out = {}
    for cfg in configs:
        what, _, chain = cfg.partition("/")
        chain, _, fix = chain.partition("/")
        Lx = L if what == "all" else sum(parts[k] for k in what.split("+"))
        if chain:
            imgs = synth(ts, Lx.astype(np.float32), chain, None)
        else:
            imgs = [np.exp(-x).astype(np.float32) for x in Lx]
        if fix == "true":
            if true_warp is None:
                from core.studies.tracking.self_calibration import TrueWarp

                true_warp = TrueWarp(ts)
            imgs = true_warp.frames(lambda i, imgs=imgs: imgs)(f)
        out[cfg] = imgs
    return out


def run(*, pixels: int = 1024, voxel: float = 0.5, frames: int = 100, device: str | None = None,
        workers: int = 0, track=(("final", "default"), ("oracle", "true")), ablate=(), ablate_frames=None,
        components=COMPONENTS, components_frames=(), checkpoint=None) -> dict:
    """Run the study (module docs); ``track``: ``(label, variant)`` pairs; returns the JSON-ready
    results."""
    from core.studies.tracking.ml_cost import _pose_errs, _scene, silent_failures
    from core.studies.tracking.self_calibration import TrueWarp
    from core.tracking.cost import prepare_frame
    from core.tracking.trial import track as track_trial

    t0 = time.perf_counter()
    ts, out, bound = _scene(frames, pixels, voxel, device, workers,
                            {"study": "core.studies.tracking.stage_limits"})
    out["machine"] = platform.machine()
    out["residual_distortion_rms_mm"] = ts.residual_distortion_mm()
    tw: list = []

    def warp():
        if not tw:
            tw.append(TrueWarp(ts))
        return tw[0]

    def save():
        out["total_s"] = time.perf_counter() - t0
        if checkpoint:
            checkpoint(out)

    kf = {nm: {0: ts.truth(0)[b]} for b, nm in enumerate(ts.names)}
    if track:  # the kernels compiled, the engines made (not timed)
        t1 = time.perf_counter()
        for o in (Variant({"stage": False}).options, Variant({}).options):
            track_trial(ts.renderer, ts.models, ts.frames, range(min(3, frames)), keyframes=kf, options=o)
        out["warm_up_s"] = time.perf_counter() - t1
    for label, vn in track:
        spec = variant(vn)
        src = warp().frames(ts.frames) if spec.get("frames") == "true" else ts.frames
        t1 = time.perf_counter()
        with Variant(spec, ts) as v:
            res = track_trial(ts.renderer, ts.models, src, range(frames), keyframes=kf, options=v.options)
        dt = time.perf_counter() - t1
        poses = {(nm, f): res.results[(nm, f)].pose for nm in ts.names for f in range(frames)}
        d = {"variant": vn, "model": v.model.to_dict(), "track_s": dt, "ms_per_frame": 1e3 * dt / frames}
        for nm in ts.names:
            E = np.array(_pose_errs(ts, nm, poses, range(frames)))
            d[nm] = bone_stats(E, bound.get(nm))
            if bound.get(nm):
                flags = [bool(res.results[(nm, f)].flags) for f in range(frames)]
                d[nm]["over_4x_bound"] = silent_failures(E, flags, bound[nm])
            d[nm]["per_frame_error"] = np.round(E, 5).tolist()
        out.setdefault("tracked", {})[label] = d
        save()
    if ablate:
        fl = list(ablate_frames) if ablate_frames else list(range(0, frames, 10))
        out["ablation"] = {"frames": fl, "variants": {}}
        prepared: dict = {}
        for vn in ablate:
            spec = variant(vn)
            key = spec.get("frames", "orig")
            t1 = time.perf_counter()
            errs: dict = {nm: [] for nm in ts.names}
            for f in fl:
                if (key, f) not in prepared:
                    src = warp().frames(ts.frames) if key == "true" else ts.frames
                    prepared[(key, f)] = prepare_frame(src(f))
                for nm, e in stage_from_truth(ts, prepared[(key, f)], f, spec).items():
                    errs[nm].append(e)
            d = {nm: bone_stats(E, bound.get(nm)) for nm, E in errs.items()}
            d["s"] = time.perf_counter() - t1
            out["ablation"]["variants"][vn] = d
            save()
    if components_frames:
        out["components"] = {"frames": list(components_frames), "variant": "default", "configs": {}}
        rows = out["components"]["configs"]
        fix = warp() if any(c.endswith("/true") for c in components) else None
        for f in components_frames:
            for cfg, imgs in component_frames(ts, f, components, fix).items():
                for nm, e in stage_from_truth(ts, prepare_frame(imgs), f, {}).items():
                    rows.setdefault(cfg, {}).setdefault(nm, []).append(np.round(e, 5).tolist())
            save()
    save()
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.stage_limits",
                                description=__doc__.split("\n")[0])
    p.add_argument("--pixels", type=int, default=1024)
    p.add_argument("--voxel", type=float, default=0.5)
    p.add_argument("--frames", type=int, default=100)
    p.add_argument("--device", default=None, help="Warp device (cpu, cuda:0)")
    p.add_argument("--workers", type=int, default=0, help="processes synthesising the frames")
    p.add_argument("--track", default="final=default,oracle=true", help="tracked runs 'label=variant,…'")
    p.add_argument("--ablate", default="", help="variants of the stage from the true poses, 'v,…'")
    p.add_argument("--ablate-frames", default="", help="their frames (default every tenth)")
    p.add_argument("--components", default=",".join(COMPONENTS))
    p.add_argument("--components-frames", default="", help="frames of the noise-free component test")
    p.add_argument("--out", default=None, help="also write the JSON here (after each part)")
    a = p.parse_args(argv)
    from core.io.atomic import json_checkpoint, print_json

    def ints(s):
        return [int(x) for x in s.split(",") if x]

    checkpoint = json_checkpoint(a.out, indent=1)

    res = run(pixels=a.pixels, voxel=a.voxel, frames=a.frames, device=a.device, workers=a.workers,
              track=[tuple(x.split("=", 1)) for x in a.track.split(",") if x],
              ablate=[x for x in a.ablate.split(",") if x], ablate_frames=ints(a.ablate_frames),
              components=[x for x in a.components.split(",") if x],
              components_frames=ints(a.components_frames),
              checkpoint=checkpoint)
    print_json(res, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
