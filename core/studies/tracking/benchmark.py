"""Tracking speed benchmark: ``python -m core.studies.tracking.benchmark [--device cuda:0] [--quick]``.

Cases (synthetic walking trial of :mod:`core.studies.tracking.acceptance`, frames synthesised before the
clock starts; frame 0 starts from the true pose so the numbers are steady-state tracking):

* ``one_bone`` — the talus over ``frames`` frames, two views of ``pixels``²;
* ``three_bones`` — tibia, talus and calcaneus over the same frames.

Each case runs plainly ``repeats`` times (``end_to_end``: frames per second and ms per frame of
the median run, for everything :func:`core.tracking.trial.track` does — frame preparation,
registrations, retries, the per-frame confidence; every run's wall time is kept, as the host's
timing varies by 10–20 % between runs) and once with ``profile=True`` (a device synchronisation
after each DRR launch) for the breakdown: ``drr`` (host tables + launch + rendering),
``metric_and_sync`` (metric launches, the wait for the device and the copy of the scores to the
host), ``cost_host`` (parameters → poses, weighted sums), ``optimizer`` (CMA-ES/pattern-search
arithmetic), ``other`` (frame preparation, confidence stencil, set-up). Accuracy (RMS error vs the
truth) is reported alongside, per frame and after the Butterworth low-pass of the kinematics
(``filtered_*``, at the acceptance study's frame rate).

Full size: 1024² views, 0.5 mm voxels, 100 frames (a GPU); ``--quick``: 192² views, 1 mm voxels,
8 frames (this machine's CPU). JSON on stdout.
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np

__all__ = ["main", "run"]


def _case(ts, bones: list[int], options, frames: int, repeats: int = 3) -> dict:
    from core.render import DRRRenderer
    from core.studies.tracking.acceptance import FRAME_RATE_HZ, pose_errors
    from core.tracking.trial import track

    models = [ts.models[b] for b in bones]
    r = DRRRenderer(ts.scene.rig, [m.volume.to_attenuation(ts.scene.bone_transfer) for m in models],
                    device=ts.device)
    kf = {m.name: {0: ts.truth(0)[b]} for m, b in zip(models, bones, strict=True)}
    track(r, models, ts.frames, [0, 1], keyframes=kf, options=options)  # warm-up: kernels, buffers
    out = {}
    for label, prof in (("end_to_end", False), ("profiled", True)):
        from dataclasses import replace

        o = replace(options, profile=prof)
        walls = []
        for _ in range(1 if prof else repeats):  # the median of repeats: host timing is noisy
            t0 = time.perf_counter()
            res = track(r, models, ts.frames, range(frames), keyframes=kf, options=o)
            walls.append(time.perf_counter() - t0)
        wall = float(np.median(walls))
        rs = list(res.results.values())
        tim = {k: float(sum((x.timing or {}).get(k, 0.0) for x in rs))
               for k in ("render_s", "metric_s", "host_s", "optimizer_s", "other_s")}
        errs = np.array([pose_errors(x.pose, ts.truth(x.frame)[bones[[m.name for m in models].index(x.bone)]],
                                     models[[m.name for m in models].index(x.bone)].centroid)
                         for x in rs if x.pose is not None])
        entry = {"wall_s": wall, "runs_wall_s": walls, "frames_per_second": frames / wall,
                 "frames_per_second_range": [frames / max(walls), frames / min(walls)],
                 "ms_per_frame": 1e3 * wall / frames,
                 "evaluations_per_frame": float(np.mean([x.evaluations for x in rs])) * len(bones),
                 "generations": int(sum(x.timing.get("calls", 0) for x in rs if x.timing)),
                 "converged_fraction": res.summary()["converged_fraction"],
                 "rms_error_mm": float(np.sqrt(np.mean(np.sum(errs[:, :3] ** 2, axis=1)))),
                 "rms_error_deg": float(np.sqrt(np.mean(np.sum(errs[:, 3:] ** 2, axis=1))))}
        if not prof and frames >= 12:  # the trajectories low-passed (the kinematics' default filter)
            ef = []
            for m, b in zip(models, bones, strict=True):
                F, _ = res.filtered_poses(m.name, FRAME_RATE_HZ, center=m.centroid)
                ef += [pose_errors(F[f], ts.truth(f)[b], m.centroid) for f in range(frames)
                       if np.all(np.isfinite(F[f]))]
            ef = np.array(ef).reshape(-1, 6)
            if not len(ef):
                ef = np.full((1, 6), np.nan)
            entry["filtered_rms_error_mm"] = float(np.sqrt(np.mean(np.sum(ef[:, :3] ** 2, axis=1))))
            entry["filtered_rms_error_deg"] = float(np.sqrt(np.mean(np.sum(ef[:, 3:] ** 2, axis=1))))
        if prof:
            tot = sum(tim.values()) or 1.0
            entry["breakdown_ms_per_frame"] = {
                "drr": 1e3 * tim["render_s"] / frames, "metric_and_sync": 1e3 * tim["metric_s"] / frames,
                "cost_host": 1e3 * tim["host_s"] / frames, "optimizer": 1e3 * tim["optimizer_s"] / frames,
                "other": 1e3 * tim["other_s"] / frames}
            entry["breakdown_fraction"] = {k: v / tot for k, v in tim.items()}
        out[label] = entry
    return out


def run(*, quick: bool = False, device: str | None = None, frames: int | None = None,
        pixels: int | None = None, cases: str = "both", repeats: int = 3) -> dict:
    """Run the cases (``"one"``, ``"three"`` or ``"both"``); returns the JSON-ready results."""
    if int(repeats) != repeats or repeats < 1:
        raise ValueError(f"repeats: expected a whole number >= 1, got {repeats!r}")
    if cases not in ("one", "three", "both"):
        raise ValueError(f"cases: expected 'one', 'three' or 'both', got {cases!r}")
    import warp as wp

    from core.studies.tracking.acceptance import TrackingScene
    from core.tracking.trial import TrackingOptions

    n = frames or (8 if quick else 100)
    px = pixels or (192 if quick else 1024)
    ts = TrackingScene(n_frames=max(n, 2), pixels=px, spacing=1.0 if quick else 0.5,
                       phase=(0.0, 0.6 * max(n, 2) / 100.0), device=device)
    t0 = time.perf_counter()
    for i in range(ts.scene.n_frames):
        ts.frames(i)
    synth = time.perf_counter() - t0
    o = TrackingOptions(mode="joint")  # synthetic frames: DRR intensities match the images
    dev = wp.get_device(str(ts.renderer.device))
    res = {"benchmark": "core.tracking", "machine": platform.machine(),
           "processor": platform.processor() or platform.machine(), "device": str(dev),
           "device_name": getattr(dev, "name", str(dev)), "quick": quick,
           "sizes": {"pixels": px, "voxel_mm": 1.0 if quick else 0.5, "frames": n,
                     "volumes_kji": {m.name: list(m.volume.data.shape) for m in ts.models}},
           "synthesis_s": synth, "repeats": int(repeats), "options": o.registration.to_dict()}
    res["mode"] = o.mode
    if cases in ("one", "both"):
        res["one_bone"] = _case(ts, [1], o, n, int(repeats))
    if cases in ("three", "both"):
        res["three_bones"] = _case(ts, [0, 1, 2], o, n, int(repeats))
    res["autoscoper_reference_s_per_frame_per_bone"] = [3.0, 13.0]
    return res


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.benchmark",
                                description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="192² views, 1 mm voxels, 8 frames")
    p.add_argument("--device", default=None, help="Warp device (cpu, cuda:0); default CUDA when present")
    p.add_argument("--frames", type=int, default=None)
    p.add_argument("--pixels", type=int, default=None)
    p.add_argument("--cases", choices=("one", "three", "both"), default="both",
                   help="one bone (talus), three bones (joint), or both")
    p.add_argument("--repeats", type=int, default=3,
                   help="end-to-end runs per case; the median is reported (default 3)")
    p.add_argument("--out", default=None, help="also write the JSON here")
    a = p.parse_args(argv)
    res = run(quick=a.quick, device=a.device, frames=a.frames, pixels=a.pixels, cases=a.cases,
              repeats=a.repeats)
    from core.io.atomic import print_json

    print_json(res, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
