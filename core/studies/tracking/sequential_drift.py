"""Sequential tracking's silent failures on the acceptance trial: the tibia's drift about its long
axis over frames 54-70 (``python -m core.studies.tracking.sequential_drift``).

The acceptance study (:mod:`core.studies.tracking.acceptance`, ``--mode joint,sequential``,
``resources/benchmarks/tracking_acceptance_modes_h100.json``) left sequential tracking with 9 silent
tibia frames over 4× the Cramér–Rao bound (54, 63-70; a smooth rotation about the long axis up to
~0.6°, which the trajectory post-pass cannot see) and 7 talus frames, where joint tracking left 1/0.
This study tracks the same trial sequentially (:func:`core.tracking.trial.track`, the acceptance
options: Gauss–Newton search, trajectory post-pass) and probes the frames ``--probe-frames``
(default 50-72) of ``--bones`` (default tibia, talus):

* **cost** — the similarity the search maximises (the Gauss–Newton engine's, full resolution, on
  the search regions about the truth) at the truth and at the tracker's estimate, and along the
  line from the truth to the estimate (``scan``: fractions -0.5 … 1.5 of the way), with the other
  bones' images left in the frames (``alone``: what a sequential search sees) and with their DRRs
  subtracted at their true poses (``truth``) and at the poses the run tracked (``tracked``);
* **restart** — the registration (the tracking options' search) restarted from the truth, alone
  and with the neighbours subtracted at their true poses: back to the estimate (the cost's optimum
  is off the truth: a bias) or staying at the truth (the search stuck in the previous frame's
  basin);
* **neighbours** — what the other bones' images are in the bone's search regions at that moment:
  in sequential tracking without the final stage and without ``sequential_subtract`` (this run's
  first) they are neither rendered nor subtracted; the study gives their share of the regions'
  pixels (a neighbour's line integral over 5 % of its largest) and of the squared gradient (the
  gradient correlation's evidence) of the bones' summed DRR, per view.

Then the fix candidate is tracked on the same frames: the sequential search with the neighbours
subtracted (``TrackingOptions(sequential_subtract=True)``: the bones registered
earlier in the frame at their registered poses, the others at their constant-velocity guesses),
and, for reference, joint tracking (``--joint``). Per run and bone: RMS × the bound (the bound of
the acceptance JSON's same scene, or computed: ``--bound compute``, the default with ``--quick``),
frames over 4× it, silent (unflagged) ones, flagged frames; and the per-frame rotation difference
between the two
sequential runs (what a check comparing them would see). ``--seed`` tracks another synthesis of
the trial (its noise, start error and grid frames; its bound computed, ``--bound compute``).

Findings
--------
One NVIDIA H100, 1024², 100 frames, grid correction, Gauss–Newton search, trajectory post-pass on
(``resources/benchmarks/sequential_drift_h100.json``; the sequential and joint runs' per-frame errors
equal ``tracking_acceptance_modes_h100.json``'s in all 300 bone-frames):

* **What the other bones are**: in sequential tracking (without the opt-in final stage, and as it was
  before ``sequential_subtract``) they are neither rendered nor subtracted — each bone is searched
  against the whole image. The talus and calcaneus cover 25.5 / 16.6 % of the tibia's
  search-region pixels (views 0 / 1, frames 50-72) and carry 26 / 25 % of the squared gradient of
  the bones' summed DRR there; around the talus the tibia and calcaneus cover 66 / 48 % and carry
  76 / 67 %.
* **A bias of the cost, not a search stuck in the previous frame's basin**: against the whole image
  the tracker's estimate scores higher than the truth in 21 of 23 tibia frames (talus 20 of 23), and
  along the line from the truth to the estimate the cost peaks 0.25-1.5 of the way (median 0.75).
  With the neighbours' DRRs subtracted at their true poses the estimate scores higher in 8 (talus 2)
  and the peak moves to -0.5…0.5 of the way in the drift frames 63-72; at the poses the run tracked,
  9 (talus 2; the peak 0-0.5 of the way in frames 63-72). Restarted from the truth against the whole
  image, the registration goes back towards the estimate (tibia 0.242° RMS rotation error over
  frames 50-72, a median 0.134° from the estimate, against the estimate's 0.372°; talus 0.426°
  against 0.451°, 0.016° from it); with the neighbours subtracted at their true poses it stays near
  the truth (tibia 0.139°, its mean error about the long axis -0.018° against the estimate's
  -0.292°; talus 0.220°). The drift follows the slowly changing overlap, so it is smooth: no restart
  from the prediction finds a better score (the cost prefers the estimate) and the trajectory
  post-pass sees no outlier.
* **The fix measured** (``TrackingOptions.sequential_subtract``, same frames, same call): silent
  frames over 4× the bound tibia / talus / calcaneus 9 / 7 / 0 → 0 / 0 / 0; × the bound (mm / °)
  tibia 1.79 / 2.46 → 1.71 / 1.79, talus 2.23 / 2.17 → 1.78 / 1.58, calcaneus 1.59 / 1.43 → 1.29 /
  1.50; the tibia's mean error about the long axis over the 100 frames -0.117° → -0.060°. Joint
  tracking in the same call: 1.73 / 1.85, 1.80 / 1.57, 1.31 / 1.52, silent 1 / 0 / 0 (tibia frame
  81, as before). The subtracted sequential run took 1.65 s for 100 frames of three bones, joint
  2.59 s.
* **Two more syntheses** (``--seed 1``, ``--seed 2``, same card,
  ``resources/benchmarks/sequential_drift_seeds_h100.json``): silent frames sequential → subtracted
  (joint) 9 / 0 / 0 → 8 / 0 / 0 (7 / 0 / 0) and 4 / 1 / 0 → 2 / 0 / 0 (2 / 0 / 0); × the bound
  talus 2.27 / 1.75 → 1.89 / 1.54 and 1.87 / 1.71 → 1.56 / 1.53, the tibia 2.36 / 2.21 → 2.32 /
  2.11 and 2.40 / 1.90 → 2.14 / 1.57. On the three seeds the subtracted sequential search tracks as
  joint tracking does (silent counts within 1, ratios within 0.06, mean rotation errors within
  0.004°): the neighbours' bias is the whole difference between the modes. What is left is shared:
  on seed 1 the tibia is 0.33-0.43° off about its long axis (0.37-0.46° in all) in frames 6-7 and
  37-39 jointly too (4.5-5.6× its rotation bound, unflagged) — not the neighbours.
* **Where it is on** (``sequential_subtract``, None — "auto" — by default since this study):
  :func:`core.tracking.from_study.track_study` (``talus track``, ``talus batch``, the window)
  subtracts the neighbours in sequential tracking of flatfield-corrected frames and searches
  against the whole image otherwise: sequential tracking is also the mode for frames whose DRR
  intensities are not matched to the images (``mode="auto"`` picks it where the frames are not
  flatfield-corrected; on the wrist sample's 8-bit radiographs a subtraction pulled the radius into
  the hole left where the ulna was subtracted, :mod:`core.studies.tracking.wrist_check`), where the
  subtraction is the harm. :func:`core.tracking.trial.track` alone, which cannot tell, keeps it off
  unless told (this study's runs set it explicitly).
"""

from __future__ import annotations

import argparse
import json
import platform
import time

import numpy as np

__all__ = ["main", "neighbour_share", "probe", "run", "summarise"]

ACCEPTANCE_JSON = "resources/benchmarks/tracking_acceptance_modes_h100.json"


def _bounds_from(path: str) -> dict:
    """Per bone ``{"rms_mm", "rms_deg"}`` of the acceptance run's Cramér–Rao bound (same scene)."""
    with open(path) as fh:
        d = json.load(fh)
    runs = d.get("runs") or {"joint": d}
    t = next(iter(runs.values()))["tracking"]
    return {n: {"rms_mm": v["cramer_rao"]["rms_mm"], "rms_deg": v["cramer_rao"]["rms_deg"]}
            for n, v in t.items() if "cramer_rao" in v}


def summarise(ts, res, bound: dict, k: float = 4.0) -> dict:
    """Per bone of ``res`` (a :class:`~core.tracking.results.TrackingResult` of ``ts``): RMS errors
    and × the bound, frames over ``k`` × the bound, the silent (unflagged) ones, flagged frames,
    and the per-frame errors (mm ×3, degrees ×3)."""
    from core.studies.tracking.acceptance import pose_errors

    out = {}
    for b, (n, m) in enumerate(zip(ts.names, ts.models, strict=True)):
        frames, E, flagged = [], [], []
        for f in range(ts.scene.n_frames):
            fr = res.results.get((n, f))
            if fr is None or fr.pose is None:
                continue
            frames.append(f)
            E.append(pose_errors(fr.pose, ts.truth(f)[b], m.centroid))
            if fr.flags:
                flagged.append(f)
        E = np.array(E)
        et, er = np.linalg.norm(E[:, :3], axis=1), np.linalg.norm(E[:, 3:], axis=1)
        row = {"rms_mm": float(np.sqrt(np.mean(et ** 2))), "rms_deg": float(np.sqrt(np.mean(er ** 2))),
               "mean_error_deg": E[:, 3:].mean(0).round(4).tolist(), "flagged_frames": flagged,
               "per_frame_error": E.round(5).tolist(), "frames": frames}
        cb = bound.get(n)
        if cb:
            over = (et > k * cb["rms_mm"]) | (er > k * cb["rms_deg"])
            bad = [f for f, o in zip(frames, over, strict=True) if o]
            ratio = {"mm": row["rms_mm"] / cb["rms_mm"], "deg": row["rms_deg"] / cb["rms_deg"]}
            row.update({"over_bound": ratio, f"over_{k:g}x_frames": bad,
                        "silent_frames": [f for f in bad if f not in flagged],
                        "silent": sum(f not in flagged for f in bad)})
        out[n] = row
    return out


def _engine_at(ts, b: int, frame, pose, others, o):
    """The Gauss–Newton engine's cost of bone ``b`` on ``frame`` about ``pose`` (its search regions
    and parameterisation, ``others`` subtracted), as :func:`core.tracking.register.register` sets it."""
    from core.tracking.engine import engine_cost
    from core.tracking.register import mm_per_pixel, search_region

    m, views = ts.models[b], tuple(range(len(ts.renderer.cameras)))
    roi = search_region(ts.renderer, pose, b, views=views, center=m.centroid, options=o.registration,
                        outline=m.outline)
    c = engine_cost(ts.renderer, bone=b, views=views, scale=1.0, term=o.registration.terms[0])
    c.set_frame(frame, base_pose=pose, center=m.centroid, roi=roi, others=others,
                px_mm=mm_per_pixel(ts.renderer, pose, m.centroid, views))
    return c, roi


def neighbour_share(ts, b: int, poses: np.ndarray, roi: np.ndarray) -> list[dict]:
    """Per view, the other bones' share of bone ``b``'s search region ``roi`` (full resolution) at
    ``poses`` (every bone's): pixels where a neighbour's line integral is over 5 % of its largest,
    and the neighbours' share of the squared gradient of the bones' summed DRR."""
    views = tuple(range(len(ts.renderer.cameras)))
    n = len(ts.names)
    img = ts.renderer.render(np.asarray(poses, float)[None], views=views, bones=list(range(n)),
                             roi=np.asarray(roi)[None, :, None, :], scale=1.0).numpy()[0]  # view, bone, H, W
    out = []
    for v in range(len(views)):
        h, w = int(roi[v][3]), int(roi[v][2])
        own = img[v, b, :h, :w].astype(float)
        rest = sum(img[v, k, :h, :w].astype(float) for k in range(n) if k != b)
        g_own = sum(x ** 2 for x in np.gradient(own))
        g_rest = sum(x ** 2 for x in np.gradient(rest))
        thr = 0.05 * max(float(rest.max()), 1e-12)
        out.append({"view": v, "pixels_share": round(float(np.mean(rest > thr)), 4),
                    "gradient_share": round(float(g_rest.sum() / max(g_own.sum() + g_rest.sum(), 1e-30)), 4),
                    "overlap_with_bone_share": round(float(np.mean((rest > thr) & (own > 0.05 * own.max()))),
                                                     4)})
    return out


def probe(ts, res, b: int, frames, o) -> list[dict]:
    """The cost at the truth and the estimate, a scan between them, restarts from the truth, and
    the neighbours' share of the search regions, for bone ``b`` in ``frames`` of ``res``."""
    from core.studies.tracking.acceptance import pose_errors
    from core.tracking.cost import OutsideViewError, prepare_frame
    from core.tracking.register import register

    n, m = ts.names[b], ts.models[b]
    others_ids = [k for k in range(len(ts.names)) if k != b]
    fractions = [-0.5, 0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5]
    rows = []
    for f in frames:
        T = ts.truth(f)
        fr = res.results.get((n, f))
        if fr is None or fr.pose is None:
            continue
        frame = prepare_frame(ts.frames(f), valid_range=o.valid_range, erode_px=o.erode_px)
        got = [res.results[(ts.names[k], f)].pose for k in range(len(ts.names))]
        tracked = np.array([T[k] if p is None else p for k, p in enumerate(got)])
        subtract = {"alone": None, "truth": (T[others_ids], others_ids),
                    "tracked": (tracked[others_ids], others_ids)}
        row = {"frame": f, "error": pose_errors(fr.pose, T[b], m.centroid).round(4).tolist(),
               "flags": list(fr.flags), "cost": {}, "restart_from_truth": {}}
        try:
            for key, oth in subtract.items():
                c, roi = _engine_at(ts, b, frame, T[b], oth, o)
                x_est = _params(fr.pose, T[b], m.centroid)
                X = np.array([t * x_est for t in fractions])
                s = 1.0 - np.asarray(c(X), float)
                row["cost"][key] = {"score_truth": float(s[1]), "score_estimate": float(s[5]),
                                    "estimate_better": bool(s[5] > s[1]),
                                    "scan": {f"{t:g}": round(float(v), 7)
                                             for t, v in zip(fractions, s, strict=True)},
                                    "scan_best_fraction": fractions[int(np.argmax(s))]}
            row["neighbours"] = neighbour_share(ts, b, T, roi)
            for key in ("alone", "truth"):
                r = register(ts.renderer, frame, bone=b, initial_pose=T[b], center=m.centroid,
                             options=o.registration, others=subtract[key], outline=m.outline)
                e = pose_errors(r.pose, T[b], m.centroid)
                d = pose_errors(r.pose, fr.pose, m.centroid)
                row["restart_from_truth"][key] = {"error": e.round(4).tolist(), "score": float(r.score),
                                                  "converged": bool(r.converged),
                                                  "to_estimate_deg": float(np.linalg.norm(d[3:])),
                                                  "to_estimate_mm": float(np.linalg.norm(d[:3]))}
        except OutsideViewError as exc:
            row["outside"] = str(exc)
        rows.append(row)
    return rows


def _params(pose, base, center) -> np.ndarray:
    from core.geometry.transforms import params_from_pose

    p = params_from_pose(np.asarray(pose, float), center=center, base=base)
    return np.concatenate([p[:3], np.degrees(p[3:])])


def _track(ts, keyframes, mode: str, subtract: bool):
    from core.tracking.trial import TrackingOptions, track

    o = TrackingOptions(mode=mode, sequential_subtract=subtract)
    t0 = time.perf_counter()
    res = track(ts.renderer, ts.models, ts.frames, range(ts.scene.n_frames), keyframes=keyframes, options=o)
    return res, o, time.perf_counter() - t0


def _pair_diff(ts, a, b) -> dict:
    """Per bone, the per-frame rotation (degrees) and translation (mm) between two runs' poses."""
    from core.studies.tracking.acceptance import pose_errors

    out = {}
    for n, m in zip(ts.names, ts.models, strict=True):
        deg, mm = [], []
        for f in range(ts.scene.n_frames):
            p, q = a.results[(n, f)].pose, b.results[(n, f)].pose
            if p is None or q is None:
                deg.append(None)
                mm.append(None)
                continue
            e = pose_errors(p, q, m.centroid)
            deg.append(round(float(np.linalg.norm(e[3:])), 4))
            mm.append(round(float(np.linalg.norm(e[:3])), 4))
        out[n] = {"deg": deg, "mm": mm}
    return out


def _default_bound(quick: bool, bound: str | None) -> str:
    """``bound`` as given; None: the acceptance JSON (seed 0's, 1024²), or ``"compute"`` with ``quick``
    (256² views, 1 mm voxels: the JSON's bound is another scene's)."""
    if bound is not None:
        return bound
    return "compute" if quick else ACCEPTANCE_JSON


def _bound_error(seed: int, bound: str) -> str | None:
    """Why ``bound`` cannot be trial ``seed``'s (None where it can): an acceptance JSON is seed 0's."""
    if seed != 0 and bound != "compute":
        return (f"seed {seed}: another trial's bound is not the acceptance JSON's ({bound}); "
                "use bound 'compute' (--bound compute)")
    return None


def run(*, quick: bool = False, device: str | None = None, n_frames: int | None = None, workers: int = 0,
        bones=("tibia", "talus"), probe_frames=None, bound: str | None = None,
        joint: bool = False, seed: int = 0) -> dict:
    """The study (module docs); returns the JSON-ready results. ``bound``: an acceptance JSON of the
    same scene (None: seed 0's at full size; ``"compute"`` with ``quick``, whose smaller scene the JSON's
    bound is not) or ``"compute"``; another ``seed`` needs ``"compute"`` (ValueError before any work
    otherwise: seed 0's bound would divide another trial's errors)."""
    bound = _default_bound(quick, bound)
    from core.geometry.transforms import pose_from_params
    from core.studies.tracking.acceptance import _random_offset, cramer_rao, tracking_scene
    from core.studies.tracking.trial_frames import synthesise

    if (why := _bound_error(seed, bound)) is not None:
        raise ValueError(why)
    t0 = time.perf_counter()
    ts = tracking_scene(quick=quick, device=device, n_frames=n_frames, seed=seed)
    g = np.random.default_rng(ts._seed + 7)  # the acceptance study's start (5 mm, 5 deg off)
    keyframes = {n: {0: pose_from_params(_random_offset(g, 5.0, 5.0), center=m.centroid, base=ts.truth(0)[b])}
                 for b, (n, m) in enumerate(zip(ts.names, ts.models, strict=True))}
    synthesise(ts, range(ts.scene.n_frames), workers)
    t_scene = time.perf_counter() - t0
    if bound == "compute":
        cb = cramer_rao(ts, range(0, ts.scene.n_frames, max(1, ts.scene.n_frames // 10)))
        bounds = {n: {"rms_mm": v["rms_mm"], "rms_deg": v["rms_deg"]} for n, v in cb.items()}
    else:
        bounds = _bounds_from(bound)
    nf = ts.scene.n_frames
    pf = [f for f in (probe_frames if probe_frames is not None else range(50, 73)) if 0 <= f < nf]
    out = {"study": "core.studies.tracking.sequential_drift", "quick": quick, "seed": seed,
           "machine": platform.machine(),
           "device": str(ts.renderer.device), "frames": nf, "pixels": ts.scene.rig[0].width,
           "bound": {"source": bound, **bounds}, "probe_frames": pf, "scene_s": t_scene, "runs": {},
           "timing_s": {}}
    seq, o, dt = _track(ts, keyframes, "sequential", False)
    out["runs"]["sequential"] = summarise(ts, seq, bounds)
    out["timing_s"]["sequential"] = dt
    t1 = time.perf_counter()
    out["probes"] = {n: probe(ts, seq, ts.names.index(n), pf, o) for n in bones if n in ts.names}
    out["timing_s"]["probes"] = time.perf_counter() - t1
    sub, _, dt = _track(ts, keyframes, "sequential", True)
    out["runs"]["sequential_subtracted"] = summarise(ts, sub, bounds)
    out["timing_s"]["sequential_subtracted"] = dt
    out["alone_vs_subtracted"] = _pair_diff(ts, seq, sub)
    if joint:
        jt, _, dt = _track(ts, keyframes, "joint", False)
        out["runs"]["joint"] = summarise(ts, jt, bounds)
        out["timing_s"]["joint"] = dt
    out["total_s"] = time.perf_counter() - t0
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.sequential_drift",
                                description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="256² views, 1 mm voxels, 20 frames (CPU check)")
    p.add_argument("--device", default=None, help="Warp device (cpu, cuda:0); default CUDA when present")
    p.add_argument("--frames", type=int, default=None, help="number of frames (default 20 quick / 100)")
    p.add_argument("--workers", type=int, default=0, help="processes for the frames' image chain")
    p.add_argument("--bones", default="tibia,talus", help="bones probed (comma-separated)")
    p.add_argument("--probe-frames", default="50-72", help="frames probed: a-b (inclusive) or a,b,c")
    p.add_argument("--bound", default=None,
                   help="the bound: an acceptance JSON of the same scene, or 'compute' (default: the "
                        "acceptance JSON at full size, computed with --quick, whose scene is another)")
    p.add_argument("--joint", action="store_true", help="track jointly too (reference)")
    p.add_argument("--seed", type=int, default=0,
                   help="the trial's seed (default 0, the acceptance study's; another needs --bound compute)")
    p.add_argument("--out", default=None, help="also write the JSON here")
    a = p.parse_args(argv)
    a.bound = _default_bound(a.quick, a.bound)
    if (why := _bound_error(a.seed, a.bound)) is not None:
        p.error(f"--seed: {why}")
    if "-" in a.probe_frames:
        lo, hi = (int(v) for v in a.probe_frames.split("-"))
        pf = list(range(lo, hi + 1))
    else:
        pf = [int(v) for v in a.probe_frames.split(",") if v.strip()]
    from core.io.atomic import print_json

    print_json(run(quick=a.quick, device=a.device, n_frames=a.frames, workers=a.workers,
                   bones=tuple(b.strip() for b in a.bones.split(",") if b.strip()), probe_frames=pf,
                   bound=a.bound, joint=a.joint, seed=a.seed), a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
