"""Two trackings at once on one device, in two threads of one process, against the same two one after the
other: ``python -m core.studies.tracking.concurrent_runs [--device cuda:0] [--frames 30] [--pixels 1024]
[--voxel 0.5] [--bones one|three] [--workers 0] [--raw] [--out FILE]``.

The engines record parts of their device work once and replay them as CUDA graphs
(:data:`core.tracking.engine_buffers.PREP_GRAPH`, :data:`core.tracking.likelihood_segments.SEGMENT_GRAPHS`,
:data:`core.tracking.engine_likelihood.STEP_GRAPH`), each captured with :class:`warp.ScopedCapture` on the
device's current stream — one stream per device in Warp, shared by every thread. A stream being captured
takes whatever is enqueued on it, from any thread, into the graph instead of running it, and a
synchronisation of it from another thread is refused. Whether a registering thread's capture takes in
another's work is what this study looks at: the bench's trial (:mod:`core.studies.tracking.frame_profile`'s:
the synthetic walk, joint mode, the likelihood stage) tracked by two threads with renderers (and so
engines, graphs and buffers) of their own — first one after the other (``sequential``; their difference is
the device's run-to-run floor: float atomics), then both at once from a barrier (``concurrent``), each
round on fresh renderers so that the engines capture their graphs during it (a warm-up on a throwaway
renderer compiles the kernels first).

Two things unrelated to the graphs also make concurrent runs differ, and are taken out by default
(``--raw``: not): the first frame's CMA-ES search samples numpy's global random state (the ``cma`` package
seeds and draws ``np.random``), so two searches at once interleave their draws — each call of
:func:`core.tracking.optimize.cmaes` is made under one lock here; and on Warp's CPU device the tile kernels
keep their shared memory's pointer in a process-wide static (x86-64), so two CPU kernels of one module at
once corrupt each other (wrong values, or a crash) — on the CPU each Warp launch is made under one lock
too. With both taken out, this 2-core x86_64 machine's CPU runs (``--device cpu --frames 4 --pixels 64
--voxel 3``) agree with the sequential ones to the bit; without them they differed by 1-3 mm and up to 10°
or crashed.

Reported (JSON on stdout, and ``--out``): per run its wall time, the error it raised (``null``: none) and its
poses' largest difference from the sequential run of the same thread (mm, degrees), the number of frames
whose pose differs and of those whose flags or notes differ; the sequential runs' own difference; the
runtime warnings (a capture refused) and the switches' ``FAILED`` after each round. On the CPU nothing is
captured by default (the graphs are CUDA's): with the two causes above serialized the runs agree there,
which is what the study's test checks.

Since 6a412dc the CMA-ES search draws from a generator of its own (numpy's global state untouched), and since
df08b5b :func:`core.tracking.trial.track` holds a lock per device for its run
(:func:`core.tracking.trial.device_lock`): the two "concurrent" runs now take turns on the device, so this
study checks that turn-taking gives the sequential runs' poses and that no capture is refused, not two
captures at once."""

from __future__ import annotations

import argparse
import json
import platform
import threading
import time
import warnings
from contextlib import contextmanager, nullcontext

import numpy as np

__all__ = ["compare", "main", "run"]


def compare(a, b) -> dict:
    """The largest differences of two tracking results' poses over their common bone-frames (mm of the
    translation, degrees of the rotation), the bone-frames whose pose differs (a pose on one side only
    counts) and those whose flags or notes differ (the post-pass's and the checks')."""
    from core.geometry.transforms import matrix_to_rotvec

    mm = deg = 0.0
    differ = flags = 0
    for k in a.results.keys() & b.results.keys():
        ra, rb = a.results[k], b.results[k]
        flags += int(tuple(ra.flags) != tuple(rb.flags) or tuple(ra.notes) != tuple(rb.notes))
        p, q = ra.pose, rb.pose
        if p is None or q is None:
            differ += int((p is None) != (q is None))
            continue
        p, q = np.asarray(p, float), np.asarray(q, float)
        if np.array_equal(p, q):
            continue
        differ += 1
        mm = max(mm, float(np.linalg.norm(p[:3, 3] - q[:3, 3])))
        deg = max(deg, float(np.degrees(np.linalg.norm(matrix_to_rotvec(p[:3, :3] @ q[:3, :3].T)))))
    return {"max_mm": mm, "max_deg": deg, "frames_differ": differ, "flags_differ": flags}


def _failed() -> dict:
    import core.tracking.likelihood_graph as lg
    import core.tracking.likelihood_segments as seg

    return {"likelihood_segments.FAILED": seg.FAILED, "likelihood_graph.FAILED": lg.FAILED}


@contextmanager
def _serialized(cpu: bool):
    """Each :func:`core.tracking.optimize.cmaes` call under one lock, and on the CPU each Warp launch under
    another (module docs); put back after."""
    import warp as wp
    from warp._src import context as ctx

    import core.tracking.optimize as opt

    rng, launches = threading.Lock(), threading.RLock()

    def locked(f, lock):
        def g(*a, **k):
            with lock:
                return f(*a, **k)
        return g

    kept = [(opt, "cmaes", locked(opt.cmaes, rng))]
    if cpu:
        kept += [(ctx.Launch, "launch", locked(ctx.Launch.launch, launches)),
                 (ctx, "launch", locked(ctx.launch, launches)), (wp, "launch", locked(wp.launch, launches)),
                 (wp, "launch_tiled", locked(wp.launch_tiled, launches))]
    old = [(m, a, getattr(m, a)) for m, a, _ in kept]
    try:
        for m, a, v in kept:
            setattr(m, a, v)
        yield
    finally:
        for m, a, v in reversed(old):
            setattr(m, a, v)


def run(device: str, frames: int, pixels: int, voxel: float, bones: str = "one", workers: int = 0,
        raw: bool = False) -> dict:
    """The study (module docs): its record (``raw``: the CMA-ES searches and the CPU's launches not
    serialized)."""
    from dataclasses import replace

    import warp as wp

    from core.render import DRRRenderer
    from core.studies.tracking.acceptance import TrackingScene
    from core.studies.tracking.trial_frames import synthesise
    from core.tracking.trial import TrackingOptions, track

    n = max(int(frames), 2)
    ts = TrackingScene(n_frames=n, pixels=pixels, spacing=voxel, phase=(0.0, 0.6 * n / 100.0), device=device)
    synthesise(ts, range(n), int(workers))
    which = [0, 1, 2] if bones == "three" else [1]
    models = [ts.models[b] for b in which]
    kf = {m.name: {0: ts.truth(0)[b]} for m, b in zip(models, which, strict=True)}
    o = replace(TrackingOptions(mode="joint"), refine_likelihood=True)

    def renderer():
        return DRRRenderer(ts.scene.rig, [m.volume.to_attenuation(ts.scene.bone_transfer) for m in models],
                           device=ts.device)

    track(renderer(), models, ts.frames, [0, 1], keyframes=kf, options=o)  # warm-up: the kernels compiled

    def one(r, out: dict, key: str, barrier=None) -> None:
        if barrier is not None:
            barrier.wait()
        t = time.perf_counter()
        try:
            out[key] = (track(r, models, ts.frames, list(range(n)), keyframes=kf, options=o), None)
        except Exception as e:  # (reported: a run refused its synchronisation, say)
            out[key] = (None, repr(e))
        out[key + "_s"] = time.perf_counter() - t

    dev = wp.get_device(device)
    rec = {"study": "core.studies.tracking.concurrent_runs", "machine": platform.machine(),
           "device": str(dev), "device_name": getattr(dev, "name", device),
           "frames": n, "pixels": pixels, "voxel_mm": voxel, "bones": [m.name for m in models],
           "serialized": [] if raw else ["cmaes"] + (["cpu_launches"] if dev.is_cpu else [])}
    got: dict = {}
    with warnings.catch_warnings(record=True) as caught, \
            nullcontext() if raw else _serialized(dev.is_cpu):
        warnings.simplefilter("always", RuntimeWarning)
        for key in ("seq_a", "seq_b"):  # one after the other, each in a thread of its own
            th = threading.Thread(target=one, args=(renderer(), got, key))
            th.start()
            th.join()
        rec["after_sequential"] = _failed()
        barrier = threading.Barrier(2)
        ths = [threading.Thread(target=one, args=(renderer(), got, key, barrier))
               for key in ("con_a", "con_b")]
        for th in ths:
            th.start()
        for th in ths:
            th.join()
        rec["after_concurrent"] = _failed()
    rec["warnings"] = sorted({str(w.message)[:300] for w in caught})

    def row(key, ref):
        res, err = got[key]
        x = {"wall_s": got[key + "_s"], "error": err}
        if res is not None and ref is not None:
            x["vs_sequential"] = compare(ref, res)
        return x

    sa, sb = got["seq_a"][0], got["seq_b"][0]
    rec["sequential"] = {"a": row("seq_a", None), "b": row("seq_b", None)}
    rec["sequential_floor"] = compare(sa, sb) if sa is not None and sb is not None else None
    rec["concurrent"] = {"a": row("con_a", sa), "b": row("con_b", sb)}
    return rec


def main(argv=None) -> None:
    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.concurrent_runs",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--device", default=None)
    p.add_argument("--frames", type=int, default=30)
    p.add_argument("--pixels", type=int, default=1024)
    p.add_argument("--voxel", type=float, default=0.5)
    p.add_argument("--bones", choices=("one", "three"), default="one")
    p.add_argument("--workers", type=int, default=0, help="processes for the frames' image chain")
    p.add_argument("--raw", action="store_true",
                   help="the CMA-ES searches and the CPU's launches not serialized")
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    from core.render.drr import default_device

    rec = run(a.device or default_device(), a.frames, a.pixels, a.voxel, a.bones, a.workers, a.raw)
    rec["command"] = "python -m core.studies.tracking.concurrent_runs " + " ".join(argv or [])
    text = json.dumps(rec, indent=1, default=float)
    if a.out:
        with open(a.out, "w") as f:
            f.write(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
