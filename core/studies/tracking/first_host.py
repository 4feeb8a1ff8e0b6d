"""The first frame's host work moved off the registering thread: ``python -m core.studies.tracking.first_host
[--device cpu|cuda:0] [--pixels 1024] [--voxel 2] [--rounds 3] [--variants off,on,restarts] [--coarsest MM]
[--out FILE]``.

The bench's one-bone trial (:mod:`core.studies.tracking.frame_profile`: the synthetic walking trial of
``talus bench track``, the talus alone, joint mode, the likelihood stage, frame 0 from the true pose; the
tracker still runs its global search there, ``"global_newton"``: CMA-ES at pyramid scale 4, Gauss–Newton
steps at scale 2, then at full resolution, then the restart check) tracked over its first frame only,
once per variant per round (round ``i`` starts with the ``i``-th variant), after a warm-up run of each:

* ``off``: :data:`core.tracking.engine_upload.FILL_ASIDE` and :data:`core.tracking.engine_frames.
  PYRAMID_AHEAD` off — the frame's pinned copy made by :func:`~core.tracking.engine_upload.share` in the
  registering thread at the registration's start, each pyramid level prepared when it starts;
* ``on``: both on (the defaults) — the copy made in a thread of its own while the CMA-ES stage runs and the
  scale-2 regions low-passed in the view threads meanwhile;
* ``restarts``: also :data:`core.tracking.first_restarts.RESTART_REGIONS_AHEAD` (off by default): the
  restart check's first level's regions prepared during the checked registration's final stage, from the
  searched pose (``ahead_taken``: per pyramid preparation in order — the CMA-ES level, the search's
  scale-2 level, the restarts' first level — whether it found its regions made ahead).

Timed in the registering thread (``perf_counter`` around each call, summed over the first frame): the
calls the switches change — ``share`` (:func:`~core.tracking.engine_upload.share`), ``fill_aside``,
``aside_start``, ``aside_wait`` (:class:`~core.tracking.engine_upload.Aside`), ``pyramid_ahead`` (handing
the views to the view threads) and ``pyramid_rois`` per scale (:func:`core.tracking.engine_frames.
pyramid_rois` as the engine calls it) — their sum ``changed_ms`` is the
host time the first frame spends in them on its critical path; ``first_frame_ms`` the frame's wall time
and ``thread_cpu_ms`` the registering thread's CPU time (on the CPU device both include the kernels,
which run in the calling thread). On a CPU device the shared upload is switched on for the run
(:data:`~core.tracking.engine_upload.DEVICES` given ``"cpu"``, as the tests do; unpinned host memory).
``poses_sha1``: the frame's pose, score, flags and confidence, the same in every run where the switches
keep the results. ``--coarsest MM``: the automatic levels' and the restarts' coarsest pixel
(:func:`~core.tracking.register_options.default_levels`' ``coarsest_mm``, 1.2 mm) set to it, so that a smaller
image keeps the pyramid levels of 1024² views. JSON on stdout (and in FILE).
"""

from __future__ import annotations

import argparse
import functools
import hashlib
import platform
import threading
import time
from contextlib import contextmanager

import numpy as np

__all__ = ["main"]

#: (FILL_ASIDE, PYRAMID_AHEAD, RESTART_REGIONS_AHEAD) per variant
_VARIANTS = {"off": (False, False, False), "on": (True, True, False), "restarts": (True, True, True)}


@contextmanager
def _timed(record: dict):
    """The calls the switches change wrapped (the registering thread's time per name)."""
    import core.tracking.engine as eng
    import core.tracking.engine_frames as ef
    import core.tracking.engine_upload as eu

    me = threading.get_ident()
    kept = []

    def wrap(mod, attr, name_of):
        real = getattr(mod, attr)

        def w(*a, **k):
            if threading.get_ident() != me:
                return real(*a, **k)
            t0 = time.perf_counter()
            try:
                return real(*a, **k)
            finally:
                name = name_of(a, k)
                c, ms = record.get(name, (0, 0.0))
                record[name] = (c + 1, ms + 1e3 * (time.perf_counter() - t0))

        kept.append((mod, attr, real))
        setattr(mod, attr, w)

    try:
        wrap(eu, "share", lambda a, k: "share")
        wrap(eu, "fill_aside", lambda a, k: "fill_aside")
        wrap(eu.Aside, "start", lambda a, k: "aside_start")
        wrap(eu.Aside, "wait", lambda a, k: "aside_wait")
        wrap(ef, "pyramid_ahead", lambda a, k: "pyramid_ahead")
        wrap(eng, "pyramid_rois", lambda a, k: f"pyramid_rois_x{float(a[3]):g}")
        real_rois = eng.pyramid_rois

        def rois(frame, views, roi, scale):  # whether the call finds its regions prepared ahead
            got = ef._AHEAD.get(threading.get_ident())
            hit = got is not None and got[0][0]() is frame and got[0][1:] == (
                tuple(int(v) for v in views), np.asarray(roi, dtype=np.int64).tobytes(), float(scale))
            record.setdefault("ahead_taken", []).append(bool(hit))
            return real_rois(frame, views, roi, scale)

        eng.pyramid_rois = rois
        yield
    finally:
        for mod, attr, real in reversed(kept):
            setattr(mod, attr, real)


def _digest(res) -> str:
    h = hashlib.sha1()
    for key in sorted(res.results):
        fr = res.results[key]
        h.update(np.asarray(fr.pose, dtype=float).tobytes())
        h.update(repr((fr.score, fr.flags, fr.notes, fr.evaluations, fr.confidence)).encode())
    return h.hexdigest()


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.first_host",
                                description=__doc__.split("\n")[0])
    p.add_argument("--device", default="cpu")
    p.add_argument("--pixels", type=int, default=1024)
    p.add_argument("--voxel", type=float, default=2.0)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--variants", default="off,on,restarts")
    p.add_argument("--coarsest", type=float, default=None)
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    from dataclasses import replace

    import warp as wp

    import core.tracking.engine_frames as ef
    import core.tracking.engine_upload as eu
    import core.tracking.first_restarts as fr
    import core.tracking.register as reg
    from core.render import DRRRenderer
    from core.studies.tracking.acceptance import TrackingScene
    from core.studies.tracking.frame_profile import rotated
    from core.studies.tracking.trial_frames import synthesise
    from core.tracking.trial import TrackingOptions, track

    names = [v.strip() for v in a.variants.split(",") if v.strip()]
    for v in names:
        if v not in _VARIANTS:
            raise SystemExit(f"--variants: expected names of {sorted(_VARIANTS)}, got {v!r}")
    ts = TrackingScene(n_frames=2, pixels=a.pixels, spacing=a.voxel, phase=(0.0, 0.012), device=a.device)
    synthesise(ts, range(2), 0)
    model = ts.models[1]
    r = DRRRenderer(ts.scene.rig, [model.volume.to_attenuation(ts.scene.bone_transfer)], device=ts.device)
    kf = {model.name: {0: ts.truth(0)[1]}}
    o = replace(TrackingOptions(mode="joint"), refine_likelihood=True, backward_limit=None,
                trajectory_limit=None)
    dev = wp.get_device(str(ts.renderer.device))
    devices = eu.DEVICES
    if not dev.is_cuda:
        eu.DEVICES = ("cuda", "cpu")
    kept = eu.FILL_ASIDE, ef.PYRAMID_AHEAD, fr.RESTART_REGIONS_AHEAD
    levels = reg.default_levels, reg._newton_fallback
    if a.coarsest is not None:  # the pyramid scales of a larger image at these pixels
        reg.default_levels = functools.partial(levels[0], coarsest_mm=float(a.coarsest))
        reg._newton_fallback = functools.partial(levels[1], coarsest_mm=float(a.coarsest))

    def run(v: str) -> dict:
        eu.FILL_ASIDE, ef.PYRAMID_AHEAD, fr.RESTART_REGIONS_AHEAD = _VARIANTS[v]
        record: dict = {}
        with _timed(record):
            c0 = time.thread_time()
            t0 = time.perf_counter()
            res = track(r, [model], ts.frames, [0], keyframes=kf, options=o)
            wall = time.perf_counter() - t0
            cpu = time.thread_time() - c0
        taken = record.pop("ahead_taken", [])
        calls = {k: {"calls": c, "ms": ms} for k, (c, ms) in sorted(record.items())}
        return {"first_frame_ms": 1e3 * wall, "thread_cpu_ms": 1e3 * cpu, "calls": calls,
                "ahead_taken": taken,
                "changed_ms": sum(x["ms"] for x in calls.values()), "poses_sha1": _digest(res)}

    out = {"study": "core.studies.tracking.first_host", "device": str(dev),
           "device_name": getattr(dev, "name", str(dev)), "machine": platform.machine(),
           "pixels": a.pixels, "voxel_mm": a.voxel, "bone": model.name, "variants": {}, "round_orders": []}
    try:
        for v in names:  # warm-up: kernels, buffers, pools
            run(v)
        runs = {v: [] for v in names}
        for i in range(int(a.rounds)):
            order = rotated(names, i)
            out["round_orders"].append(order)
            for v in order:
                runs[v].append(run(v))
    finally:
        eu.DEVICES = devices
        eu.FILL_ASIDE, ef.PYRAMID_AHEAD, fr.RESTART_REGIONS_AHEAD = kept
        reg.default_levels, reg._newton_fallback = levels
    for v, rs in runs.items():
        out["variants"][v] = {
            "runs": rs,
            "changed_ms_median": float(np.median([x["changed_ms"] for x in rs])),
            "first_frame_ms_median": float(np.median([x["first_frame_ms"] for x in rs])),
            "thread_cpu_ms_median": float(np.median([x["thread_cpu_ms"] for x in rs]))}
    out["same_poses_in_every_run"] = len({x["poses_sha1"] for rs in runs.values() for x in rs}) == 1
    try:
        import os

        out["load_average"] = list(os.getloadavg())
    except OSError:
        pass
    from core.io.atomic import print_json

    print_json(out, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
