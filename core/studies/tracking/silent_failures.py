"""Silent failures of the default tracker: what a user can see of frames whose error is over 4× the
Cramér–Rao bound (``python -m core.studies.tracking.silent_failures``).

Tracks the acceptance trial (:mod:`core.studies.tracking.acceptance`: its scene, its starts, the
grid-fitted distortion correction) with the tracker's defaults, per configuration ``mode:search``
(``joint:newton`` the default tracker) and scene seed, and keeps per bone and frame everything the
frame step knows — the pose and its error against the truth (only here), the score and each view's,
evaluations, batched calls, the stopping rule, the search's step from its start, the last quadratic
fit's gradient, Hessian and roughness, the confidence σ, the flags and notes, the time breakdown —
and the bone's Cramér–Rao bound (every tenth frame, as the acceptance study). ``--dump`` writes it
all to one compressed ``.npz`` per run (the analysis reads it back without a GPU); the JSON on
stdout counts, per configuration and bone, the frames over ``4×`` the bound, those left unflagged
(*silent*) and the good frames flagged, before and after the trajectory post-pass of
:mod:`core.tracking.flags_post` (the tracker's own result holds both: the post-pass flags carry
its flag name). The configurations track with the acceptance study's options
(:func:`~core.studies.tracking.acceptance.study_options`: sequentially with the neighbours
subtracted); ``--workers`` synthesises the frames in processes; ``--frame-bounds K`` also dumps each
frame's own bound (:func:`frame_bounds`, at the true pose) on every K-th frame and the frames over
4×. :mod:`core.studies.tracking.silent_checks` judges candidate checks on the dumps.
``--line`` evaluates a bone's cost from a dumped estimate to the truth
(:func:`cost_line`): whether a silent frame's truth is an optimum the search missed.

Seeds 0-2, joint and sequential, at ea76c8b (one NVIDIA H100;
``resources/benchmarks/tracking_silent_checks_h100.json``): 39 bone-frames over 4×, 20 silent after
the trajectory check as it was, 17 with its *next to a flagged frame* rule (:mod:`core.tracking.flags_post`).

Earlier (``resources/benchmarks/tracking_silent_failures_h100.json``; tracked on one NVIDIA H100,
the rest on this 2-core CPU machine): the post-pass and what it caught are in
:mod:`core.tracking.flags_post`'s docs. No per-frame quantity the tracker keeps separated the
frames over 4× the bound from the others (rank AUC 0.42-0.59). The runs it leaves silent (the tibia
off about its long axis for several frames) are the cost's own optima: in the seed-1 joint runs
(frames 5-8, 10, 38, 39) the cost at the truth is 0.00017-0.0024 worse than at the estimate, its
best along the line within a quarter of the way (frame 38 halfway), so neither a wider search nor
restarts would find or flag them. Where the line falls towards the truth (seed 0 jointly, frames
41, 50, 81, 89; 4 of 5 sequential failures) it is the host cost's own roughness: moving every
frame's axial rotation to the host cost's one-dimensional minimum leaves the tibia's RMS 0.173 →
0.178° (4 of its 5 failures fixed, 3 new), halfway between the two minima 0.155°.
"""

from __future__ import annotations

import argparse
import json
import platform
import time

import numpy as np

__all__ = ["analyse", "cost_line", "count", "dump_run", "main"]

#: The issue's failure: an error over this many times the bone's Cramér–Rao bound (RMS of its
#: per-frame bounds), translation or rotation (:func:`core.studies.tracking.acceptance_records.over_bound`).
OVER = 4.0


def _capture():
    """Patch the frame step to keep each bone-frame's final registration (the study only)."""
    from core.tracking import frame_step

    kept: dict = {}
    orig = frame_step._frame_result

    def keep(name, f, a, w):
        kept[(name, f)] = a.result
        return orig(name, f, a, w)

    frame_step._frame_result = keep
    return kept, lambda: setattr(frame_step, "_frame_result", orig)


def dump_run(ts, *, mode: str, search: str, seed: int, post: bool = True) -> dict:
    """Track scene ``ts`` (a :class:`~core.studies.tracking.acceptance.TrackingScene`) with
    ``mode`` and ``search`` from the acceptance study's starts and options
    (:func:`~core.studies.tracking.acceptance.study_options`); per bone, arrays over the frames."""
    from dataclasses import replace

    from core.geometry.transforms import pose_from_params
    from core.studies.tracking.acceptance import _random_offset, pose_errors, study_options
    from core.tracking.checks import _distance, _predict
    from core.tracking.trial import track

    o = study_options(mode, search)  # as the acceptance study (sequential: the neighbours subtracted)
    if not post and hasattr(o, "trajectory_limit"):
        o = replace(o, trajectory_limit=None)
    g = np.random.default_rng(seed + 7)
    keyframes = {n: {0: pose_from_params(_random_offset(g, 5.0, 5.0), center=m.centroid, base=ts.truth(0)[b])}
                 for b, (n, m) in enumerate(zip(ts.names, ts.models, strict=True))}
    n_frames = ts.scene.n_frames
    kept, undo = _capture()
    try:
        t0 = time.perf_counter()
        res = track(ts.renderer, ts.models, ts.frames, range(n_frames), keyframes=keyframes, options=o)
        dt = time.perf_counter() - t0
    finally:
        undo()
    out = {"time_s": dt, "bones": {}}
    for b, (n, m) in enumerate(zip(ts.names, ts.models, strict=True)):
        c = m.centroid
        rec = {k: [] for k in ("err", "pose", "truth", "score", "view_scores", "evaluations", "generations",
                               "reason", "x", "grad", "hessian", "fit_noise", "sigma", "flags", "notes",
                               "timing", "pred_mm", "pred_deg", "retried", "center")}
        for f in range(n_frames):
            fr = res.results[(n, f)]
            r = kept.get((n, f))
            P = np.full((4, 4), np.nan) if fr.pose is None else np.asarray(fr.pose, float)
            rec["pose"].append(P)
            rec["truth"].append(ts.truth(f)[b])
            e = pose_errors(P, ts.truth(f)[b], c) if fr.pose is not None else np.full(6, np.nan)
            rec["err"].append(e)
            rec["score"].append(fr.score)
            rec["evaluations"].append(fr.evaluations)
            rec["retried"].append(fr.retried)
            rec["flags"].append(list(fr.flags))
            rec["notes"].append(list(fr.notes))
            rec["timing"].append(fr.timing or {})
            s = (fr.confidence or {}).get("sigma") or [None] * 6
            rec["sigma"].append([np.nan if v is None else v for v in s])
            fit = getattr(r, "fit", None)
            rec["view_scores"].append(np.asarray(getattr(r, "view_scores", [np.nan, np.nan]), float)[:2])
            rec["generations"].append(getattr(r, "generations", -1))
            rec["reason"].append(getattr(r, "reason", ""))
            rec["x"].append(np.asarray(getattr(r, "x", np.full(6, np.nan)), float))
            rec["grad"].append(np.full(6, np.nan) if fit is None else np.asarray(fit.g, float))
            rec["hessian"].append(np.full((6, 6), np.nan) if fit is None else np.asarray(fit.H, float))
            rec["fit_noise"].append(np.nan if fit is None else float(fit.noise))
            pm = pd = np.nan
            if f >= 2 and fr.pose is not None:  # the constant-velocity prediction from the two frames before
                p0, p1 = res.results[(n, f - 2)].pose, res.results[(n, f - 1)].pose
                if p0 is not None and p1 is not None:
                    pm, pd = _distance(_predict(f - 2, p0, f - 1, p1, f, c), P, c)
            rec["pred_mm"].append(pm)
            rec["pred_deg"].append(pd)
        rec["center"] = [np.asarray(c, float)]
        out["bones"][n] = rec
    return out


def frame_bounds(ts, frames) -> dict:
    """Per bone, ``(n_frames, 6, 6)`` Cramér–Rao covariances (:func:`core.tracking.bound.pose_bound`
    at the true pose, mm and degrees) in ``frames``, NaN elsewhere: the bound of each frame itself
    rather than the bone's RMS over every tenth frame."""
    from core.tracking.bound import pose_bound
    from core.tracking.cost import OutsideViewError

    N = [m.photons_per_pixel for m in ts.scene.imaging]
    out = {n: np.full((ts.scene.n_frames, 6, 6), np.nan) for n in ts.names}
    if any(v is None for v in N):
        return out
    for f in sorted({int(f) for f in frames}):
        L = ts.scene.line_integrals(f, renderer=ts._scene_renderer)
        for b, (n, m) in enumerate(zip(ts.names, ts.models, strict=True)):
            try:
                out[n][f] = pose_bound(ts.renderer, b, ts.truth(f)[b], m.centroid, line_integral=L,
                                       quanta_per_pixel=N).covariance
            except OutsideViewError:
                pass
    return out


def count(err: np.ndarray, flags: list, bound: dict, post_name: str) -> dict:
    """Frames over :data:`OVER` × the bound, silent ones, and good frames flagged — with every flag,
    and without the post-pass's (flags starting with ``post_name``)."""
    e = np.asarray(err, float)
    ok = np.all(np.isfinite(e), axis=1)
    over = ok & ((np.linalg.norm(e[:, :3], axis=1) > OVER * bound["rms_mm"])
                 | (np.linalg.norm(e[:, 3:], axis=1) > OVER * bound["rms_deg"]))
    before = np.array([any(not s.startswith(post_name) for s in fl) for fl in flags])
    after = np.array([bool(fl) for fl in flags])
    frames = np.flatnonzero(over).tolist()
    return {"over": frames, "silent_before": [f for f in frames if not before[f]],
            "silent_after": [f for f in frames if not after[f]],
            "good_flagged_before": int((ok & ~over & before).sum()),
            "good_flagged_after": np.flatnonzero(ok & ~over & after).tolist(),
            "good_frames": int((ok & ~over).sum())}


def _center(z, n: str) -> np.ndarray:
    """The bone's rotation centre from a dump: kept, or solved from the errors (the centroid
    displacement of each pose from the truth is linear in it)."""
    if f"{n}.center" in z.files:
        return np.asarray(z[f"{n}.center"], float).reshape(3)
    P, T, E = z[f"{n}.pose"], z[f"{n}.truth"], z[f"{n}.err"]
    ok = np.all(np.isfinite(P.reshape(len(P), -1)), axis=1)
    A = np.concatenate([P[k, :3, :3] - T[k, :3, :3] for k in np.flatnonzero(ok)])
    y = np.concatenate([E[k, :3] - (P[k, :3, 3] - T[k, :3, 3]) for k in np.flatnonzero(ok)])
    return np.linalg.lstsq(A, y, rcond=None)[0]


def analyse(path: str, **post) -> dict:
    """Per bone of a dump (:func:`main` ``--dump``): the counts of :func:`count` with the frames'
    flags as the tracker left them, the post-pass's own flags taken off, then
    :func:`core.tracking.flags_post.apply_trajectory_flags` (``post``: its keywords) over the
    rebuilt :class:`~core.tracking.results.TrackingResult` — the user's path: the pass reads only
    the poses and flags, which the dump holds as the tracker returned them."""
    from core.tracking.flags_post import FLAG, apply_trajectory_flags
    from core.tracking.results import FrameResult, TrackingResult

    z = np.load(path)
    names = sorted({k.split(".")[0] for k in z.files}, key=lambda n: z.files.index(f"{n}.pose"))
    results, centers, truth = {}, {}, {}
    for n in names:
        P = z[f"{n}.pose"]
        flags = json.loads(str(z[f"{n}.flags"]))
        for f in range(len(P)):
            own = tuple(s for s in flags[f] if not s.startswith(FLAG))
            pose = P[f] if np.all(np.isfinite(P[f])) else None
            results[(n, f)] = FrameResult(n, f, pose, float(z[f"{n}.score"][f]), 0, 0.0, not own, own)
        centers[n] = _center(z, n)
        truth[n] = (z[f"{n}.err"], json.loads(str(z[f"{n}.bound"])))
    frames = tuple(range(len(z[f"{names[0]}.pose"])))
    res = TrackingResult(tuple(names), frames, results, "complete", 0.0)
    out, _ = apply_trajectory_flags(res, centers, **post)
    got = {}
    for n in names:
        E, bound = truth[n]
        fl = [list(out.results[(n, f)].flags) for f in frames]
        c = count(E, fl, bound, FLAG)
        q = np.maximum(np.linalg.norm(E[:, :3], axis=1) / bound["rms_mm"],
                       np.linalg.norm(E[:, 3:], axis=1) / bound["rms_deg"])
        c["good_flagged_ratio"] = [round(float(q[f]), 2) for f in c["good_flagged_after"]]
        c["over_ratio"] = [round(float(q[f]), 2) for f in c["over"]]
        got[n] = c
    return got


def cost_line(ts, path: str, frames, *, bone: int = 0, joint: bool = True,
              steps=(-0.5, -0.25, 0.0, 0.25, 0.5, 0.75, 1.0, 1.25, 1.5)) -> dict:
    """The similarity cost of bone ``bone`` in ``frames`` along the line from the dumped estimate
    (``path``, :func:`main` ``--dump`` of scene ``ts``) to the truth, at the fractions ``steps``
    (0: the estimate, 1: the truth; lower is better): whether the truth is a better optimum the search
    missed (the cost falls towards it) or the cost's own optimum is off (it rises). Host cost at full
    resolution (:class:`~core.tracking.cost.RegistrationCost`, the tracking options' terms), with the
    other bones subtracted at their estimates when ``joint``, as in the tracker's last joint round."""
    from core.geometry.transforms import params_from_pose
    from core.tracking.cost import RegistrationCost, prepare_frame
    from core.tracking.options import TrackingOptions
    from core.tracking.roi import search_roi

    z = np.load(path)
    o = TrackingOptions()
    m = ts.models[bone]
    c = m.centroid
    t = np.asarray(steps, dtype=float)
    out = {}
    for f in frames:
        frame = prepare_frame(ts.frames(f), valid_range=o.valid_range, erode_px=o.erode_px)
        est = [z[f"{n}.pose"][f] for n in ts.names]
        ids = [k for k in range(len(est)) if k != bone]
        others = (np.stack([est[k] for k in ids]), ids) if joint and ids else None
        roi = search_roi(ts.renderer, est[bone], bone, views=tuple(range(frame.n_views)), center=c,
                         reach_mm=2.0, points=m.outline)
        cost = RegistrationCost(ts.renderer, frame, bone=bone, base_pose=est[bone], center=c, roi=roi,
                                terms=o.registration.terms, others=others)
        d = params_from_pose(ts.truth(f)[bone], center=c, base=est[bone])
        d = np.r_[d[:3], np.degrees(d[3:])]
        v = np.asarray(cost(t[:, None] * d[None, :]), float)
        out[int(f)] = {"to_truth": d.round(4).tolist(), "cost": v.round(6).tolist(),
                       "truth_minus_estimate": round(float(v[t == 1.0][0] - v[t == 0.0][0]), 6),
                       "best_step": float(t[int(np.argmin(v))])}
    return {"steps": t.tolist(), "frames": out}


def main(argv=None) -> int:
    from core.studies.tracking.acceptance import cramer_rao, tracking_scene
    from core.tracking.flags_post import FLAG

    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.silent_failures",
                                description=__doc__.split("\n")[0])
    p.add_argument("--configs", default="joint:newton", help="mode:search,... (default joint:newton)")
    p.add_argument("--seeds", default="0", help="scene seeds, comma-separated")
    p.add_argument("--frames", type=int, default=100)
    p.add_argument("--pixels", type=int, default=1024)
    p.add_argument("--voxel", type=float, default=0.5)
    p.add_argument("--device", default=None)
    p.add_argument("--workers", type=int, default=0, help="processes for the frames' image chain")
    p.add_argument("--frame-bounds", type=int, default=0, metavar="K",
                   help="dump each frame's own bound on every K-th frame and the frames over 4x (0: none)")
    p.add_argument("--no-post", action="store_true", help="track without the trajectory post-pass")
    p.add_argument("--dump", default=None, help="write <dump>_<seed>_<mode>_<search>.npz")
    p.add_argument("--out", default=None, help="also write the JSON here")
    p.add_argument("--analyse", nargs="+", default=None, metavar="NPZ",
                   help="no tracking: count the dumps' frames before and after the post-pass (CPU)")
    p.add_argument("--limit", type=float, default=None, help="the post-pass's limit (--analyse)")
    p.add_argument("--line", default=None, metavar="NPZ",
                   help="no tracking: the tibia's cost from the dump's estimate to the truth in "
                   "--line-frames (the dump's scene: --seeds, one; joint unless its name says sequential)")
    p.add_argument("--line-frames", default="", help="frames for --line, comma-separated")
    a = p.parse_args(argv)
    if a.line:
        from core.io.atomic import print_json

        ts = tracking_scene(quick=a.pixels <= 256, device=a.device, seed=int(a.seeds.split(",")[0]),
                            n_frames=a.frames, pixels=a.pixels)
        frames = [int(f) for f in a.line_frames.split(",")]
        got = cost_line(ts, a.line, frames, joint="sequential" not in a.line)
        print_json({"study": "core.studies.tracking.silent_failures", "line": a.line, **got}, a.out)
        return 0
    if a.analyse:
        from core.io.atomic import print_json

        post = {} if a.limit is None else {"limit": a.limit}
        print_json({"study": "core.studies.tracking.silent_failures", "post": post,
                    "runs": {path: analyse(path, **post) for path in a.analyse}}, a.out)
        return 0
    from core.studies.tracking.trial_frames import synthesise

    out = {"study": "core.studies.tracking.silent_failures", "machine": platform.machine(), "runs": {}}
    for seed in (int(s) for s in a.seeds.split(",")):
        t0 = time.perf_counter()
        quick = a.pixels <= 256
        ts = tracking_scene(quick=quick, device=a.device, seed=seed, n_frames=a.frames, pixels=a.pixels)
        if a.voxel != (1.0 if quick else 0.5):
            raise SystemExit("--voxel: the acceptance scene's voxels are 1 mm at 256² and below, else 0.5 mm")
        synthesise(ts, range(ts.scene.n_frames), a.workers)
        setup = time.perf_counter() - t0
        bound = cramer_rao(ts, range(0, ts.scene.n_frames, max(1, ts.scene.n_frames // 10)))
        out["device"] = str(ts.renderer.device)
        dumps = {}
        for cfg in a.configs.split(","):
            mode, search = cfg.split(":")
            got = dump_run(ts, mode=mode, search=search, seed=seed, post=not a.no_post)
            key = f"{seed}:{mode}:{search}"
            run = {"setup_s": setup, "track_s": got["time_s"], "bones": {}}
            arrays = {}
            for n, rec in got["bones"].items():
                run["bones"][n] = dict(count(rec["err"], rec["flags"], bound[n], FLAG),
                                       bound_mm=bound[n]["rms_mm"], bound_deg=bound[n]["rms_deg"])
                for k, v in rec.items():
                    if k in ("flags", "notes", "timing", "reason"):
                        arrays[f"{n}.{k}"] = np.array(json.dumps(v))
                    else:
                        arrays[f"{n}.{k}"] = np.asarray(v, float)
                arrays[f"{n}.bound"] = np.array(json.dumps(bound[n]))
            out["runs"][key] = run
            dumps[(mode, search)] = arrays
            print(json.dumps({key: run}), flush=True)
        if a.frame_bounds:  # every k-th frame and every frame over 4x in any configuration
            t1 = time.perf_counter()
            fs = set(range(0, ts.scene.n_frames, a.frame_bounds))
            for key in out["runs"]:
                if key.startswith(f"{seed}:"):
                    fs |= {f for c in out["runs"][key]["bones"].values() for f in c["over"]}
            fb = frame_bounds(ts, fs)
            for arrays in dumps.values():
                arrays.update({f"{n}.frame_bound": C for n, C in fb.items()})
            out.setdefault("frame_bounds_s", {})[str(seed)] = time.perf_counter() - t1
        if a.dump:
            for (mode, search), arrays in dumps.items():
                np.savez_compressed(f"{a.dump}_{seed}_{mode}_{search}.npz", **arrays)
    from core.io.atomic import print_json

    print_json(out, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
