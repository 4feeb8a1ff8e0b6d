"""The Gauss–Newton search's host time per frame, replayed: ``python -m core.studies.tracking.search_host
[--device cpu|cuda:0] [--frames 8] [--pixels 128] [--voxel 1.5] [--repeats 200] [--workers 0]
[--prep-graph off|on|both|off,on,...] [--cprofile FILE] [--out FILE]``.

The bench's trial (:mod:`core.studies.tracking.frame_profile`: the synthetic walking trial of
``talus bench track``, the talus alone, joint mode, the likelihood stage; frames synthesised before it
runs) is tracked once — on this machine's CPU at a small size on the fine-pixel path of 1024² views
(:data:`core.tracking.register_options.COARSE_NEWTON_MM` set to 100 mm: the moments' gradient,
:data:`~core.tracking.register_options.FINAL_STEP`; at 1024² on a GPU that is the path taken anyway) —
each :func:`core.tracking.engine_search.gauss_newton_search` of the run recorded with the scores and
moments its steps fetched from the device. Each search is then replayed ``repeats`` times on its own
engine with the device work taken out: the engine's pipeline for 13 poses replaced by one that hands back
the recorded results in turn (the branch of :meth:`core.tracking.engine.GaussNewtonCost.submit` a CUDA
device takes: the parameter rows written to the pipeline's host buffer, no launch) — so what is timed is
the search's host work alone: the Levenberg–Marquardt state (``ask``, ``tell``, ``result``), the 13-pose
design, the engine's ``submit``, ``collect`` and ``newton`` (the moments' Gauss–Newton algebra), the
:class:`~core.tracking.engine_search.GaussNewtonStep` and the fit of the result (on a CUDA device each
step's wait for the device too, on an idle device). Every replay must give the recorded result to the bit
(``exact``).

``host_us_per_frame``: per search the minimum and the median over the replays (``perf_counter``),
summed over the frames after the first, divided by their number; ``steps_per_frame`` the 13-pose steps.
``set_frame``: per recorded run, the engine's :meth:`~core.tracking.engine.GaussNewtonCost.set_frame`
calls timed as they ran (``set_frame_us_per_frame``, per frame after the first; on a CUDA device its host
time: it enqueues the frame's preparation without a wait; on the CPU its kernels run inside it) and the
fingerprint (sha1) of the run's tracked poses and scores. ``--prep-graph``: the trial recorded once per
entry, :data:`core.tracking.engine_buffers.PREP_GRAPH` set to it (``both``: off, then on; alternate them,
``off,on,off,on``, for the position in the process), each run after a two-frame warm-up of its own; the
searches replayed are the first run's; ``same_poses_in_every_run``: every run's fingerprint equal.
``results_sha1``: the recorded searches' results (x, cost, evaluations), a fingerprint to compare between
trees. ``--cprofile FILE``: the replays once more under :mod:`cProfile` (its text in FILE). JSON on stdout.
"""

from __future__ import annotations

import argparse
import hashlib
import platform
import time

import numpy as np

__all__ = ["main", "record", "replay"]


class _Replayed:
    """A 13-pose pipeline that hands back recorded ``(scores, moments)`` in turn."""

    def __init__(self, outs: list, like) -> None:
        self.outs = outs
        self.i = 0
        self.x_np = np.zeros((13, 6))
        self.gn = like

    def launch(self) -> None:
        pass

    def fetch(self):
        out, gn = self.outs[self.i]
        self.i += 1
        return out.copy(), gn.copy()


def record(frames: int, pixels: int, voxel: float, device: str = "cpu", workers: int = 0,
           prep_graphs=(False,)) -> list:
    """Track the trial (module docs) once per value of ``prep_graphs``
    (:data:`core.tracking.engine_buffers.PREP_GRAPH` set to it; after a two-frame warm-up of each) and
    return per run ``(searches, prepared, poses)``: its searches ``(frame, engine, x0, keywords, fetched,
    result)`` in order, the ``(frame, seconds)`` of the engines' ``set_frame`` calls and the fingerprint
    (sha1) of the tracked poses and scores."""
    from dataclasses import replace

    import core.tracking.engine as engine
    import core.tracking.engine_buffers as buffers
    import core.tracking.engine_pipeline as pipeline
    import core.tracking.register_options as ro
    import core.tracking.trial as trial
    from core.render import DRRRenderer
    from core.studies.tracking.acceptance import TrackingScene
    from core.studies.tracking.trial_frames import synthesise
    from core.tracking.trial import TrackingOptions, track

    n = max(int(frames), 2)
    ts = TrackingScene(n_frames=n, pixels=pixels, spacing=voxel, phase=(0.0, 0.6 * n / 100.0), device=device)
    synthesise(ts, range(n), int(workers))
    models = [ts.models[1]]
    r = DRRRenderer(ts.scene.rig, [m.volume.to_attenuation(ts.scene.bone_transfer) for m in models],
                    device=ts.device)
    kf = {models[0].name: {0: ts.truth(0)[1]}}
    o = replace(TrackingOptions(mode="joint"), refine_likelihood=True)
    searches: list = []
    prepared: list = []
    state = {"fetched": None, "frame": None}
    real_search, real_fetch = engine.gauss_newton_search, pipeline._Pipeline.fetch
    real_step, real_set = trial.track_frame, engine.GaussNewtonCost.set_frame

    def search(cost, x0, **kw):
        state["fetched"] = fetched = []
        try:
            res = real_search(cost, x0, **kw)
        finally:
            state["fetched"] = None
        searches.append((state["frame"], cost, np.array(x0, dtype=float), dict(kw), fetched, res))
        return res

    def fetch(self):
        got = real_fetch(self)
        if state["fetched"] is not None and got[1] is not None:
            state["fetched"].append((got[0].copy(), got[1].copy()))
        return got

    def frame_step(run, f, *a, **k):
        state["frame"] = f
        return real_step(run, f, *a, **k)

    def set_frame(self, *a, **k):
        t = time.perf_counter()
        try:
            return real_set(self, *a, **k)
        finally:
            prepared.append((state["frame"], time.perf_counter() - t))

    kept = [(ro, "COARSE_NEWTON_MM", 100.0), (engine, "gauss_newton_search", search),
            (pipeline._Pipeline, "fetch", fetch), (trial, "track_frame", frame_step),
            (engine.GaussNewtonCost, "set_frame", set_frame), (buffers, "PREP_GRAPH", buffers.PREP_GRAPH)]
    old = [(m, a, getattr(m, a)) for m, a, _ in kept]
    runs = []
    try:
        for m, a, v in kept:
            setattr(m, a, v)
        for graph in prep_graphs:
            buffers.PREP_GRAPH = bool(graph)
            searches, prepared = [], []  # (the lists the wrappers fill: each run's own)
            track(r, models, ts.frames, [0, 1], keyframes=kf, options=o)  # warm-up: kernels, buffers, graphs
            searches, prepared = [], []
            res = track(r, models, ts.frames, list(range(n)), keyframes=kf, options=o)
            sha = hashlib.sha1()
            for key in sorted(res.results):
                x = res.results[key]
                pose = np.full((4, 4), np.nan) if x.pose is None else np.asarray(x.pose, dtype=float)
                sha.update(pose.tobytes() + np.float64(x.score).tobytes())
            runs.append((searches, prepared, sha.hexdigest()))
    finally:
        for m, a, v in reversed(old):
            setattr(m, a, v)
    return runs


def replay(cost, x0, kw: dict, fetched: list):
    """One replay of a recorded search (module docs): ``(result, seconds)``."""
    from core.tracking.engine_search import gauss_newton_search

    kw = {k: v for k, v in kw.items() if k != "idle"}  # (the caller's work during the first step)
    pipe = _Replayed(fetched, None)
    saved = cost._pipes, cost._dev_render, cost._count_pending, cost._pending
    cost._pipes = {13: pipe}
    cost._dev_render = True  # (the CUDA branch of submit: the rows written to the pipeline's buffer)
    cost._count_pending = False
    try:
        t = time.perf_counter()
        res = gauss_newton_search(cost, x0, **kw)
        dt = time.perf_counter() - t
    finally:
        cost._pipes, cost._dev_render, cost._count_pending, cost._pending = saved
    if pipe.i != len(fetched):
        raise AssertionError(f"replay: {pipe.i} steps taken, {len(fetched)} recorded")
    return res, dt


def _same(a, b) -> bool:
    return (a.x.tobytes() == b.x.tobytes() and float(a.fun) == float(b.fun) and a.evaluations == b.evaluations
            and a.reason == b.reason and a.model.H.tobytes() == b.model.H.tobytes()
            and a.model.noise == b.model.noise)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.search_host",
                                description=__doc__.split("\n")[0])
    p.add_argument("--device", default="cpu")
    p.add_argument("--frames", type=int, default=8)
    p.add_argument("--pixels", type=int, default=128)
    p.add_argument("--voxel", type=float, default=1.5)
    p.add_argument("--repeats", type=int, default=200)
    p.add_argument("--workers", type=int, default=0)
    p.add_argument("--prep-graph", default="off")
    p.add_argument("--cprofile", default=None)
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    names = [v.strip() for v in a.prep_graph.replace("both", "off,on").split(",") if v.strip()]
    if not names or set(names) - {"off", "on"}:
        p.error(f"--prep-graph: off, on, both or a list of them (off,on,off,on), got {a.prep_graph!r}")
    graphs = tuple(v == "on" for v in names)
    t0 = time.perf_counter()
    runs = record(a.frames, a.pixels, a.voxel, a.device, a.workers, graphs)
    t_rec = time.perf_counter() - t0
    searches = runs[0][0]
    sha = hashlib.sha1()
    exact = True
    per = []
    for frame, cost, x0, kw, fetched, res in searches:
        sha.update(res.x.tobytes() + np.float64(res.fun).tobytes() + bytes(str(res.evaluations), "ascii"))
        times = []
        for _ in range(int(a.repeats)):
            got, dt = replay(cost, x0, kw, fetched)
            times.append(dt)
        exact &= _same(got, res)
        per.append((frame, len(fetched), min(times), float(np.median(times))))
    later = [q for q in per if q[0] is not None and q[0] != 0]
    frames_after = len({q[0] for q in later}) or 1
    steps = max(sum(q[1] for q in later), 1)
    import warp as wp

    dev = wp.get_device(a.device)
    prep = []
    for graph, (_, prepared, poses) in zip(graphs, runs, strict=True):
        dts = [dt for f, dt in prepared if f is not None and f != 0]
        prep.append({"prep_graph": bool(graph), "set_frame_us_per_frame": 1e6 * sum(dts) / frames_after,
                     "calls_per_frame": len(dts) / frames_after,
                     "us_median_call": 1e6 * float(np.median(dts)) if dts else None, "poses_sha1": poses})
    out = {
        "study": "core.studies.tracking.search_host",
        "machine": f"{platform.machine()} {platform.processor() or ''}".strip(),
        "device": str(dev), "device_name": getattr(dev, "name", str(dev)),
        "frames": a.frames, "pixels": a.pixels, "voxel_mm": a.voxel, "repeats": a.repeats,
        "record_s": t_rec,
        "searches": len(searches), "searches_after_first": len(later),
        "steps_per_frame": sum(q[1] for q in later) / frames_after,
        "exact": bool(exact),
        "host_us_per_frame": {"min": 1e6 * sum(q[2] for q in later) / frames_after,
                              "median": 1e6 * sum(q[3] for q in later) / frames_after},
        "host_us_per_step": {"min": 1e6 * sum(q[2] for q in later) / steps,
                             "median": 1e6 * sum(q[3] for q in later) / steps},
        "set_frame": prep,
        "same_poses_in_every_run": len({v["poses_sha1"] for v in prep}) == 1,
        "per_search": [{"frame": f, "steps": s, "min_us": 1e6 * m, "median_us": 1e6 * md}
                       for f, s, m, md in per],
        "results_sha1": sha.hexdigest(),
    }
    if a.cprofile:
        import cProfile
        import io
        import pstats

        pr = cProfile.Profile()
        pr.enable()
        for _ in range(20):
            for _frame, cost, x0, kw, fetched, _res in searches:
                replay(cost, x0, kw, fetched)
        pr.disable()
        s = io.StringIO()
        pstats.Stats(pr, stream=s).sort_stats("tottime").print_stats(50)
        with open(a.cprofile, "w") as fh:
            fh.write(s.getvalue())
    from core.io.atomic import print_json

    print_json(out, a.out)
    return 0 if exact else 1


if __name__ == "__main__":
    raise SystemExit(main())
