"""Robustness of the two tracking searches, ``local`` (quadratic models) against ``newton``
(Gauss–Newton steps), where the default choice between them is decided
(``python -m core.studies.tracking.search_robustness``).

On the acceptance trial (:func:`core.studies.tracking.acceptance.tracking_scene`, its default
grid-fitted distortion correction), each search in turn, on the same scene, the same frames and the
same random starts:

* **capture** — first-frame registrations (:func:`core.tracking.trial.register_start`: the widened
  first-frame options, the checks and the restart check, what a user gets from a hand-placed start)
  from the truth moved by exactly ``mm`` / ``deg`` in random directions, for each ``--offsets``
  pair; per bone the success fraction (mean surface error, TRE, ≤ 0.5 mm, as
  :func:`~core.studies.tracking.acceptance.capture_range`), the strict one (centroid ≤ 0.5 mm and
  rotation ≤ 0.5°), flagged starts, *silent misses* (TRE over 0.5 mm and no flag), median / max
  TRE and the mean time per start. The draws are :func:`capture_range`'s (same ``seed``: its 5 mm
  / 5° trials are the acceptance study's);
* **large inter-frame motion** — every ``k``-th frame of the trial tracked (``--strides``; ``k``
  times the motion between the frames a tracker sees, the velocity guess's miss growing with it),
  from the truth moved by 5 mm / 5° at the first frame, in ``--mode``; per bone the RMS and max
  errors, frames converged and flagged, silent failures (unflagged, over 0.5 mm or 0.5°), *lost*
  frames (over 2 mm or 5°), and the true motion between tracked frames.

Both searches are warmed up first (one first-frame registration each) so neither run pays Warp's
compilation. ``--quick``: 256² views, 1 mm voxels, 20 frames (a CPU); the full size 1024², 0.5 mm,
100 frames. The JSON goes to stdout (and ``--out``, rewritten after every part so a run cut short
keeps what it finished).
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np

from core.geometry.transforms import pose_from_params
from core.studies.tracking import acceptance as acc
from core.studies.tracking.acceptance import CORRECTIONS, DEFAULT_CORRECTION, mean_tre, pose_errors

__all__ = ["SEARCHES", "capture", "main", "run", "strided"]

SEARCHES = ("local", "newton")


def _options(search: str, mode: str):
    from dataclasses import replace

    from core.tracking.trial import TrackingOptions

    o = TrackingOptions(mode=mode)
    return replace(o, registration=replace(o.registration, search=search))


def capture(ts, options, *, trials: int, mm: float, deg: float, seed: int = 1, tre_mm: float = 0.5) -> dict:
    """Per bone, first-frame registrations from starts exactly ``mm`` / ``deg`` off the truth (the
    random frames and directions of :func:`core.studies.tracking.acceptance.capture_range` for the
    same ``seed``)."""
    from core.tracking.cost import prepare_frame
    from core.tracking.trial import register_start

    g = np.random.default_rng(seed)
    out = {}
    for b, m in enumerate(ts.models):
        surface = acc.surface_points(m)
        rows = []
        for k in range(trials):
            f = int(g.integers(ts.scene.n_frames))
            truth = ts.truth(f)[b]
            init = pose_from_params(acc._random_offset(g, mm, deg), center=m.centroid, base=truth)
            frame = prepare_frame(ts.frames(f))
            res = register_start(ts.renderer, frame, m, b, init, options=options, seed=k)
            if res.pose is None:
                rows.append((f, np.inf, np.inf, np.inf, True, res.time_s, res.evaluations))
                continue
            e = pose_errors(res.pose, truth, m.centroid)
            rows.append((f, float(np.linalg.norm(e[:3])), float(np.linalg.norm(e[3:])),
                         mean_tre(m, res.pose, truth, points=surface), bool(res.flags), res.time_s,
                         res.evaluations))
        tre = np.array([r[3] for r in rows])
        et, er = np.array([r[1] for r in rows]), np.array([r[2] for r in rows])
        flagged = np.array([r[4] for r in rows])
        miss = tre > tre_mm
        out[ts.names[b]] = {
            "trials": trials, "success_fraction": float(np.mean(~miss)),
            "strict_success_fraction": float(np.mean((et <= 0.5) & (er <= 0.5))),
            "flagged": int(flagged.sum()), "misses": int(miss.sum()),
            "silent_misses": int((miss & ~flagged).sum()),
            "median_tre_mm": float(np.median(tre)), "max_tre_mm": float(np.max(tre)),
            "max_error_mm": float(np.max(et)), "max_error_deg": float(np.max(er)),
            "mean_time_s": float(np.mean([r[5] for r in rows])),
            "mean_evaluations": float(np.mean([r[6] for r in rows])),
            "per_trial": [{"frame": r[0], "mm": round(r[1], 4), "deg": round(r[2], 4),
                           "tre_mm": round(r[3], 4), "flagged": r[4]} for r in rows]}
    return out


def strided(ts, options, *, stride: int, seed: int = 0, lost=(2.0, 5.0), bound: dict | None = None) -> dict:
    """Track every ``stride``-th frame of the trial (the tracker sees them as consecutive frames)
    from the truth moved 5 mm / 5° at the first; per bone errors, flags and silent failures, and
    with ``bound`` (:func:`~core.studies.tracking.acceptance.cramer_rao`) the RMS errors over it
    and the frames over 4× it (flagged or not), as the acceptance study counts them."""
    from core.tracking.trial import track

    frames = list(range(0, ts.scene.n_frames, stride))
    g = np.random.default_rng(seed + 7)
    keyframes = {n: {0: pose_from_params(acc._random_offset(g, 5.0, 5.0), center=m.centroid,
                                         base=ts.truth(0)[b])}
                 for b, (n, m) in enumerate(zip(ts.names, ts.models, strict=True))}
    for f in frames:  # synthesise the images first: not part of tracking time
        ts.frames(f)
    t0 = time.perf_counter()
    res = track(ts.renderer, ts.models, lambda k: ts.frames(frames[k]), range(len(frames)),
                keyframes=keyframes, options=options)
    wall = time.perf_counter() - t0
    bones = {}
    for b, (n, m) in enumerate(zip(ts.names, ts.models, strict=True)):
        E, flags, conv = [], [], 0
        for k, f in enumerate(frames):
            fr = res.results[(n, k)]
            conv += fr.converged
            if fr.pose is None:
                E.append(np.full(6, np.inf))
            else:
                E.append(pose_errors(fr.pose, ts.truth(f)[b], m.centroid))
            flags.append(bool(fr.flags))
        E, flags = np.array(E), np.array(flags)
        et, er = np.linalg.norm(E[:, :3], axis=1), np.linalg.norm(E[:, 3:], axis=1)
        bad = (et > 0.5) | (er > 0.5)
        motion = np.array([pose_errors(ts.truth(frames[k + 1])[b], ts.truth(frames[k])[b], m.centroid)
                           for k in range(len(frames) - 1)])
        mt, mr = np.linalg.norm(motion[:, :3], axis=1), np.linalg.norm(motion[:, 3:], axis=1)
        bones[n] = {"rms_mm": float(np.sqrt(np.mean(et ** 2))), "rms_deg": float(np.sqrt(np.mean(er ** 2))),
                    "max_mm": float(et.max()), "max_deg": float(er.max()),
                    "converged": int(conv), "flagged": int(flags.sum()),
                    "silent_failures": int((bad & ~flags).sum()),
                    "lost": int(((et > lost[0]) | (er > lost[1])).sum()),
                    "motion_mm": {"median": float(np.median(mt)), "max": float(mt.max())},
                    "motion_deg": {"median": float(np.median(mr)), "max": float(mr.max())}}
        if bound and n in bound:
            cb = bound[n]
            over = (et > 4 * cb["rms_mm"]) | (er > 4 * cb["rms_deg"])
            bones[n]["rms_over_bound"] = {"mm": bones[n]["rms_mm"] / cb["rms_mm"],
                                          "deg": bones[n]["rms_deg"] / cb["rms_deg"]}
            bones[n]["over_4x_bound"] = {"frames": [frames[k] for k in np.flatnonzero(over)],
                                         "silent": int((over & ~flags).sum())}
    s = res.summary()
    return {"stride": stride, "frames": len(frames), "tracking_s": wall,
            "ms_per_frame": 1e3 * wall / len(frames), "evaluations": s.get("evaluations"), "bones": bones}


def run(*, quick: bool = True, device: str | None = None, searches=SEARCHES, offsets=((5.0, 5.0),),
        trials: int = 5, strides=(1,), mode: str = "joint", correction: str = DEFAULT_CORRECTION,
        n_frames: int | None = None, seed: int = 0, out: str | None = None) -> dict:
    """The study (module docs); returns the JSON-ready results, written to ``out`` after every part."""
    from core.io.atomic import print_json

    t0 = time.perf_counter()
    ts = acc.tracking_scene(quick=quick, device=device, seed=seed, n_frames=n_frames, correction=correction)
    res = {"study": "core.studies.tracking.search_robustness", "quick": quick, "machine": platform.machine(),
           "processor": platform.processor() or platform.machine(), "device": str(ts.renderer.device),
           "config": {"pixels": ts.scene.rig[0].width, "voxel_mm": float(ts.models[0].volume.spacing[0]),
                      "frames": ts.scene.n_frames, "mode": mode, "correction": correction,
                      "offsets": [list(o) for o in offsets], "trials": trials, "strides": list(strides),
                      "searches": list(searches)},
           "scene_s": time.perf_counter() - t0, "warmup_s": {}, "capture": {}, "strided": {}}

    def save():
        res["total_s"] = time.perf_counter() - t0
        if out:
            print_json(res, out)

    opts = {s: _options(s, mode) for s in searches}
    for s in searches:  # compile each search's kernels before anything is timed
        t = time.perf_counter()
        capture(ts, opts[s], trials=1, mm=5.0, deg=5.0, seed=seed + 99)
        res["warmup_s"][s] = time.perf_counter() - t
    save()
    for mm, deg in offsets:
        key = f"{mm:g}mm_{deg:g}deg"
        res["capture"][key] = {}
        for s in searches:
            t = time.perf_counter()
            res["capture"][key][s] = capture(ts, opts[s], trials=trials, mm=mm, deg=deg, seed=seed + 1)
            res["capture"][key][s]["wall_s"] = time.perf_counter() - t
            save()
    bound = None
    if strides:  # the acceptance study's per-frame bound (every tenth frame), shared by the runs
        t = time.perf_counter()
        bound = acc.cramer_rao(ts, range(0, ts.scene.n_frames, max(1, ts.scene.n_frames // 10)))
        res["cramer_rao"] = {n: {"rms_mm": b["rms_mm"], "rms_deg": b["rms_deg"]} for n, b in bound.items()}
        res["bound_s"] = time.perf_counter() - t
    for k in strides:
        res["strided"][str(k)] = {}
        for s in searches:
            res["strided"][str(k)][s] = strided(ts, opts[s], stride=k, seed=seed, bound=bound)
            save()
    save()
    return res


def _pairs(text: str) -> tuple:
    return tuple(tuple(float(v) for v in p.split(",")) for p in text.split(";") if p)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.search_robustness",
                                description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="256² views, 1 mm voxels, 20 frames")
    p.add_argument("--device", default=None, help="Warp device (cpu, cuda:0); default CUDA when present")
    p.add_argument("--frames", type=int, default=None, help="frames of the trial (default 20 quick / 100)")
    p.add_argument("--searches", default=",".join(SEARCHES))
    p.add_argument("--offsets", default="5,5", help="start offsets 'mm,deg;mm,deg;...' (default 5,5)")
    p.add_argument("--trials", type=int, default=5, help="first-frame registrations per bone and offset")
    p.add_argument("--strides", default="1", help="comma-separated k: track every k-th frame (0: none)")
    p.add_argument("--mode", choices=("sequential", "joint"), default="joint")
    p.add_argument("--correction", choices=CORRECTIONS, default=DEFAULT_CORRECTION)
    p.add_argument("--out", default=None, help="also write the JSON here (after every part)")
    a = p.parse_args(argv)
    strides = tuple(int(k) for k in a.strides.split(",") if int(k) > 0)
    res = run(quick=a.quick, device=a.device, searches=tuple(a.searches.split(",")),
              offsets=_pairs(a.offsets), trials=a.trials, strides=strides, mode=a.mode,
              correction=a.correction, n_frames=a.frames, out=a.out)
    from core.io.atomic import print_json

    print_json(res, None)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
