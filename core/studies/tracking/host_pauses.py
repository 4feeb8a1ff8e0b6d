"""Host pauses around a tracking run: ``python -m core.studies.tracking.host_pauses [--device cpu]
[--pixels 64] [--frames 8] [--repeats 3] [--out FILE]``.

Two things that stop the registering thread without showing in a registration's median time:

* the cyclic garbage collector's full collections — after a one-bone warm-up on the benchmark's scene
  (:mod:`core.studies.tracking.benchmark`'s, the talus with the likelihood stage), the objects it follows,
  a full collection's time with them and with them frozen (:func:`gc.freeze`), and per tracked run
  (alternated with :data:`core.tracking.trial.GC_FREEZE` off and on) the collections and their pauses
  (:class:`core.tracking.gc_pause.GcWatch`);
* the interpreter's lock — 400 sleeps of 0.2 ms (a stand-in for a short wait on the device, which gives
  the lock up) timed alone and beside a thread preparing 1024² frame pairs without pause
  (:meth:`core.tracking.feed.FrameFeed._prepare`, the feed worker's work), at the default switch
  interval and at 0.5 ms (:data:`core.tracking.trial.SWITCH_INTERVAL`): the overshoot is the wait for the
  lock back.

JSON on stdout (and ``--out``).
"""

from __future__ import annotations

import argparse
import gc
import os
import platform
import sys
import threading
import time

import numpy as np

__all__ = ["gil_overshoot", "main"]


def gil_overshoot(n: int = 400, worker: bool = False, interval: float | None = None) -> dict:
    """Overshoot (ms) of ``n`` sleeps of 0.2 ms, with a thread preparing 1024² frame pairs meanwhile
    (``worker``), at the switch ``interval`` (None: as it is)."""
    from core.tracking.feed import FrameFeed

    rng = np.random.default_rng(0)
    imgs = [rng.uniform(0.1, 0.9, (1024, 1024)).astype(np.float32) for _ in range(2)]
    feed = FrameFeed(lambda f: imgs, (0.02, 0.999), 3)
    stop = threading.Event()
    done = [0]

    def work() -> None:
        while not stop.is_set():
            feed._prepare(imgs, (), ())
            done[0] += 1

    kept = sys.getswitchinterval()
    if interval is not None:
        sys.setswitchinterval(interval)
    th = threading.Thread(target=work) if worker else None
    try:
        if th is not None:
            th.start()
        over = []
        for _ in range(n):
            t = time.perf_counter()
            time.sleep(0.0002)
            over.append(time.perf_counter() - t - 0.0002)
    finally:
        stop.set()
        if th is not None:
            th.join()
        sys.setswitchinterval(kept)
    o = 1e3 * np.array(over)
    return {"worker": worker, "switch_interval_s": interval if interval is not None else kept,
            "median_ms": float(np.median(o)), "p99_ms": float(np.percentile(o, 99)), "max_ms": float(o.max()),
            "sum_ms": float(o.sum()), "frames_prepared": done[0]}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.host_pauses",
                                description=__doc__.split("\n")[0])
    p.add_argument("--device", default="cpu")
    p.add_argument("--pixels", type=int, default=64)
    p.add_argument("--voxel", type=float, default=2.0)
    p.add_argument("--frames", type=int, default=8)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    from dataclasses import replace

    import core.tracking.trial as trial
    from core.render import DRRRenderer
    from core.studies.tracking.acceptance import TrackingScene
    from core.studies.tracking.trial_frames import synthesise
    from core.tracking.gc_pause import GcWatch
    from core.tracking.trial import TrackingOptions, track

    n = max(int(a.frames), 3)
    ts = TrackingScene(n_frames=n, pixels=a.pixels, spacing=a.voxel, phase=(0.0, 0.6 * n / 100.0),
                       device=a.device)
    synthesise(ts, range(n), 0)
    models = [ts.models[1]]
    r = DRRRenderer(ts.scene.rig, [m.volume.to_attenuation(ts.scene.bone_transfer) for m in models],
                    device=ts.device)
    kf = {m.name: {0: ts.truth(0)[1]} for m in models}
    o = replace(TrackingOptions(mode="joint"), refine_likelihood=True)
    track(r, models, ts.frames, [0, 1], keyframes=kf, options=o)  # warm-up
    out = {"study": "core.studies.tracking.host_pauses", "machine": platform.machine(),
           "cpu_count": os.cpu_count(), "python": platform.python_version(), "device": a.device,
           "pixels": a.pixels, "voxel_mm": a.voxel,
           "frames": n, "objects_after_warm_up": len(gc.get_objects())}
    t = time.perf_counter()
    gc.collect()
    out["full_collection_ms"] = 1e3 * (time.perf_counter() - t)
    gc.freeze()
    try:
        t = time.perf_counter()
        gc.collect()
        out["full_collection_frozen_ms"] = 1e3 * (time.perf_counter() - t)
    finally:
        gc.unfreeze()
    runs = []
    kept = trial.GC_FREEZE
    try:
        for _ in range(int(a.repeats)):
            for on in (False, True):
                trial.GC_FREEZE = on
                with GcWatch() as w:
                    t = time.perf_counter()
                    track(r, models, ts.frames, range(n), keyframes=kf, options=o)
                    wall = time.perf_counter() - t
                runs.append({"gc_freeze": on, "wall_s": wall, **w.to_dict()})
    finally:
        trial.GC_FREEZE = kept
    out["runs"] = runs
    out["gil"] = [gil_overshoot(worker=w, interval=i) for i in (None, 0.0005) for w in (False, True)]
    from core.io.atomic import print_json

    print_json(out, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
