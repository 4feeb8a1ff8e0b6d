"""The Gauss–Newton search's host time per frame, replayed: ``python -m core.studies.tracking.search_host
[--frames 8] [--pixels 128] [--voxel 1.5] [--repeats 200] [--cprofile FILE] [--out FILE]``.

The bench's trial (:mod:`core.studies.tracking.frame_profile`: the synthetic walking trial of
``talus bench track``, the talus alone, joint mode, the likelihood stage) tracked on Warp's CPU device at a
small size, on the fine-pixel path of 1024² views (:data:`core.tracking.register_options.COARSE_NEWTON_MM`
set to 100 mm: the moments' gradient, :data:`~core.tracking.register_options.FINAL_STEP`), each
:func:`core.tracking.engine_search.gauss_newton_search` of the run recorded with the scores and moments its
steps fetched from the device. Each search is then replayed ``repeats`` times on its own engine with the
device work taken out: the engine's pipeline for 13 poses replaced by one that hands back the recorded
results in turn (the branch of :meth:`core.tracking.engine.GaussNewtonCost.submit` a CUDA device takes:
the parameter rows written to the pipeline's host buffer, no launch, no wait) — so what is timed is the
search's host work alone: the Levenberg–Marquardt state (``ask``, ``tell``, ``result``), the 13-pose
design, the engine's ``submit``, ``collect`` and ``newton`` (the moments' Gauss–Newton algebra), the
:class:`~core.tracking.engine_search.GaussNewtonStep` and the fit of the result. Every replay must give
the recorded result to the bit (``exact``).

``host_us_per_frame``: per search the minimum and the median over the replays (``perf_counter``),
summed over the frames after the first, divided by their number; ``steps_per_frame`` the 13-pose steps.
``results_sha1``: the recorded searches' results (x, cost, evaluations), a fingerprint to compare
between trees. ``--cprofile FILE``: the replays once more under :mod:`cProfile` (its text in FILE).
JSON on stdout. Run on the GPU's host the same way (``--device`` is not an option: the search's host
work is the same code on any device; the recorded device work comes from the CPU's run).
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


def record(frames: int, pixels: int, voxel: float) -> list:
    """Track the trial (module docs) and return its searches: ``(phase, engine, x0, keywords,
    fetched, result)`` in order."""
    from dataclasses import replace

    import core.tracking.engine as engine
    import core.tracking.engine_pipeline as pipeline
    import core.tracking.register_options as ro
    from core.render import DRRRenderer
    from core.studies.tracking.acceptance import TrackingScene
    from core.tracking.trial import TrackingOptions, track

    n = max(int(frames), 2)
    ts = TrackingScene(n_frames=n, pixels=pixels, spacing=voxel, phase=(0.0, 0.6 * n / 100.0), device="cpu")
    models = [ts.models[1]]
    r = DRRRenderer(ts.scene.rig, [m.volume.to_attenuation(ts.scene.bone_transfer) for m in models],
                    device="cpu")
    kf = {models[0].name: {0: ts.truth(0)[1]}}
    o = replace(TrackingOptions(mode="joint"), refine_likelihood=True)
    searches: list = []
    state = {"fetched": None, "frame": None}
    real_search, real_fetch, real_step = engine.gauss_newton_search, pipeline._Pipeline.fetch, None

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

    import core.tracking.trial as trial

    real_step = trial.track_frame

    def frame_step(run, f, *a, **k):
        state["frame"] = f
        return real_step(run, f, *a, **k)

    kept = [(ro, "COARSE_NEWTON_MM", 100.0), (engine, "gauss_newton_search", search),
            (pipeline._Pipeline, "fetch", fetch), (trial, "track_frame", frame_step)]
    old = [(m, a, getattr(m, a)) for m, a, _ in kept]
    try:
        for m, a, v in kept:
            setattr(m, a, v)
        track(r, models, ts.frames, list(range(n)), keyframes=kf, options=o)
    finally:
        for m, a, v in reversed(old):
            setattr(m, a, v)
    return searches


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
    p.add_argument("--frames", type=int, default=8)
    p.add_argument("--pixels", type=int, default=128)
    p.add_argument("--voxel", type=float, default=1.5)
    p.add_argument("--repeats", type=int, default=200)
    p.add_argument("--cprofile", default=None)
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    t0 = time.perf_counter()
    searches = record(a.frames, a.pixels, a.voxel)
    t_rec = time.perf_counter() - t0
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
    out = {
        "study": "core.studies.tracking.search_host",
        "machine": f"{platform.machine()} {platform.processor() or ''}".strip(),
        "frames": a.frames, "pixels": a.pixels, "voxel_mm": a.voxel, "repeats": a.repeats,
        "record_s": t_rec,
        "searches": len(searches), "searches_after_first": len(later),
        "steps_per_frame": sum(q[1] for q in later) / frames_after,
        "exact": bool(exact),
        "host_us_per_frame": {"min": 1e6 * sum(q[2] for q in later) / frames_after,
                              "median": 1e6 * sum(q[3] for q in later) / frames_after},
        "host_us_per_step": {"min": 1e6 * sum(q[2] for q in later) / max(sum(q[1] for q in later), 1),
                             "median": 1e6 * sum(q[3] for q in later) / max(sum(q[1] for q in later), 1)},
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
