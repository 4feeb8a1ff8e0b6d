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

JSON on stdout (``--out``: also to a file, rewritten after each run).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

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
    from core.studies.tracking.ml_cost import _coverage, _pose_errs, _sigmas, _summary, silent_failures

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
            ends: dict = {}

            def progress(done, total, fr, ends=ends):
                ends[fr.frame] = time.perf_counter()

            with fst.final_model(m):
                t1 = time.perf_counter()
                res = track(r, models, ts.frames, range(n), keyframes=kf, options=o, progress=progress)
                dt = time.perf_counter() - t1
            c[label] = _record(ts, res, names, n, dt, ends, bound)
            out[case] = c
            out["total_s"] = time.perf_counter() - t0
            print(f"{case} {label}: {dt:.1f} s " + " ".join(
                f"{nm} {c[label][nm].get('over_bound', {}).get('mm', np.nan):.2f}/"
                f"{c[label][nm].get('over_bound', {}).get('deg', np.nan):.2f}" for nm in names), flush=True)
            if checkpoint:
                checkpoint(out)
    out["table"] = table(out)
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
    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.tissue_stage",
                                description=__doc__.split("\n")[0])
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
    p.add_argument("--machine-name", default=None, help="the machine's name for the JSON (e.g. the GPU)")
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    import json

    from core.io.atomic import atomic_write, print_json

    def checkpoint(res):
        if a.machine_name:
            res["machine_name"] = a.machine_name
        if a.out:
            atomic_write(a.out, json.dumps(res, indent=1) + "\n")

    res = run(device=a.device, frames=a.frames, pixels=a.pixels, voxel=a.voxel, workers=a.workers,
              highpass=[float(x) for x in a.highpass.split(",") if x],
              cases=[x for x in a.cases.split(",") if x], kind=a.tissue, coarse_mm=a.coarse_mm,
              tissue_psf=not a.no_tissue_psf, each=a.each, again=a.again, glare=not a.no_glare,
              variants=a.variants.split(",") if a.variants else ("",), tracker=not a.no_tracker,
              correction=a.correction, warm_frames=a.warm_frames, checkpoint=checkpoint)
    if a.machine_name:
        res["machine_name"] = a.machine_name
    print_json(res, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
