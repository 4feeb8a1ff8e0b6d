"""Where a tracking frame's time goes: ``python -m core.studies.tracking.frame_profile [--device cuda:0]
[--frames 100] [--pixels 1024] [--voxel 0.5] [--bones three|one] [--final likelihood|none] [--workers 12]
[--repeats 3] [--variants SPEC] [--cprofile] [--out FILE]``.

The scene and trial of ``talus bench track`` (:mod:`core.studies.tracking.benchmark`: the synthetic walking
trial, frames synthesised before the clock starts, frame 0 from the true pose, joint tracking of tibia,
talus and calcaneus or the talus alone, ``--final likelihood``: the likelihood stage). After a two-frame
warm-up, ``repeats`` plain runs (wall, first frame, ms a frame after it; ``frames``: the run frame by frame,
its slow frames with what ran in them, :class:`core.studies.tracking.loop_clock.FrameClock`), then one run
with the tracker's functions wrapped (:data:`WRAPPED`): the wall time of each call (``perf_counter``),
inclusive and exclusive of the wrapped functions it calls, summed per phase — ``first`` (frame 0), ``later``
(the frames after it; divide by their number for a frame), ``backward`` (the backward check's registration of
the first frame at the run's end, :mod:`core.tracking.backward_check`) and ``loop`` (the tracker's loop
outside the frame step). ``wp.synchronize_*``: the host's waits for the device; ``engine.stage``: the engine's
full-resolution regions prepared on the device (in ``set_frame``; with their host copies where the frame is
not shared), ``engine_upload.share``: joint registration's one upload of the whole frame,
``GaussNewtonCost._render``: the neighbours' DRRs to subtract; ``stage_gen.next0`` / ``stage_gen.next``: a
final stage's set-up and first step / each later step up to its next wait (its generator,
:func:`core.tracking.final_stage.final_stage_steps`); ``unusual_calls``: the wrapped calls of the wrapped
run's three slowest frames that the median frame did not make (or made fewer or more times), with their
time. The wrappers cost about a millisecond a frame of three bones; ``--cprofile`` adds a run under
:mod:`cProfile` (its text next to the JSON). ``--variants 'name:module.ATTR=value,...;name2:...'``
(modules under ``core.tracking``, values Python literals) runs the plain runs once per variant in turn,
``repeats`` rounds (``variants``: each one's runs; the host's drift shared), each with its switches set and
put back after; the wrapped run has the modules' own.
Round ``i`` starts with the ``i``-th variant (``round_orders``): on one NVIDIA H100 at f4f4b08 the variant
run first in every round (then always the same) was the slowest in all four rounds, a position bias as
large as any switch (``resources/benchmarks/tracking_bench_final_f4f4b08_h100.json``). JSON on stdout.
"""

from __future__ import annotations

import argparse
import functools
import time
from contextlib import contextmanager

import numpy as np

from core.studies.tracking.loop_clock import frame_walls  # (re-exported: its old home)

__all__ = ["WRAPPED", "frame_walls", "main", "parse_variants", "profile_run", "rotated", "switched",
           "wrapped"]

#: (module, attribute) of the functions wrapped, by the name their callers look them up by; classes'
#: methods as "Class.method"
WRAPPED = (
    ("core.tracking.trial", ("apply_trajectory_flags",)),
    ("core.tracking.frame_step", ("register_together", "register_checked", "settle", "stage_move_check",
                                  "_frame_result", "motion_prediction", "predict_pose", "_moved_around",
                                  "stage_pass", "_confirmed", "missing_flags")),
    ("core.tracking.joint_pipeline", ("run_pipelined",)),
    ("core.tracking.joint", ("search_region", "engine_cost", "mm_per_pixel", "_submit", "_collect", "_drive",
                             "_result", "register", "restarts_together")),
    ("core.tracking.final_stage", ("final_stages", "run_side_by_side", "confirm_move")),
    ("core.tracking.attempt", ("register", "verify_start", "_failures", "confidence_of", "_conf_flags",
                               "_motion_limits", "remeasured")),
    ("core.tracking.register", ("_run", "search_region", "result_of", "mm_per_pixel")),
    ("core.tracking.engine", ("gauss_newton_search", "GaussNewtonCost.set_frame", "GaussNewtonCost.submit",
                              "GaussNewtonCost.collect", "GaussNewtonCost.newton",
                              "GaussNewtonCost.sibling", "GaussNewtonCost._render", "stage", "pyramid_rois")),
    ("core.tracking.engine_upload", ("share",)),
    ("core.tracking.engine_search", ("LevenbergMarquardt.ask", "LevenbergMarquardt.tell",
                                     "LevenbergMarquardt.result")),
    ("core.tracking.engine_likelihood", ("LikelihoodEngine.set_frame", "LikelihoodEngine.refine_steps")),
    ("core.tracking.feed", ("FrameFeed.get", "FrameFeed.prefetch")),
    ("core.tracking.frame_state", ("_BoneState.add",)),
    ("warp", ("synchronize_event", "synchronize_device", "synchronize_stream", "synchronize")),
)


class _Stats:
    """Calls, inclusive and exclusive seconds per (phase, name)."""

    def __init__(self) -> None:
        self.rows: dict = {}
        self.stack: list = []
        self.phase = "loop"
        self.first = None  # the run's first frame (its first frame step's)
        self.frame = None  # the frame whose step is running (None: the loop, the backward check)
        self.per_frame: dict = {}  # frame -> {name: [calls, inclusive seconds]} within its frame step

    def timed(self, fn, name: str):
        @functools.wraps(fn)  # (its module and name kept; __wrapped__ the function it calls)
        def w(*a, **k):
            self.stack.append(0.0)
            t = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                self.done(name, time.perf_counter() - t)
        w._timing_only = True  # (the calls passed on unchanged: joint_pipeline.applies looks through it)
        return w

    def done(self, name: str, dt: float) -> None:
        child = self.stack.pop()
        if self.stack:
            self.stack[-1] += dt
        s = self.rows.setdefault((self.phase, name), [0, 0.0, 0.0])
        s[0] += 1
        s[1] += dt
        s[2] += dt - child
        if self.frame is not None:
            c = self.per_frame.setdefault(self.frame, {}).setdefault(name, [0, 0.0])
            c[0] += 1
            c[1] += dt

    def unusual(self, frames) -> dict:
        """Per frame of ``frames`` (those after the run's first), the wrapped functions its step called a
        number of times other than the median over the frames after the first (a function a frame did not
        call counts 0): ``{frame: [[name, calls, median calls, inclusive ms], ...]}``, what ran in a slow
        frame that the others did not run (or ran more often)."""
        later = [f for f in self.per_frame if f != self.first]
        names = {n for f in later for n in self.per_frame[f]}
        med = {n: float(np.median([self.per_frame[f].get(n, [0, 0.0])[0] for f in later])) for n in names}
        out = {}
        for f in frames:
            got = self.per_frame.get(f, {})
            out[int(f)] = sorted(([n, got.get(n, [0, 0.0])[0], med[n], 1e3 * got.get(n, [0, 0.0])[1]]
                                  for n in names if got.get(n, [0, 0.0])[0] != med[n]), key=lambda r: -r[3])
        return out

    def table(self) -> dict:
        out: dict = {}
        for (ph, name), (n, inc, exc) in sorted(self.rows.items(), key=lambda kv: -kv[1][1]):
            out.setdefault(ph, []).append({"name": name, "calls": n, "incl_ms": 1e3 * inc,
                                           "excl_ms": 1e3 * exc})
        return out


@contextmanager
def wrapped():
    """Inside the block the functions of :data:`WRAPPED` (and the frame step, the backward check and the
    final stages' generators) are timed; yields the :class:`_Stats`. Everything is restored after."""
    import importlib

    import core.tracking.backward_check as backward
    import core.tracking.final_stage as fst
    import core.tracking.trial as trial

    st = _Stats()
    kept: list = []

    def put(obj, attr, new) -> None:
        kept.append((obj, attr, getattr(obj, attr)))
        setattr(obj, attr, new)

    for modname, names in WRAPPED:
        mod = importlib.import_module(modname)
        for name in names:
            obj, _, attr = name.rpartition(".")
            owner = getattr(mod, obj) if obj else mod
            if hasattr(owner, attr):
                short = "wp" if modname == "warp" else modname.rsplit(".", 1)[-1]
                label = name if obj else f"{short}.{attr}"
                put(owner, attr, st.timed(getattr(owner, attr), label))
    step = trial.track_frame

    def frame_step(run, f, *a, **k):
        old = st.phase
        if old != "backward":
            st.first = f if st.first is None else st.first
            st.phase = "first" if f == st.first else "later"
        was, st.frame = st.frame, (f if old != "backward" else None)
        try:
            return st.timed(step, "track_frame")(run, f, *a, **k)
        finally:
            st.phase, st.frame = old, was

    check = backward.backward_check

    def backward_check(*a, **k):
        old, st.phase = st.phase, "backward"
        try:
            return st.timed(check, "backward_check")(*a, **k)
        finally:
            st.phase = old

    steps = fst.final_stage_steps

    def final_stage_steps(*a, **k):
        g = steps(*a, **k)

        def timed():
            n = 0
            while True:
                st.stack.append(0.0)
                t = time.perf_counter()
                try:
                    v = next(g)
                except StopIteration as stop:
                    st.done("stage_gen.next_last", time.perf_counter() - t)
                    return stop.value
                st.done("stage_gen.next0" if n == 0 else "stage_gen.next", time.perf_counter() - t)
                n += 1
                yield v

        return timed()

    put(trial, "track_frame", frame_step)
    put(backward, "backward_check", backward_check)
    put(fst, "final_stage_steps", final_stage_steps)
    try:
        yield st
    finally:
        for obj, attr, old in reversed(kept):
            setattr(obj, attr, old)


def profile_run(renderer, models, frames, order, keyframes, options, skip=None) -> dict:
    """One run of :func:`core.tracking.trial.track` with :func:`wrapped` (``skip``: track's): the run's
    times and the table (the first phase that of the run's first frame step), and ``unusual_calls``: the
    wrapped calls of the three slowest frames after the first whose counts differ from the median frame's
    (:meth:`_Stats.unusual`)."""
    from core.tracking.trial import track

    with wrapped() as st:
        got = _timed_track(track, renderer, models, frames, list(order), keyframes, options, skip)
    got["stats"] = st.table()
    # what the three slowest frames after the first called that the others did not (loop_clock's records)
    got["unusual_calls"] = st.unusual([r["frame"] for r in got["frames"].get("slowest_records", [])])
    return got


def _timed_track(track, renderer, models, frames, order, keyframes, options, skip=None) -> dict:
    from core.studies.tracking.loop_clock import FrameClock
    from core.tracking.gc_pause import GcWatch

    clock = FrameClock()
    with GcWatch() as gw, clock.watching():
        t0 = time.perf_counter()
        res = track(renderer, models, frames, order, keyframes=keyframes, options=options,
                    progress=clock.progress, skip=skip)
        wall = time.perf_counter() - t0
    ends = {f: e[0] for f, e in clock.ends.items()}
    first = ends.get(order[0], t0) - t0
    n = max(len(order) - 1, 1)
    evals = float(np.mean([x.evaluations for x in res.results.values()])) * len(models)
    return {"wall_s": wall, "first_frame_ms": 1e3 * first,
            "ms_per_frame_after_first": 1e3 * (wall - first) / n, "evaluations_per_frame": evals,
            "frames": clock.report(order, t0, wall), "gc": gw.to_dict()}


def parse_variants(spec: str | None) -> dict:
    """``{name: [(module, attribute, value), ...]}`` of ``--variants`` (module docs)."""
    import ast

    out: dict = {}
    for part in (spec or "").split(";"):
        if not part.strip():
            continue
        name, _, sets = part.partition(":")
        items = []
        for a in sets.split(","):
            if not a.strip():
                continue
            path, _, val = a.partition("=")
            mod, _, attr = path.strip().rpartition(".")
            items.append(("core.tracking." + mod, attr, ast.literal_eval(val.strip())))
        out[name.strip()] = items
    return out


def rotated(names: list, i: int) -> list:
    """``names`` rotated left by ``i`` (round ``i``'s order of the variants)."""
    if not names:
        return []
    i %= len(names)
    return names[i:] + names[:i]


@contextmanager
def switched(items):
    """The module attributes of ``items`` ``(module, attribute, value)`` set within the block."""
    import importlib

    kept = []
    try:
        for mod, attr, val in items:
            m = importlib.import_module(mod)
            if not hasattr(m, attr):
                raise ValueError(f"variants: {mod} has no {attr}")
            kept.append((m, attr, getattr(m, attr)))
            setattr(m, attr, val)
        yield
    finally:
        for m, attr, old in reversed(kept):
            setattr(m, attr, old)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.frame_profile",
                                description=__doc__.split("\n")[0])
    p.add_argument("--device", default=None)
    p.add_argument("--frames", type=int, default=100)
    p.add_argument("--pixels", type=int, default=1024)
    p.add_argument("--voxel", type=float, default=0.5)
    p.add_argument("--bones", choices=("three", "one"), default="three")
    p.add_argument("--final", choices=("likelihood", "none"), default="likelihood")
    p.add_argument("--workers", type=int, default=0)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--cprofile", action="store_true")
    p.add_argument("--variants", default=None)
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    from dataclasses import replace

    import warp as wp

    from core.render import DRRRenderer
    from core.studies.tracking.acceptance import TrackingScene
    from core.studies.tracking.trial_frames import synthesise
    from core.tracking.trial import TrackingOptions, track

    n = max(int(a.frames), 2)
    ts = TrackingScene(n_frames=n, pixels=a.pixels, spacing=a.voxel, phase=(0.0, 0.6 * n / 100.0),
                       device=a.device)
    synthesise(ts, range(n), int(a.workers))
    bones = [0, 1, 2] if a.bones == "three" else [1]
    models = [ts.models[b] for b in bones]
    r = DRRRenderer(ts.scene.rig, [m.volume.to_attenuation(ts.scene.bone_transfer) for m in models],
                    device=ts.device)
    kf = {m.name: {0: ts.truth(0)[b]} for m, b in zip(models, bones, strict=True)}
    o = TrackingOptions(mode="joint")
    if a.final == "likelihood":
        o = replace(o, refine_likelihood=True)
    track(r, models, ts.frames, [0, 1], keyframes=kf, options=o)  # warm-up: kernels, buffers
    dev = wp.get_device(str(ts.renderer.device))
    out = {"study": "core.studies.tracking.frame_profile", "device": str(dev),
           "device_name": getattr(dev, "name", str(dev)), "frames": n, "pixels": a.pixels,
           "voxel_mm": a.voxel, "bones": [m.name for m in models], "final": a.final,
           "plain": []}
    variants = parse_variants(a.variants)

    def plain() -> dict:
        return _timed_track(track, r, models, ts.frames, range(n), kf, o)

    if variants:
        out["variants"] = {k: {"switches": [f"{m}.{at}={v!r}" for m, at, v in it], "runs": []}
                           for k, it in variants.items()}
        out["round_orders"] = []
        for i in range(int(a.repeats)):  # each round starts one variant later (module docs: position bias)
            order = rotated(list(variants), i)
            out["round_orders"].append(order)
            for k in order:
                with switched(variants[k]):
                    out["variants"][k]["runs"].append(plain())
    else:
        out["plain"] = [plain() for _ in range(int(a.repeats))]
    out["wrapped"] = profile_run(r, models, ts.frames, range(n), kf, o)
    if a.cprofile:
        import cProfile
        import io
        import pstats

        pr = cProfile.Profile()
        pr.enable()
        out["cprofile_run"] = _timed_track(track, r, models, ts.frames, range(n), kf, o)
        pr.disable()
        s = io.StringIO()
        pstats.Stats(pr, stream=s).sort_stats("tottime").print_stats(60)
        if a.out:
            with open(a.out + ".cprofile.txt", "w") as fh:
                fh.write(s.getvalue())
    from core.io.atomic import print_json

    print_json(out, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
