"""CPU time of whole tracking frames, one and several DRR threads (``python -m
core.studies.tracking.cpu_frames``).

One bone (the talus) of the synthetic walking trial of :mod:`core.studies.tracking.acceptance`
(``--pixels`` views, ``--voxel`` mm voxels, the 100-frame trial's speed) is tracked on the CPU
with the Gauss–Newton search by :func:`core.tracking.trial.track`: everything a frame costs —
the prediction, the registration, the failure checks and the confidence. Frames are synthesised
before the clock starts. Per frame the wall time, the process's CPU time (all threads) and the
load average (``/proc/loadavg``, 1 minute) when it ended; the machine is shared, so every timing
carries the load it was measured under.

* ``steady`` — frames 1 … n-1 with frame 0 given as its true pose (a tracked trial after its
  first frame), once per entry of ``--threads`` (:attr:`core.render.DRRRenderer.cpu_threads`)
  and ``--rounds`` times, alternating, so the thread counts see the same load; ``same_poses``:
  whether every thread count gave bit-identical poses.
* ``whole`` (unless ``--no-first``) — frames 0 … n-1 from the true pose at frame 0 as a keyframe
  with the last thread count: frame 0 is the first-frame search (widened options and the restart
  check), the dearest frame of a trial.

Accuracy: per-frame RMS centroid (mm) and rotation (°) errors over the Cramér–Rao bound of the
same trial (:func:`core.studies.tracking.acceptance.cramer_rao` on ``--bound-frames`` frames).
JSON on stdout (``--out``: also to a file).
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from dataclasses import replace

import numpy as np

__all__ = ["main", "run"]


def _load() -> list[float]:
    try:
        with open("/proc/loadavg") as f:
            return [float(x) for x in f.read().split()[:3]]
    except OSError:  # not Linux
        return [float(x) for x in os.getloadavg()]


def _rms(e: np.ndarray) -> tuple[float, float]:
    e = np.asarray(e).reshape(-1, 6)
    return (float(np.sqrt(np.mean(np.sum(e[:, :3] ** 2, axis=1)))),
            float(np.sqrt(np.mean(np.sum(e[:, 3:] ** 2, axis=1)))))


def _track(ts, r, model, index, frames, options, *, skip_first: bool) -> dict:
    """Track ``frames`` and time each one (wall, CPU of the whole process, load)."""
    from core.studies.tracking.acceptance import pose_errors
    from core.tracking.trial import track

    truth0 = ts.truth(0)[index]
    kf = {model.name: {0: truth0}}
    skip = {model.name: {0: truth0}} if skip_first else None
    rows = []
    mark = [time.perf_counter(), time.process_time()]

    def progress(done, total, fr):
        w, c = time.perf_counter(), time.process_time()
        row = {"frame": fr.frame, "wall_s": w - mark[0], "cpu_s": c - mark[1], "load_1min": _load()[0],
               "evaluations": int(fr.evaluations), "flags": list(fr.flags or []), "retried": bool(fr.retried)}
        if fr.pose is not None:
            e = pose_errors(fr.pose, ts.truth(fr.frame)[index], model.centroid)
            row.update(error_mm=float(np.linalg.norm(e[:3])), error_deg=float(np.linalg.norm(e[3:])),
                       error=[float(x) for x in e])
        t = fr.timing or {}
        row.update({k: float(t[k]) for k in ("render_s", "metric_s", "host_s", "optimizer_s", "other_s")
                    if k in t})
        rows.append(row)
        mark[0], mark[1] = time.perf_counter(), time.process_time()

    load0 = _load()
    res = track(r, [model], ts.frames, list(frames), keyframes=kf, options=options, skip=skip,
                progress=progress)
    P = res.poses(model.name)
    wall = [x["wall_s"] for x in rows]
    cpu = [x["cpu_s"] for x in rows]
    return {"load_before": load0, "load_after": _load(), "frames": [x["frame"] for x in rows],
            "wall_s_per_frame": float(np.mean(wall)), "cpu_s_per_frame": float(np.mean(cpu)),
            "max_wall_s": float(np.max(wall)), "per_frame": rows, "_poses": P}


def run(*, frames: int = 8, pixels: int = 512, voxel: float = 0.5, threads=(1, 2), rounds: int = 2,
        first: bool = True, bound_frames: int = 2, bone: int = 1) -> dict:
    """Run the study (module docs); returns the JSON-ready results."""
    from core.render import DRRRenderer
    from core.studies.tracking.acceptance import TrackingScene, cramer_rao
    from core.tracking.trial import TrackingOptions

    if frames < 2:
        raise ValueError(f"frames: expected >= 2, got {frames}")
    threads = [int(t) for t in threads]
    ts = TrackingScene(n_frames=frames, pixels=pixels, spacing=voxel, phase=(0.0, 0.6 * frames / 100.0),
                       device="cpu")
    t0 = time.perf_counter()
    for i in range(frames):
        ts.frames(i)
    synth = time.perf_counter() - t0
    model = ts.models[bone]
    name = ts.names[bone]
    bf = sorted({round(float(x)) for x in np.linspace(0, frames - 1, max(1, bound_frames))})
    bound = cramer_rao(ts, bf).get(name) if bound_frames > 0 else None
    base = TrackingOptions(mode="joint")
    o = replace(base, registration=replace(base.registration, search="newton"))
    r = DRRRenderer(ts.scene.rig, [model.volume.to_attenuation(ts.scene.bone_transfer)], device="cpu")
    out = {"study": "core.studies.tracking.cpu_frames", "machine": platform.machine(),
           "processor": platform.processor() or platform.machine(), "cpu_count": os.cpu_count(),
           "device": "cpu", "bone": name, "search": "newton", "pixels": pixels, "voxel_mm": voxel,
           "frames": frames,
           "threads_env": {k: os.environ.get(k)
                           for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "TALUS_CPU_THREADS")},
           "synthesis_s": synth, "bound": bound, "bound_frames": bf, "load_start": _load()}
    r.cpu_threads = threads[0]
    t0, c0 = time.perf_counter(), time.process_time()
    _track(ts, r, model, bone, [0, 1], o, skip_first=True)  # warm-up: kernels, buffers
    out["warm_up"] = {"wall_s": time.perf_counter() - t0, "cpu_s": time.process_time() - c0}

    def summary(runs):
        e = [x["error"] for run in runs for x in run["per_frame"] if "error" in x]
        mm, deg = _rms(e)
        s = {"rms_error_mm": mm, "rms_error_deg": deg,
             "flagged": sum(bool(x["flags"]) for run in runs for x in run["per_frame"])}
        if bound:
            s["bound_ratio"] = {"mm": mm / bound["rms_mm"], "deg": deg / bound["rms_deg"]}
        return s

    steady: dict = {"runs": []}
    poses = {}
    for k in range(int(rounds)):
        for t in threads:
            r.cpu_threads = t
            run_ = _track(ts, r, model, bone, range(frames), o, skip_first=True)
            P = run_.pop("_poses")
            poses.setdefault(t, P)
            steady["runs"].append({"threads": t, "round": k, **run_})
    for t in threads:
        mine = [x for x in steady["runs"] if x["threads"] == t]
        steady[f"threads_{t}"] = {
            "wall_s_per_frame": float(np.mean([x["wall_s_per_frame"] for x in mine])),
            "cpu_s_per_frame": float(np.mean([x["cpu_s_per_frame"] for x in mine])),
            "load_1min": [x["load_after"][0] for x in mine], **summary(mine[:1])}
    ref = poses[threads[0]]
    steady["same_poses"] = bool(all(np.array_equal(p, ref, equal_nan=True) for p in poses.values()))
    out["steady"] = steady
    if first:
        r.cpu_threads = threads[-1]
        w = _track(ts, r, model, bone, range(frames), o, skip_first=False)
        w.pop("_poses")
        later = [x for x in w["per_frame"] if x["frame"] > 0]
        w["threads"] = threads[-1]
        w["first_frame"] = {k: w["per_frame"][0][k] for k in ("wall_s", "cpu_s", "load_1min", "evaluations")}
        w["after_first"] = {"wall_s_per_frame": float(np.mean([x["wall_s"] for x in later])),
                            "cpu_s_per_frame": float(np.mean([x["cpu_s"] for x in later]))}
        w.update(summary([w]))
        out["whole"] = w
    out["load_end"] = _load()
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.cpu_frames",
                                description=__doc__.split("\n")[0])
    p.add_argument("--frames", type=int, default=8)
    p.add_argument("--pixels", type=int, default=512)
    p.add_argument("--voxel", type=float, default=0.5)
    p.add_argument("--threads", default="1,2", help="DRR thread counts to compare (default 1,2)")
    p.add_argument("--rounds", type=int, default=2, help="alternating rounds of the thread counts")
    p.add_argument("--bound-frames", type=int, default=2, help="frames of the Cramér-Rao bound (0: none)")
    p.add_argument("--no-first", action="store_true", help="skip the whole-trial run with its first frame")
    p.add_argument("--out", default=None, help="also write the JSON here")
    a = p.parse_args(argv)
    res = run(frames=a.frames, pixels=a.pixels, voxel=a.voxel, threads=[int(x) for x in a.threads.split(",")],
              rounds=a.rounds, first=not a.no_first, bound_frames=a.bound_frames)
    from core.io.atomic import print_json

    print_json(res, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
