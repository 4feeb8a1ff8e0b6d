"""The tracker's poses refined by weighted least squares on the line-integral image, on the
standard synthetic walking trial (``python -m core.studies.tracking.ml_cost``).

The trial of :mod:`core.studies.tracking.benchmark` (1024² views, 0.5 mm voxels, 100 frames; frame
0 from the true pose) is tracked by :func:`core.tracking.trial.track` with the Gauss–Newton search
and the default cost, one bone (the talus, alone in the renderer) and three bones jointly. Each
frame's tracked pose is then refined by :meth:`core.tracking.likelihood_cost.LikelihoodCost.refine`: the
bone's DRR against the fluoroscope's line integrals, both high-passed by a Gaussian of
``--highpass`` pixels (the soft tissue's and the walkway's smooth structure taken out), weighted
by the expected counts, gain and offset fitted linearly, and, in joint mode, the other bones'
DRRs at their tracked (then refined) poses subtracted (``--passes`` rounds over the bones).

Reported per case and bone: per-frame RMS error (mm, degrees) of the tracker and of each
refinement, over the Cramér–Rao bound of the same trial
(:func:`core.studies.tracking.acceptance.cramer_rao`, every tenth frame), the mean error, the
fraction of axes within 2σ of the refinement's covariance, and the refinement's time per
bone-frame. ``chain_bound``: the bound with the PSF, glare and read noise after the quantum
stage (:func:`core.tracking.bound.chain_information`) on ``--chain-frames``.

``--quick``: 192² views, 1 mm voxels, 8 frames (this machine's CPU). JSON on stdout.

``--final`` (:func:`run_final`): the trial tracked twice in one process, as today and with the
device refinement as the registrations' final stage (``TrackingOptions.refine_likelihood``,
:mod:`core.tracking.final_stage`; three bones: after the last joint round, the neighbours at
the poses of the round before, :mod:`core.tracking.frame_step`): error / bound ratios, time per
frame and the stage's share, and the 2σ coverage of each run's own confidence; ``--every-round``
adds a three-bone run with the stage after every round, as before. Per bone: frames over 4× their
bound and how many of them went unflagged (:func:`silent_failures`; the flags include the final
stage's move check, :func:`core.tracking.frame_step.stage_move_check`); per frame the stage's move,
the diagonals of its sandwich and independent-pixel covariances, χ² and residual autocorrelation
(:class:`~core.studies.tracking.ml_cost_final._StageProbe`); ``rejected_frames``: the frames whose
stage move the check rejected (the
similarity's pose kept; they count among ``false_flags`` when that left them within 4× the
bound). ``--correction grid``: the frames undistorted with the grid fit
(:mod:`core.studies.tracking.grid_correction`; the JSON records the scene's residual distortion and
the fits). Measured: ``resources/benchmarks/tracking_final_rounds_h200.json`` (before the
rejection), ``resources/benchmarks/tracking_final_reject_h200.json``, with the grid correction
``tracking_grid_correction_h200.json`` (three jointly) and ``tracking_grid_stage_modes_h200.json``
(``--cases three,talus,tibia,calcaneus --final-variants 6:-``: each bone alone and three jointly, the
stage at 4 and 6 px; one NVIDIA H200, × the bound mm / °, alone tibia 1.48 / 1.53, talus
1.50 / 1.50, calcaneus 1.19 / 1.33 at 4 px, 1.60 / 1.56, 1.61 / 1.55, 1.11 / 1.32 at 6 px; jointly
1.50 / 1.42, 1.38 / 1.31, 1.20 / 1.36 at 4 px, 1.52 / 1.42, 1.27 / 1.26, 1.15 / 1.35 at 6 px).
``--correction grid,exact``: the corrections in turn on the same raw frames and bound (results per
correction in ``by_correction``); ``exact`` is the true distortion model, a study-only oracle (no
distortion error left). Measured (``resources/benchmarks/tracking_exact_correction_h200.json``,
``--cases tibia,three --final-variants 8:-``, one NVIDIA H200, 100 frames, × the bound mm / °, exact
against grid): the exact correction does not lower the tibia — 4 px alone 1.47 / 1.54 against
1.48 / 1.53, jointly 1.51 / 1.37 against 1.50 / 1.42 (talus 1.37 / 1.30 against 1.38 / 1.31,
calcaneus 1.18 / 1.34 against 1.20 / 1.36); 8 px alone 2.04 / 1.60 against 1.94 / 1.63, jointly
1.66 / 1.40 against 1.68 / 1.43. Frames over 4× the bound at 4 px: none with the grid, one tibia
frame (flagged) jointly with the exact correction; at 8 px 1-3 tibia frames, silent, with either.
The grid correction's leftover distortion is not what holds the tibia at ~1.5×: its 4 px error is
spread (mean ≤ 0.3× the bound per axis, lag-1 autocorrelation ≤ 0.09), and the stage's own σ for
it is 7× the bound (17× at 8 px; the talus's 1.4×): a structured residual.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

from core.studies.tracking.ml_cost_final import _corrections, _variant, run_final, silent_failures
from core.studies.tracking.ml_cost_scene import _pose_errs, _scene, _summary, synthesise

__all__ = ["main", "refine_frame", "run", "run_final", "silent_failures", "synthesise"]


def refine_frame(renderer, frame, models, poses, *, highpass_px: float, passes: int = 2, psf=None,
                 reach_mm: float = 1.0, iters: int = 5) -> tuple[np.ndarray, list[dict]]:
    """Refine the poses ``(n_bones, 4, 4)`` of ``models`` (volume ``i`` of ``renderer`` = bone
    ``i``) in one frame: each bone in turn with the others at their current poses subtracted,
    ``passes`` rounds. Returns the refined poses and each bone's last refinement output."""
    from core.tracking.cost import OutsideViewError, search_roi
    from core.tracking.likelihood_cost import LikelihoodCost

    P = np.array(poses, dtype=float)
    outs: list[dict] = [{} for _ in models]
    n = len(models)
    for _ in range(passes if n > 1 else 1):
        for i, m in enumerate(models):
            if not np.all(np.isfinite(P[i])):
                continue
            oth = [k for k in range(n) if k != i and np.all(np.isfinite(P[k]))]
            try:
                roi = search_roi(renderer, P[i], i, views=range(len(renderer.cameras)), center=m.centroid,
                                 reach_mm=reach_mm)
            except OutsideViewError:
                continue
            cost = LikelihoodCost(renderer, frame, bone=i, base_pose=P[i], center=m.centroid, roi=roi,
                                  others=(P[oth], oth) if oth else None, others_gain=False, background=0,
                                  highpass_px=highpass_px, psf=psf)
            out = cost.refine(iters=iters)
            P[i] = cost.poses(out["x"][None])[0]
            outs[i] = out
    return P, outs


def run(*, quick: bool = False, device: str | None = None, frames: int | None = None, variants=("8",),
        passes: int = 2, cases=("one", "three"), chain_frames=(0, 40, 80), refine_every: int = 1,
        psf=None, workers: int = 0, checkpoint=None, pixels: int | None = None,
        voxel: float | None = None) -> dict:
    """Run the study (module docs); returns the JSON-ready results. ``variants``: refinements
    ``"<high-pass σ px>"`` or ``"<σ>+psf"`` (the DRRs blurred by ``psf``, a kernel estimated
    from calibration frames); ``refine_every``: refine every k-th frame only (the tracker's
    errors are reported over all frames and over those)."""
    from core.render import DRRRenderer
    from core.studies.tracking.bound_gap import _chain_terms
    from core.tracking.bound import chain_information
    from core.tracking.cost import prepare_frame
    from core.tracking.trial import TrackingOptions, track

    n = frames or (8 if quick else 100)
    px, vox = (192, 1.0) if quick else (1024, 0.5)
    px, vox = pixels or px, voxel or vox
    ts, out, bound = _scene(n, px, vox, device, workers, {
        "study": "core.studies.tracking.ml_cost", "variants": list(variants), "passes": passes,
        "refined_frames": list(range(0, n, refine_every))})
    if chain_frames:
        t0 = time.perf_counter()
        N = [m.photons_per_pixel for m in ts.scene.imaging]
        cb = {}
        for b, (nm, m) in enumerate(zip(ts.names, ts.models, strict=True)):
            covs = []
            for f in chain_frames:
                if f >= n:
                    continue
                L = ts.scene.line_integrals(f, renderer=ts._scene_renderer)
                J = chain_information(ts.renderer, b, ts.truth(f)[b], m.centroid, line_integral=L,
                                      quanta_per_pixel=N, **_chain_terms(ts))
                covs.append(np.linalg.inv(J))
            if covs:
                C = np.mean(covs, axis=0)
                cb[nm] = {"rms_mm": float(np.sqrt(np.trace(C[:3, :3]))),
                          "rms_deg": float(np.sqrt(np.trace(C[3:, 3:])))}
        out["chain_bound"] = cb
        out["chain_bound_frames"] = [f for f in chain_frames if f < n]
        out["chain_bound_s"] = time.perf_counter() - t0
    base = TrackingOptions(mode="joint")
    o = replace(base, registration=replace(base.registration, search="newton"))
    for case in cases:
        bones = [1] if case == "one" else [0, 1, 2]
        models = [ts.models[b] for b in bones]
        names = [ts.names[b] for b in bones]
        r = DRRRenderer(ts.scene.rig, [m.volume.to_attenuation(ts.scene.bone_transfer) for m in models],
                        device=ts.device)
        kf = {m.name: {0: ts.truth(0)[b]} for m, b in zip(models, bones, strict=True)}
        t0 = time.perf_counter()
        res = track(r, models, ts.frames, range(n), keyframes=kf, options=o)
        c = {"track_s": time.perf_counter() - t0}
        tracked = {(nm, f): res.results[(nm, f)].pose for nm in names for f in range(n)}
        E = {nm: np.array(_pose_errs(ts, nm, tracked, range(n))) for nm in names}
        c["tracker"] = {nm: _summary(E[nm], bound.get(nm)) for nm in names}
        fr_ref = list(range(0, n, refine_every))
        c["tracker_on_refined_frames"] = {nm: _summary(E[nm][fr_ref], bound.get(nm)) for nm in names}
        for var in variants:
            hp = float(var.split("+")[0])
            k = psf if var.endswith("+psf") else None
            if var.endswith("+psf") and psf is None:
                raise ValueError(f"variant {var}: needs psf")
            t0 = time.perf_counter()
            refined, covs = {}, {nm: [] for nm in names}
            for f in fr_ref:
                P0 = np.array([tracked[(nm, f)] if tracked[(nm, f)] is not None else np.full((4, 4), np.nan)
                               for nm in names])
                P, outs = refine_frame(r, prepare_frame(ts.frames(f)), models, P0, highpass_px=hp,
                                       passes=passes, psf=k)
                for i, nm in enumerate(names):
                    refined[(nm, f)] = P[i]
                    covs[nm].append(outs[i].get("covariance", np.full((6, 6), np.nan)))
            dt = time.perf_counter() - t0
            Er = {nm: np.array(_pose_errs(ts, nm, refined, fr_ref)) for nm in names}
            c[f"refined_{var}"] = {"s_per_frame": dt / len(fr_ref),
                                      **{nm: _summary(Er[nm], bound.get(nm), covs[nm]) for nm in names}}
        out[case] = c
        if checkpoint:
            checkpoint(out)
    return out



def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.ml_cost",
                                description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="192² views, 1 mm voxels, 8 frames (CPU)")
    p.add_argument("--device", default=None)
    p.add_argument("--frames", type=int, default=None)
    p.add_argument("--pixels", type=int, default=None, help="override the views' size")
    p.add_argument("--voxel", type=float, default=None, help="override the voxel size (mm)")
    p.add_argument("--variants", default="8", help="refinements: high-pass σ (px), '+psf' with --psf")
    p.add_argument("--psf", default=None, help=".npy kernel estimated from calibration frames")
    p.add_argument("--refine-every", type=int, default=1)
    p.add_argument("--workers", type=int, default=0, help="processes for the frames' image chain")
    p.add_argument("--passes", type=int, default=2)
    p.add_argument("--cases", default="one,three")
    p.add_argument("--chain-frames", default="0,40,80", help="frames of the chain bound ('' = none)")
    p.add_argument("--final", action="store_true",
                   help="track with and without the final stage (TrackingOptions.refine_likelihood)")
    p.add_argument("--highpass", type=float, default=4.0, help="--final: the stage's high-pass σ (px)")
    p.add_argument("--final-variants", default="",
                   help="--final: more stages 'σ:lag[:confidence],…' ('-': the default)")
    p.add_argument("--glare", action="store_true",
                   help="--final: undo the veiling glare measured from calibration disc frames")
    p.add_argument("--correction", type=_corrections, default="model",
                   help="--final: the frames' distortion correction (TrackingScene correction: model, grid, "
                   "exact), or several in turn on the same frames, e.g. 'grid,exact'")
    p.add_argument("--erode-px", type=int, default=None,
                   help="--final: unusable band around black pixels (TrackingOptions.erode_px, 3)")
    p.add_argument("--every-round", action="store_true",
                   help="--final: three bones also with the stage after every joint round (as before)")
    p.add_argument("--keep-moves", action="store_true",
                   help="--final: also with the flagged stage moves kept (stage_move_reject=False)")
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    from core.io.atomic import json_checkpoint, print_json

    checkpoint = json_checkpoint(a.out, indent=2)

    if a.final:
        res = run_final(device=a.device, frames=a.frames, cases=a.cases.split(","),
                        pixels=a.pixels or 1024, voxel=a.voxel or 0.5, highpass_px=a.highpass,
                        workers=a.workers, checkpoint=checkpoint,
                        variants=[_variant(v) for v in a.final_variants.split(",") if v], glare=a.glare,
                        every_round=a.every_round, keep_moves=a.keep_moves,
                        correction=a.correction[0] if len(a.correction) == 1 else a.correction,
                        erode_px=a.erode_px)
        print_json(res, a.out)
        return 0
    res = run(quick=a.quick, workers=a.workers, checkpoint=checkpoint, pixels=a.pixels, voxel=a.voxel,
              device=a.device, frames=a.frames, variants=a.variants.split(","),
              passes=a.passes, cases=a.cases.split(","), refine_every=a.refine_every,
              psf=None if a.psf is None else np.load(a.psf),
              chain_frames=[int(x) for x in a.chain_frames.split(",") if x])
    print_json(res, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
