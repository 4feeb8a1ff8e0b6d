"""Throughput of ``talus batch`` against the number of Dask workers, and a model of it.

``python -m core.studies.batch.benchmark [--device cpu|cuda] [--workers 1,2] [--pixels N]
[--frames N] [--trials N] [--serial] [--out FILE.json]``

A demo study (:func:`core.synthetic.make_demo_study`; its first trial copied to ``--trials``
trials on the same frames, each with the same keyframes) is tracked — talus and calcaneus, one
(trial, bone) task each — by a local Dask cluster of each worker count in ``--workers``, every
time from empty journals; ``--serial`` adds the same tasks run one after the other in this
process without Dask (the scheduler-free reference). Printed JSON: per run the tasks, workers,
wall time, cluster start-up, every task's time, loading (opening the study, reading the CTs,
opening the views and journals), first frame (bone models, renderer, Warp kernels and the first
frame's widened search) and the median later frame, the wall time not spent in tasks per task
(scheduling, and workers idle at the end), throughput in frames/s, and the load average
before and after (the machine may be shared). ``model`` predicts
the wall time and throughput for 1-16 workers from the one-worker run: start-up + the greedy
(longest task first) makespan of the measured task times plus the per-task scheduling overhead,
assuming each worker has its own device (one GPU per worker; on a CPU, cores beyond the free ones
only share them).

Imports no Qt: runs where the app is not installed.
"""

from __future__ import annotations

import argparse
import heapq
import os
import shutil
import statistics
import tempfile
import time
from pathlib import Path

from ...io.atomic import print_json
from ...study import Study
from ...tracking.batch import TaskSettings, build_tasks, run_batch, run_serial

BONES = ("talus", "calcaneus")


def make_study(folder: Path, *, pixels: int, frames: int, trials: int, device: str | None,
               bones=BONES) -> Path:
    """The demo study with ``trials`` trials on the same frames (same keyframes)."""
    from ...synthetic import make_demo_study

    make_demo_study(folder, n_frames=frames, pixels=pixels, device=device, calibration_session=False,
                    spacing=max(0.5, 96.0 / pixels), tissue_spacing=max(2.0, 192.0 / pixels))
    with Study.open(folder, mode="w") as st:
        walk = st.manifest["trials"]["walk"]
        views = [st.path(v["path"]) for v in walk["views"]]
        for k in range(2, trials + 1):
            name = f"walk{k}"
            st.add_trial(name, views, calibration=walk["calibration"], bones=list(bones),
                         bit_depth=walk["views"][0]["bit_depth"])
            for b in bones:
                st.trial(name).record_pose(b, 0, st.trial("walk").poses(b)[0])
    return folder


def _fresh(study: Path, dest: Path) -> Path:
    """A copy of the study whose journals hold only the keyframes."""
    if dest.exists():
        shutil.rmtree(dest)
    shutil.copytree(study, dest, ignore=shutil.ignore_patterns("reports"))
    return dest


def _run(study: Path, settings: TaskSettings, workers: int, bones=BONES) -> dict:
    # one (trial, bone) task each, as the module notes say: the demo's frames are divided by the full
    # scale (no flatfield correction), which mode "auto" also tracks one bone per task; pinned so the
    # measured tasks stay the same if the demo gains a correction (split_bones: mode "sequential"
    # alone makes one task of a trial's bones)
    tasks = build_tasks([study], bones=list(bones), mode="sequential", split_bones=True)
    load0 = os.getloadavg()[0]
    if workers == 0:
        s = run_serial(tasks, settings)
    else:
        s = run_batch(tasks, settings, workers=workers)
    recs = s["task_records"]
    frame_s = [r["frame_s"] for r in recs if r.get("frame_s")]
    ends = sorted(r["seconds"] for r in recs)
    return {
        "workers": workers if workers else "serial (no Dask)",
        "tasks": s["tasks"], "status": s["status"], "failures": s["failures"],
        "wall_s": round(s["wall_s"], 2),
        "cluster_startup_s": None if s["startup_s"] is None else round(s["startup_s"], 2),
        "frames_tracked": s["frames_tracked"],
        "frames_per_s": round(s["frames_per_s"], 4),
        "task_s": [round(r["seconds"], 2) for r in recs],
        "task_load_s": [round(r["load_s"], 2) for r in recs],
        "task_first_frame_s": [None if r["first_frame_s"] is None else round(r["first_frame_s"], 2)
                               for r in recs],
        "frame_s_median": round(statistics.median(frame_s), 3) if frame_s else None,
        "task_s_sum": round(sum(ends), 2),
        # wall time not spent in tasks (per task): scheduling, and workers idle at the end
        "scheduling_s_per_task": round(max(0.0, s["wall_s"] - (s["startup_s"] or 0.0)
                                           - sum(ends) / max(workers, 1)) / len(recs), 3),
        "load_average": [round(load0, 2), round(os.getloadavg()[0], 2)],
    }


def _gpu_names() -> list[str]:
    """The GPUs of this machine as nvidia-smi names them (empty when it is missing)."""
    import subprocess

    try:
        out = subprocess.run(["nvidia-smi", "-L"], capture_output=True, text=True, timeout=30).stdout
    except (OSError, subprocess.SubprocessError):
        return []
    return [line.split(" (UUID")[0] for line in out.splitlines() if line.strip()]


def model(one: dict, counts=(1, 2, 4, 8, 16)) -> list[dict]:
    """Predicted wall time and throughput against workers from a one-worker run (see the
    module docs): start-up + greedy makespan of (task time + scheduling per task)."""
    per_task = [t + one["scheduling_s_per_task"] for t in one["task_s"]]
    frames = one["frames_tracked"]
    out = []
    for w in counts:
        heap = [0.0] * w
        for t in sorted(per_task, reverse=True):
            heapq.heappush(heap, heapq.heappop(heap) + t)
        wall = (one["cluster_startup_s"] or 0.0) + max(heap)
        out.append({"workers": w, "wall_s": round(wall, 2), "frames_per_s": round(frames / wall, 4),
                    "speed_up": round(one["wall_s"] / wall, 2)})
    return out


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(prog="python -m core.studies.batch.benchmark",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--device", default="cpu", help="cpu or cuda (one worker per GPU)")
    p.add_argument("--workers", default="1,2", help="comma-separated worker counts")
    p.add_argument("--pixels", type=int, default=None, help="image size (default 64 on cpu, 256 on cuda)")
    p.add_argument("--frames", type=int, default=None, help="frames per trial (default 3 on cpu, 20 on cuda)")
    p.add_argument("--trials", type=int, default=2, help="trials (each with the --bones)")
    p.add_argument("--bones", default=",".join(BONES), help="bones, comma-separated (a task each)")
    p.add_argument("--serial", action="store_true", help="also run the tasks in this process without Dask")
    p.add_argument("--confidence", action="store_true", help="with the per-frame uncertainty")
    p.add_argument("--out", default=None, help="also write the JSON here")
    a = p.parse_args(argv)
    cpu = a.device.startswith("cpu")
    pixels = a.pixels or (64 if cpu else 256)
    frames = a.frames or (3 if cpu else 20)
    counts = [int(w) for w in a.workers.split(",")]
    bones = tuple(b.strip() for b in a.bones.split(",") if b.strip())
    settings = TaskSettings(device=a.device, confidence=a.confidence)
    with tempfile.TemporaryDirectory(prefix="talus-batch-bench-") as tmp:
        t0 = time.perf_counter()
        base = make_study(Path(tmp) / "demo", pixels=pixels, frames=frames, trials=a.trials,
                          device=a.device, bones=bones)
        made = time.perf_counter() - t0
        runs = []
        for w in ([0] if a.serial else []) + counts:
            runs.append(_run(_fresh(base, Path(tmp) / f"run{w}"), settings, w, bones))
    result = {
        "benchmark": "talus batch throughput against workers",
        "device": a.device, "gpus": _gpu_names() if not cpu else [], "cpu_count": os.cpu_count(),
        "study": {"pixels": pixels, "frames_per_trial": frames, "trials": a.trials, "bones": list(bones),
                  "tasks": a.trials * len(bones), "made_s": round(made, 1)},
        "settings": {"confidence": a.confidence, "metric": settings.metric},
        "runs": runs,
    }
    one = next((r for r in runs if r["workers"] == 1), None)
    if one is not None:
        result["model"] = model(one)
    print_json(result, a.out)
    return result


if __name__ == "__main__":
    main()
