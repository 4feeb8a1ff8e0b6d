"""The likelihood final stage with a soft-tissue regressor on the tracker's path (``python -m
core.studies.tracking.tissue_stage``).

The acceptance trial (:class:`core.studies.tracking.acceptance.TrackingScene`, by default 1024²,
0.5 mm voxels, 100 frames; the distortion undone by the correction a calibration session fits to
grid frames, ``correction="grid"``; the veiling glare measured from lead-disc frames undone) is
tracked by :func:`core.tracking.trial.track` (Gauss–Newton search) with the registrations' final
likelihood stage (``TrackingOptions.refine_likelihood``, :mod:`core.tracking.final_stage`) at each
high-pass σ of ``--highpass``, without and with the tissue regressor
(:attr:`core.tracking.final_stage.FinalModel.tissue`): the lab's soft-tissue volume — here the
generator's resampled onto a coarser grid offset by half a voxel
(:func:`core.studies.tracking.tissue_regressor.user_tissue`, ``coarse``; never the exact volume),
foot part following the calcaneus and shank part the tibia as the scene splits them — rendered by
the stage at the CURRENT ESTIMATE of those bones' poses (the similarity's pose of the stage's
bone, the neighbours' poses the stage is given), through the PSF estimated from pinhole
calibration frames as fluence (``--tissue-psf``, :func:`core.studies.tracking.background_fit.
estimated_psf`), high-passed like the frame, with a coefficient of its own per view.

Cases: ``three`` — tibia, talus and calcaneus jointly; ``sequential`` — the same three bones in
sequential mode (each bone's stage gets the bones registered before it in the frame and the
others' predicted poses, :func:`core.tracking.final_stage.stage_neighbours`). The talus alone in
the renderer (``ml_cost``'s ``one``) has no estimate of the calcaneus's or the tibia's pose, so
there the stage has no tissue to render (its result is the plain stage's).

Per case and run (``tracker``: no stage; ``hp<σ>``: the stage; ``hp<σ>_tissue``: with the
regressor): per bone the per-frame RMS error over the Cramér–Rao bound of the same trial
(:func:`core.studies.tracking.acceptance.cramer_rao`, every tenth frame; mm, degrees), frames over
4× the bound and the unflagged ones among them (:func:`core.studies.tracking.ml_cost.
silent_failures`), the 2σ coverage of the run's confidence; the stage's time per bone-frame
(``likelihood_ms_per_bone_frame``, set-up and tissue rendering included) and per frame after the
first. Only this study reads the truth. Reuses :mod:`core.studies.tracking.ml_cost`'s scene,
summaries and failure counts.

Measured (``resources/benchmarks/tracking_tissue_stage_h200.json``, one NVIDIA H200, the defaults
with ``--highpass 4,8 --variants ",again,each+again"``; over the bound mm/°, tibia, talus,
calcaneus, three bones jointly): no stage 1.72/1.95, 1.83/1.59, 1.31/1.53 (5 tibia frames over
4× the bound, none flagged); high-pass 4 px 1.56/1.42, 1.38/1.29, 1.21/1.38, with the tissue
1.64/1.47, 1.36/1.28, 1.21/1.37; high-pass 8 px 1.72/1.46, 1.31/1.31, 1.15/1.42, with the tissue
1.92/1.66, 1.17/1.18, 1.15/1.34 (the talus within 1.25×, the tibia 0.2× worse); the tissue
rendered again after the first refinement, or a gain per part, within 0.03 of these. Sequential
alike. The stage 15.3 / 16.8 / 21.9 / 22.9 ms per bone-frame (three jointly; sequentially 19.5 /
20.9 / 26.5 / 28.0 ms).

``--probe`` (:func:`probe`, ``resources/benchmarks/tracking_tissue_stage_probe_cpu.json``, this
2-core CPU machine, 256², grid-corrected noisy frames 0-18 step 2, from the TRUE poses, 10 samples
a bone: ±20-25 %): at the 8 px high-pass (2 px here) the talus 1.54/1.85 → 1.56/1.69 with the
4 mm tissue and 1.41/1.53 with the generator's exact volume; the tibia 1.74/0.86 → 1.42/1.03
(4 mm) and 2.28/1.44 (exact: its rotation about the long axis −0.055 → −0.139° on average).
From the true poses the 4 mm tissue does not cost the tibia what it costs in tracking (1.72/1.46
→ 1.92/1.66 on the H200): with the stage's robust rounds (``--probe-modes robust``) it still
takes the tibia 2.07/0.96 → 1.68/1.12, and rendered at poses a random 0.05 mm / 0.05° off
(``est``) the same within 0.01 (``tibia_modes`` in that JSON). This probe missed the tracking
loss because its 20 frames span only the first 11 % of stance, where the 4 mm volume's
pose-dependent offset is negative and cancelled the tibia's own bias; over the 100 frames the
first-order bias from the true poses reproduces it (:mod:`core.studies.tracking.tissue_tibia`:
the 4 mm volume's resampling stripes, smoothed skin and cut shank top cross the tibia's edges —
the volume's error, not the stage's tissue path, the estimated poses or the gain). A 2 mm volume
does not cost the tibia (tracked: 1.54/1.36, 1.15/1.19, 1.12/1.30 × the bound, one NVIDIA H200);
with only a 4 mm volume, ``BoneStage(highpass_px=4.0, tissue=False)`` for the tibia.

JSON on stdout (``--out``: also to a file, rewritten after each run).
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from core.studies.tracking import _study_cli as cli

__all__ = ["main", "run", "tissue_model"]


def tissue_model(ts, *, kind: str = "coarse", coarse_mm: float = 4.0, psf: bool = True, each: bool = False,
                 again: bool = False, base=None):
    """The final stage's :class:`~core.tracking.final_stage.FinalModel` (``base``: default the
    module's ``MODEL``) with the trial's tissue as a user has it (module docs): the volumes of
    ``kind`` (:data:`core.studies.tracking.tissue_regressor.TISSUES`) following the scene's bones
    (the tracker's renderer holds the trial's bones in the scene's order), the estimated PSF
    (``psf``), each part its own regressor (``each``), rendered again after the first refinement
    (``again``)."""
    import core.tracking.final_stage as fst
    from core.studies.tracking.tissue_regressor import user_tissue

    base = fst.MODEL if base is None else base
    # (through the scene's HU transfer, as the tracker's bone volumes are given theirs)
    vols = [v.to_attenuation(ts.scene.tissue_transfer)
            for v in user_tissue(ts.scene, kind, coarse_mm=coarse_mm)]
    k = None
    if psf:
        from core.studies.tracking.background_fit import estimated_psf

        k = np.asarray(estimated_psf(ts), dtype=np.float64)
    return replace(base, tissue=tuple(zip(vols, ts.scene.tissue_bones, strict=True)), tissue_each=each,
                   tissue_psf=k, tissue_again=again)


def _record(ts, res, names, n, dt, ends, bound) -> dict:
    """One run's numbers (module docs), with ml_cost's summaries."""
    from core.studies.tracking.ml_cost import _pose_errs, _summary
    from core.studies.tracking.ml_cost_final import _coverage, _sigmas, silent_failures

    poses = {(nm, f): res.results[(nm, f)].pose for nm in names for f in range(n)}
    tim = [res.results[(nm, f)].timing or {} for nm in names for f in range(n)]
    after = (ends[n - 1] - ends[0]) / (n - 1) if n > 1 and 0 in ends and n - 1 in ends else None
    d = {"track_s": dt, "ms_per_frame": 1e3 * dt / n,
         "ms_per_frame_after_first": None if after is None else 1e3 * after,
         "likelihood_ms_per_bone_frame": 1e3 * float(np.mean([t.get("likelihood_s", 0.0) for t in tim])),
         "likelihood_setup_ms_per_bone_frame": 1e3 * float(np.mean([t.get("likelihood_setup_s", 0.0)
                                                                    for t in tim])),
         "likelihood_steps_per_bone_frame": float(np.mean([t.get("likelihood_steps", 0) for t in tim])),
         "likelihood_taken": int(sum(t.get("likelihood_taken", 0) for t in tim)),
         "likelihood_rejected": int(sum(t.get("likelihood_rejected", 0) for t in tim)),
         "flagged": int(sum(bool(res.results[k].flags) for k in poses))}
    for nm in names:
        E = np.array(_pose_errs(ts, nm, poses, range(n)))
        S = _sigmas(res, nm, range(n))
        frs = [res.results[(nm, f)] for f in range(n)]
        s = _summary(E, bound.get(nm))
        d[nm] = {**s, "within_2_sigma": _coverage(E, S)}
        if bound.get(nm):
            d[nm]["over_4x_bound"] = silent_failures(E, [bool(x.flags) for x in frs], bound[nm])
        d[nm]["rejected_frames"] = [x.frame for x in frs if (x.timing or {}).get("likelihood_rejected")]
        d[nm]["error"] = np.round(E, 5).tolist()
    return d


def timed_run(ts, renderer, models, keyframes, options, model, n: int, names, bound, label: str) -> dict:
    """Frames ``0 … n-1`` of ``ts`` tracked with the stage model ``model`` (timed, the frames' end
    times kept), as :func:`_record` holds it; prints ``label`` with the bones' ratios to the bound."""
    import core.tracking.final_stage as fst
    from core.tracking.trial import track

    ends: dict = {}

    def progress(done, total, fr):
        ends[fr.frame] = time.perf_counter()

    with fst.final_model(model):
        t1 = time.perf_counter()
        res = track(renderer, models, ts.frames, range(n), keyframes=keyframes, options=options,
                    progress=progress)
        dt = time.perf_counter() - t1
    rec = _record(ts, res, names, n, dt, ends, bound)
    print(f"{label}: {dt:.1f} s " + " ".join(
        f"{nm} {rec[nm].get('over_bound', {}).get('mm', np.nan):.2f}/"
        f"{rec[nm].get('over_bound', {}).get('deg', np.nan):.2f}" for nm in names), flush=True)
    return rec


def run(*, device: str | None = None, frames: int = 100, pixels: int = 1024, voxel: float = 0.5,
        workers: int = 0, highpass=(4.0, 2.0), cases=("three", "sequential"), kind: str = "coarse",
        coarse_mm: float = 4.0, tissue_psf: bool = True, each: bool = False, again: bool = False,
        glare: bool = True, correction: str = "grid", warm_frames: int = 3, variants=("",),
        tracker: bool = True, checkpoint=None) -> dict:
    """Run the study (module docs); returns the JSON-ready results. ``variants``: the tissue runs
    per high-pass, each ``""`` (``each`` and ``again`` as given) or ``"+"``-joined flags ``each``,
    ``again`` (run ``hp<σ>_tissue_<flags>``); ``tracker``: also the run without a stage."""
    import core.tracking.final_stage as fst
    from core.render import DRRRenderer
    from core.studies.tracking.ml_cost import _scene
    from core.tracking.trial import TrackingOptions, track

    n = int(frames)
    t0 = time.perf_counter()
    ts, out, bound = _scene(n, pixels, voxel, device, workers,
                            {"study": "core.studies.tracking.tissue_stage", "highpass_px": list(highpass),
                             "correction": correction, "glare_undone": glare}, glare=glare,
                            correction=correction)
    plain_model = fst.MODEL
    tm = tissue_model(ts, kind=kind, coarse_mm=coarse_mm, psf=tissue_psf, each=each, again=again,
                      base=plain_model)
    out["stage_model"] = plain_model.to_dict()
    models_t = {"": tm}
    for v in variants:
        if v:
            fl = set(v.split("+"))
            if not fl <= {"each", "again"}:
                raise ValueError(f"variants: expected flags each, again joined by '+', got {v!r}")
            models_t[v] = replace(tm, tissue_each="each" in fl, tissue_again="again" in fl)
    out["tissue_model"] = {**tm.to_dict(), "kind": kind, "coarse_mm": coarse_mm, "variants": list(variants),
                           "generator_tissue_spacing_mm": [v.spacing.tolist() for v in ts.scene.tissue]}
    out["setup_s"] = time.perf_counter() - t0
    bones = [0, 1, 2]
    models = [ts.models[b] for b in bones]
    names = [ts.names[b] for b in bones]
    r = DRRRenderer(ts.scene.rig, [m.volume.to_attenuation(ts.scene.bone_transfer) for m in models],
                    device=ts.device)
    kf = {m.name: {0: ts.truth(0)[b]} for m, b in zip(models, bones, strict=True)}
    for case in cases:
        mode = {"three": "joint", "sequential": "sequential"}[case]
        base = TrackingOptions(mode=mode)
        plain = replace(base, registration=replace(base.registration, search="newton"))
        runs = [("tracker", plain, plain_model)] if tracker else []
        for hp in highpass:
            o = replace(plain, registration=replace(plain.registration, final_highpass_px=float(hp)),
                        refine_likelihood=True)
            runs += [(f"hp{hp:g}", o, plain_model)]
            runs += [(f"hp{hp:g}_tissue" + (f"_{v}" if v else ""), o, models_t[v]) for v in variants]
        c: dict = {"mode": mode}
        for _, o, m in runs:  # warm-up: the kernels compiled, the engines' buffers made (not timed)
            with fst.final_model(m):
                track(r, models, ts.frames, range(min(n, warm_frames)), keyframes=kf, options=o)
        for label, o, m in runs:
            c[label] = timed_run(ts, r, models, kf, o, m, n, names, bound, f"{case} {label}")
            out[case] = c
            out["total_s"] = time.perf_counter() - t0
            if checkpoint:
                checkpoint(out)
    out["table"] = table(out)
    return out


def probe(*, pixels: int = 256, voxel: float = 1.0, n_frames: int = 20, frames=range(0, 20, 2),
          highpass=(1.0, 2.0), kinds=("none", "coarse", "exact"), coarse_mm: float = 4.0,
          tissue_psf: bool = True, correction: str = "grid", glare: bool = True, device: str | None = "cpu",
          bones=None, modes=("plain",), pose_error: float = 0.05, checkpoint=None) -> dict:
    """What the tissue model itself does to each bone (``--probe``; study only): the stage's
    refinement (:class:`~core.tracking.engine_likelihood.LikelihoodEngine`, its plain Gauss–Newton
    steps) started from the TRUE pose, the neighbours subtracted at their true poses and the tissue
    (``kinds``: ``none``, or a volume of :func:`~core.studies.tracking.tissue_regressor.user_tissue`)
    rendered at the true poses of its bones, per high-pass σ (px at this size) — no tracker, no
    pose estimate: the error is the model's (and the frame's noise). Per bone, σ and tissue: RMS
    error, its ratio to the bound of these frames, the mean error per axis. ``modes``: ``plain``
    (as above), ``robust`` (the stage's refinement with :data:`~core.tracking.final_stage.MODEL`'s
    robust rounds), ``est`` (the tissue rendered at the true poses moved by a random
    ``pose_error`` mm / ° per axis, :func:`~core.studies.tracking.tissue_regressor.estimated_poses`),
    ``robust+est``; results keyed ``hp<σ>_<tissue>[_<mode>]``."""
    from types import SimpleNamespace

    import core.tracking.final_stage as fst
    from core.render import DRRRenderer
    from core.studies.tracking.acceptance import TrackingScene, cramer_rao, pose_errors
    from core.studies.tracking.tissue_regressor import estimated_poses, user_tissue
    from core.tracking.cost import prepare_frame, search_roi, snap_roi
    from core.tracking.engine_likelihood import LikelihoodEngine

    t0 = time.perf_counter()
    frames = [int(f) for f in frames]
    ts = TrackingScene(n_frames=n_frames, pixels=pixels, spacing=voxel, phase=(0.0, 0.6 * n_frames / 100.0),
                       device=device, glare=glare, correction=correction)
    sc = ts.scene
    k_psf = None
    if tissue_psf:
        from core.studies.tracking.background_fit import estimated_psf

        k_psf = np.asarray(estimated_psf(ts), dtype=np.float64)
    trs = {k: DRRRenderer(sc.rig, [v.to_attenuation(sc.tissue_transfer)
                                   for v in user_tissue(sc, k, coarse_mm=coarse_mm)], device=device)
           for k in kinds if k != "none"}
    bound = cramer_rao(ts, frames)
    out = {"study": "core.studies.tracking.tissue_stage --probe", "pixels": pixels, "voxel_mm": voxel,
           "frames": frames, "highpass_px": list(highpass), "kinds": list(kinds), "coarse_mm": coarse_mm,
           "tissue_psf": tissue_psf, "correction": correction, "glare_undone": glare, "modes": list(modes),
           "pose_error": pose_error,
           "bound": {nm: {"rms_mm": v["rms_mm"], "rms_deg": v["rms_deg"]} for nm, v in bound.items()}}
    errs: dict = {}
    views = tuple(range(len(sc.rig)))
    for f in frames:
        fr = prepare_frame(ts.frames(f))
        P = ts.truth(f)
        Pt = P[list(sc.tissue_bones)]
        Pe = estimated_poses(ts, f, pose_error)[list(sc.tissue_bones)]
        for b, (nm, m) in enumerate(zip(ts.names, ts.models, strict=True)):
            if bones is not None and b not in bones:
                continue
            roi = snap_roi(search_roi(ts.renderer, P[b], b, views=views, center=m.centroid, reach_mm=1.0,
                                      margin_px=4), ts.renderer, views)
            oth = [k for k in range(len(ts.names)) if k != b]
            for hp in highpass:
                for kind in kinds:
                    for mode in modes:
                        if kind == "none" and "est" in mode:
                            continue
                        eng = LikelihoodEngine(ts.renderer, bone=b, views=views, highpass_px=hp)
                        eng.set_frame(fr, base_pose=P[b], center=m.centroid, roi=roi, others=(P[oth], oth))
                        if kind != "none":
                            eng.set_tissue(trs[kind], Pe if "est" in mode else Pt, psf=k_psf)
                        if "robust" in mode:
                            o = fst._refine(eng, SimpleNamespace(final_iters=6), fst.MODEL)
                        else:
                            o = eng.refine(iters=6, sandwich=False)
                        e = pose_errors(eng.poses(np.asarray(o["x"])[None])[0], P[b], m.centroid)
                        key = f"hp{hp:g}_{kind}" + ("" if mode == "plain" else f"_{mode}")
                        errs.setdefault(nm, {}).setdefault(key, []).append(e)
        res = {}
        for nm, d in errs.items():
            for key, E in d.items():
                E = np.asarray(E)
                rm, rd = (float(np.sqrt(np.mean(np.sum(E[:, k] ** 2, axis=1))))
                          for k in (slice(0, 3), slice(3, 6)))
                res.setdefault(nm, {})[key] = {"rms_mm": rm, "rms_deg": rd,
                                               "over_bound": [round(rm / bound[nm]["rms_mm"], 3),
                                                              round(rd / bound[nm]["rms_deg"], 3)],
                                               "mean_error": E.mean(axis=0).round(5).tolist()}
        out["results"] = res
        cli.frame_done(out, f, t0, checkpoint, frames[: frames.index(f) + 1])
    return out


def table(res: dict) -> list[str]:
    """One line per case and run: each bone's RMS over the bound (mm/deg), frames over 4× (silent),
    the stage's ms per bone-frame."""
    lines = []
    for case in ("three", "sequential"):
        c = res.get(case)
        if not c:
            continue
        for label, d in c.items():
            if not isinstance(d, dict) or "track_s" not in d:
                continue
            parts = []
            for nm in ("tibia", "talus", "calcaneus"):
                s = d.get(nm)
                if s and "over_bound" in s:
                    o4 = s.get("over_4x_bound", {})
                    parts.append(f"{nm} {s['over_bound']['mm']:.2f}/{s['over_bound']['deg']:.2f} "
                                 f"(>4x {o4.get('over', '-')}, silent {o4.get('silent', '-')})")
            lines.append(f"{case} {label}: " + ", ".join(parts)
                         + f"; stage {d['likelihood_ms_per_bone_frame']:.1f} ms/bone-frame")
    return lines


def main(argv=None) -> int:
    p = cli.parser("core.studies.tracking.tissue_stage", __doc__)
    p.add_argument("--device", default=None)
    p.add_argument("--frames", type=int, default=100)
    p.add_argument("--pixels", type=int, default=1024)
    p.add_argument("--voxel", type=float, default=0.5)
    p.add_argument("--workers", type=int, default=0, help="processes for the frames' image chain")
    p.add_argument("--highpass", default="4,2", help="the stage's high-pass σs (px at this size)")
    p.add_argument("--cases", default="three,sequential")
    p.add_argument("--tissue", default="coarse", help="the user's tissue volume (tissue_regressor.TISSUES)")
    p.add_argument("--coarse-mm", type=float, default=4.0)
    p.add_argument("--no-tissue-psf", action="store_true", help="the tissue not blurred by the estimated PSF")
    p.add_argument("--each", action="store_true", help="the tissue's parts as two regressors")
    p.add_argument("--again", action="store_true", help="the tissue rendered again after the first step")
    p.add_argument("--variants", default="", help="tissue runs per high-pass: '', each, again, each+again, …")
    p.add_argument("--no-tracker", action="store_true", help="no run without the stage")
    p.add_argument("--no-glare", action="store_true", help="the frames' veiling glare left in")
    p.add_argument("--correction", choices=("model", "grid"), default="grid")
    p.add_argument("--warm-frames", type=int, default=3)
    cli.add_machine_name(p)
    p.add_argument("--probe", action="store_true",
                   help="the tissue model's own effect: the stage from the true poses (probe(); CPU sizes)")
    p.add_argument("--probe-frames", default="0,2,4,6,8,10,12,14,16,18")
    p.add_argument("--probe-bones", default="", help=cli.BONES_HELP)
    p.add_argument("--probe-modes", default="plain", help="plain, robust, est, robust+est (probe())")
    p.add_argument("--probe-kinds", default="none,coarse,exact")
    cli.add_output(p, machine_name=False)
    a = p.parse_args(argv)
    checkpoint = cli.checkpoint(a)
    if a.probe:
        res = probe(pixels=a.pixels, voxel=a.voxel, n_frames=a.frames, frames=cli.ints(a.probe_frames),
                    highpass=cli.floats(a.highpass), coarse_mm=a.coarse_mm, tissue_psf=not a.no_tissue_psf,
                    correction=a.correction, glare=not a.no_glare, device=a.device or "cpu",
                    bones=cli.ints(a.probe_bones) or None, modes=a.probe_modes.split(","),
                    kinds=a.probe_kinds.split(","), checkpoint=checkpoint)
        return cli.finish(res, a)
    res = run(device=a.device, frames=a.frames, pixels=a.pixels, voxel=a.voxel, workers=a.workers,
              highpass=cli.floats(a.highpass), cases=cli.names(a.cases), kind=a.tissue, coarse_mm=a.coarse_mm,
              tissue_psf=not a.no_tissue_psf, each=a.each, again=a.again, glare=not a.no_glare,
              variants=a.variants.split(",") if a.variants else ("",), tracker=not a.no_tracker,
              correction=a.correction, warm_frames=a.warm_frames, checkpoint=checkpoint)
    return cli.finish(res, a)


if __name__ == "__main__":
    raise SystemExit(main())
