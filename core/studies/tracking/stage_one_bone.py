"""Where one bone's likelihood final stage spends its time in ``talus bench track``'s trial
(``python -m core.studies.tracking.stage_one_bone``).

The scene is the benchmark's (:func:`core.studies.tracking.benchmark.run`: the 100-frame synthetic
walking trial, by default 1024², 0.5 mm voxels; ``--frames`` of it), the bone the talus alone, the
options the benchmark's ``--final likelihood`` run (the search stopping at
:data:`~core.tracking.register_options.STAGE_SEARCH_TOL`, then the stage). Per variant
(:func:`core.studies.tracking.stage_speed._variant`'s names, alternated over ``--repeats``):

* ``runs`` — the frames tracked and timed end to end: wall time a frame after the first, the stage's
  ``likelihood_s`` and its set-up, steps and renders per bone-frame (medians and means);
* ``host_parts`` (``--profile``) — the stage's functions and the engine's methods each timed on the
  host without a synchronisation (inclusive wall time per bone-frame, so a method that waits for
  the device holds its wait; :meth:`~core.tracking.likelihood_launches._Launches._wait` on its own);
* ``kernels`` (``--profile``) — the device's time per activity inside the stage (Warp's CUDA
  activity timing around :func:`~core.tracking.final_stage.final_stage`), against its wall time;
* ``host`` (``--host-profile``) — the stage under :mod:`cProfile` (the functions with the most own
  time per bone-frame).

The study's own parts (alone or ``a+b``): ``noprefetch`` / ``prefetch`` the registration's upload of
the stage's rows while the search runs off / on (:data:`core.tracking.register.STAGE_PREFETCH`:
:func:`~core.tracking.final_stage.stage_prefetch` in its ``idle`` slot), ``noafter`` / ``after`` the first
refinement's sandwich before the robust factors / after the robust refinement's first step
(:data:`core.tracking.final_stage.SANDWICH_AFTER_STEP`, on by default since both were measured alone:
``resources/benchmarks/tracking_stage_one_bone_97b2893_h100.json``, when both were off by default);
``sorts`` the robust factors' median's one sort off (``roiprev``, the regions by the tracker's engine's
kernel instead of a count per thread block, went with that kernel: ``tracking_share_frame_h100.json``),
``nolean`` the steps' tables solved and the sandwich's autocovariance copied as before
(:data:`core.tracking.likelihood_solve.LEAN_SOLVES`, :data:`core.tracking.likelihood_confidence.COV_ON_READ`),
``h2prev`` the three first as at 97b2893 (:data:`_PARTS`).
The runs count the stages that took the prefetched rows. ``--interleave N``: then ``N`` tracks more in which
the variants take the stage in turn, frame by frame (the ``i``-th stage call under variant ``(i + run) % k``:
the host's drift, 20 % from run to run on one NVIDIA H100's host, shared; only flags read inside the stage
count there, not the prefetch's), with per variant the stage's ms over those calls and, against the first,
the median of the differences within each cycle of ``k`` consecutive calls (``interleaved``).
Also the poses of every variant against the first's (largest difference, mm / degrees, and whether
equal to the bit). JSON on stdout (``--out``: also to a file).
"""

from __future__ import annotations

import argparse
import time
from contextlib import ExitStack, contextmanager

import numpy as np

__all__ = ["main", "run"]


def _json_line(x) -> str:
    import json

    return json.dumps(x, default=float)

#: functions timed on the host (module, owner or None, name) by ``host_parts``
_HOST = (("core.tracking.final_stage", None, "final_stage"),
         ("core.tracking.final_stage", None, "search_roi"),
         ("core.tracking.final_stage", None, "snap_roi"),
         ("core.tracking.final_stage", None, "likelihood_engine"),
         ("core.tracking.final_stage", None, "_refine_steps"),
         ("core.tracking.final_stage", None, "stage_params"),
         ("core.tracking.engine_likelihood", None, "solve_moments"),
         ("core.tracking.likelihood_solve", None, "solve_tables"),
         ("core.tracking.engine_likelihood", "LikelihoodEngine", "set_frame"),
         ("core.tracking.engine_likelihood", "LikelihoodEngine", "_stage"),
         ("core.tracking.engine_likelihood", "LikelihoodEngine", "_staged"),
         ("core.tracking.engine_likelihood", "LikelihoodEngine", "_frame_others"),
         ("core.tracking.engine_likelihood", "LikelihoodEngine", "_others_own"),  # (the recorded set-up's)
         ("core.tracking.engine_likelihood", "LikelihoodEngine", "step_launch"),
         ("core.tracking.engine_likelihood", "LikelihoodEngine", "step_result"),
         ("core.tracking.engine_likelihood", "LikelihoodEngine", "_step_work"),
         ("core.tracking.engine_likelihood", "LikelihoodEngine", "_wait"),
         ("core.tracking.engine_likelihood", "LikelihoodEngine", "robust_weights"),
         ("core.tracking.engine_likelihood", "LikelihoodEngine", "scale_weights"),
         # (the stage's default robust round: both of the above as one recorded piece; it calls them
         # where the weights are counted, so theirs are inside its time there)
         ("core.tracking.engine_likelihood", "LikelihoodEngine", "robust_scale"),
         ("core.tracking.engine_likelihood", "LikelihoodEngine", "sandwich_launch"),
         ("core.tracking.engine_likelihood", "LikelihoodEngine", "sandwich_result"))


@contextmanager
def _patched(obj, name: str, new):
    old = getattr(obj, name)
    setattr(obj, name, new)
    try:
        yield
    finally:
        setattr(obj, name, old)


def _generator_timed(f, acc, name):
    """A generator function's wrapper that counts the time spent inside it (its own steps)."""
    def g(*a, **k):
        gen = f(*a, **k)
        t = time.perf_counter()
        x = acc.setdefault(name, [0.0, 0])
        x[1] += 1
        try:
            while True:
                try:
                    nxt = next(gen)
                except StopIteration as stop:
                    return stop.value
                x[0] += time.perf_counter() - t
                yield nxt
                t = time.perf_counter()
        finally:
            x[0] += time.perf_counter() - t
    return g


def _host_parts(acc: dict):
    """:data:`_HOST` each timed (``acc`` name -> [s, calls]; no synchronisation added)."""
    import importlib
    import inspect

    st = ExitStack()
    for mod, owner, name in _HOST:
        obj = importlib.import_module(mod)
        if owner is not None:
            obj = getattr(obj, owner)
        f = getattr(obj, name)
        if inspect.isgeneratorfunction(f):
            st.enter_context(_patched(obj, name, _generator_timed(f, acc, name)))
            continue

        def timed(*a, _f=f, _n=name, **k):
            t = time.perf_counter()
            try:
                return _f(*a, **k)
            finally:
                x = acc.setdefault(_n, [0.0, 0])
                x[0] += time.perf_counter() - t
                x[1] += 1
        st.enter_context(_patched(obj, name, timed))
    return st


def _kernels(acc: dict, box: list):
    """The device's activities inside :func:`~core.tracking.final_stage.final_stage` (``acc`` name ->
    [ms, count]; ``box``: [bone-frames, wall s])."""
    import warp as wp

    import core.tracking.final_stage as fst

    plain = fst.final_stage

    def wrapped(*a, **k):
        wp.timing_begin(cuda_filter=wp.TIMING_ALL)
        t = time.perf_counter()
        try:
            return plain(*a, **k)
        finally:
            res = wp.timing_end()
            box[1] += time.perf_counter() - t
            box[0] += 1
            for x in res:
                y = acc.setdefault(x.name, [0.0, 0])
                y[0] += x.elapsed
                y[1] += 1
    return _patched(fst, "final_stage", wrapped)


def _cprofile(prof, box: list):
    import core.tracking.final_stage as fst

    plain = fst.final_stage

    def wrapped(*a, **k):
        prof.enable()
        try:
            return plain(*a, **k)
        finally:
            prof.disable()
            box[0] += 1
    return _patched(fst, "final_stage", wrapped)


@contextmanager
def _counting(counts: list):
    """``counts``: [stages that took the rows :func:`~core.tracking.final_stage.stage_prefetch` uploaded
    while the search ran, stages that uploaded their own]."""
    import core.tracking.likelihood_frames as lf

    taken = lf._FrameRegions._prefetched

    def counted(self, *a, **k):
        out = taken(self, *a, **k)
        counts[0 if out is not None else 1] += 1
        return out

    with _patched(lf._FrameRegions, "_prefetched", counted):
        yield


#: this study's own variant parts (name -> (module, flag, value) triples): the registration's prefetch of
#: the stage's rows on / off (:data:`core.tracking.register.STAGE_PREFETCH`), the first refinement's
#: sandwich after the robust refinement's first step on / off
#: (:data:`core.tracking.final_stage.SANDWICH_AFTER_STEP`), the robust factors' median's one sort off
#: (:data:`core.tracking.likelihood_kernels.MEDIAN_ONE_SORT`), a refinement's steps on the device / the host
#: (``devsteps`` / ``hoststeps``, ``devrender`` its ``"render"``: :data:`core.tracking.engine_likelihood.
#: DEVICE_STEPS`), the steps' tables
#: solved and the sandwich's autocovariance copied as before (:data:`core.tracking.likelihood_solve.
#: LEAN_SOLVES`, :data:`core.tracking.likelihood_confidence.COV_ON_READ` off); ``h2prev`` the three
#: first as at 97b2893 (the robust factors' CUDA graphs and the solves' direct calls measured then are
#: removed since: ``tracking_stage_one_bone_328e54e_h100.json``)
_PARTS = {"prefetch": (("core.tracking.register", "STAGE_PREFETCH", True),),
          "noprefetch": (("core.tracking.register", "STAGE_PREFETCH", False),),
          "after": (("core.tracking.final_stage", "SANDWICH_AFTER_STEP", True),),
          "noafter": (("core.tracking.final_stage", "SANDWICH_AFTER_STEP", False),),
          "sorts": (("core.tracking.likelihood_kernels", "MEDIAN_ONE_SORT", False),),
          "devsteps": (("core.tracking.engine_likelihood", "DEVICE_STEPS", True),),
          "devrender": (("core.tracking.engine_likelihood", "DEVICE_STEPS", "render"),),
          "hoststeps": (("core.tracking.engine_likelihood", "DEVICE_STEPS", False),),
          "nolean": (("core.tracking.likelihood_solve", "LEAN_SOLVES", False),
                     ("core.tracking.likelihood_confidence", "COV_ON_READ", False))}
_PARTS["h2prev"] = tuple(t for k in ("noprefetch", "noafter", "sorts") for t in _PARTS[k])


def _variant_of(name: str, counts: list):
    """:func:`core.studies.tracking.stage_speed._variant` of ``name`` with this study's parts
    (:data:`_PARTS`) known too, the stages that took prefetched rows counted into ``counts``."""
    from core.studies.tracking.stage_speed import _flag, _variant

    parts = name.split("+")
    st = ExitStack()
    st.enter_context(_counting(counts))
    for x in parts:
        for flag in _PARTS.get(x, ()):
            st.enter_context(_flag(*flag))
    rest = "+".join(x for x in parts if x not in _PARTS) or "base"
    st.enter_context(_variant(rest))
    return st


@contextmanager
def _interleaving(variants, shift: int, calls: list):
    """:func:`~core.tracking.final_stage.final_stage` under ``variants[(i + shift) % k]`` at its ``i``-th call
    (a stage run again by the move check's confirmation, ``TO_TOL``, under the defaults and not counted);
    ``calls`` gets ``(variant, stage ms)`` per counted call."""
    import core.tracking.final_stage as fst
    from core.tracking.engine_likelihood import TO_TOL

    plain = fst.final_stage

    def wrapped(*a, **k):
        if TO_TOL.get():
            return plain(*a, **k)
        v = variants[(len(calls) + shift) % len(variants)]
        with _variant_of(v, [0, 0]):
            res = plain(*a, **k)
        calls.append((v, 1e3 * float((res.timing or {}).get("likelihood_s", 0.0))))
        return res

    with _patched(fst, "final_stage", wrapped):
        yield


def _interleaved_summary(variants, runs: list) -> dict:
    """Per variant the stage's ms over the interleaved runs' calls (median, mean, count) and, against the
    first variant, the median of the differences within each cycle of ``k`` consecutive calls (each
    variant once a cycle: the host's drift shared)."""
    k = len(variants)
    per = {v: [t for calls in runs for u, t in calls if u == v] for v in variants}
    out = {"per_variant": {v: {"stage_ms_median": float(np.median(x)) if x else None,
                               "stage_ms_mean": float(np.mean(x)) if x else None, "calls": len(x)}
                           for v, x in per.items()}}
    diffs: dict = {v: [] for v in variants[1:]}
    for calls in runs:
        for c in range(0, len(calls) - k + 1, k):
            cyc = dict(calls[c:c + k])
            for v in variants[1:]:
                if v in cyc and variants[0] in cyc:
                    diffs[v].append(cyc[v] - cyc[variants[0]])
    out["cycle_difference_ms_against_" + variants[0]] = {
        v: {"median": float(np.median(d)) if d else None,
            "quartiles": [float(q) for q in np.percentile(d, [25, 75])] if d else None, "cycles": len(d)}
        for v, d in diffs.items()}
    return out


def run(*, device=None, frames: int = 40, pixels: int = 1024, voxel: float = 0.5, variants=("base",),
        repeats: int = 3, profile: bool = True, host_profile: bool = False, workers: int = 0,
        interleave: int = 0) -> dict:
    """Run the study (module docs); returns the JSON-ready results."""
    from dataclasses import replace

    from core.render import DRRRenderer
    from core.studies.tracking.acceptance import TrackingScene
    from core.studies.tracking.benchmark import _search_tol
    from core.studies.tracking.stage_speed import _host_table, _pose_diff
    from core.studies.tracking.trial_frames import synthesise
    from core.tracking.trial import TrackingOptions, track

    n = int(frames)
    t0 = time.perf_counter()
    ts = TrackingScene(n_frames=max(n, 2), pixels=pixels, spacing=voxel, phase=(0.0, 0.6 * max(n, 2) / 100.0),
                       device=device)
    synthesise(ts, range(ts.scene.n_frames), int(workers))
    out: dict = {"study": "core.studies.tracking.stage_one_bone", "pixels": pixels, "voxel_mm": voxel,
                 "frames": n, "variants": list(variants), "repeats": repeats,
                 "synthesis_s": time.perf_counter() - t0}
    base = TrackingOptions(mode="joint")
    o = replace(base, registration=replace(base.registration, search="newton"), refine_likelihood=True)
    m = ts.models[1]
    r = DRRRenderer(ts.scene.rig, [m.volume.to_attenuation(ts.scene.bone_transfer)], device=ts.device)
    kf = {m.name: {0: ts.truth(0)[1]}}
    runs: dict = {v: [] for v in variants}
    poses: dict = {}
    with _search_tol("likelihood"):
        for v in variants:  # warm-up: kernels, buffers, graphs
            with _variant_of(v, [0, 0]):
                track(r, [m], ts.frames, range(min(n, 4)), keyframes=kf, options=o)
        for rep in range(int(repeats)):
            for v in (variants if rep % 2 == 0 else variants[::-1]):
                ends: dict = {}

                def progress(done, total, fr, ends=ends):
                    ends[fr.frame] = time.perf_counter()

                counts = [0, 0]
                with _variant_of(v, counts):
                    t1 = time.perf_counter()
                    res = track(r, [m], ts.frames, range(n), keyframes=kf, options=o, progress=progress)
                    wall = time.perf_counter() - t1
                rs = [res.results[(m.name, f)] for f in range(n)]
                tim = [x.timing or {} for x in rs[1:]]
                after = 1e3 * (wall - (ends[0] - t1)) / max(n - 1, 1)
                d = {"wall_s": wall, "ms_per_frame_after_first": after,
                     "stage_ms_mean": 1e3 * float(np.mean([t.get("likelihood_s", 0.0) for t in tim])),
                     "stage_ms_median": 1e3 * float(np.median([t.get("likelihood_s", 0.0) for t in tim])),
                     "setup_ms_mean": 1e3 * float(np.mean([t.get("likelihood_setup_s", 0.0) for t in tim])),
                     "registration_ms_median": 1e3 * float(np.median([x.time_s for x in rs[1:]])),
                     "steps_mean": float(np.mean([t.get("likelihood_steps", 0) for t in tim])),
                     "renders_mean": float(np.mean([t.get("likelihood_renders", 0) for t in tim])),
                     "taken": int(sum(t.get("likelihood_taken", 0) for t in tim)),
                     "prefetch_taken": counts[0], "prefetch_not_taken": counts[1]}
                runs[v].append(d)
                poses.setdefault(v, {(m.name, f): rs[f].pose for f in range(n)})
                print(f"{v} rep {rep}: {d['ms_per_frame_after_first']:.3f} ms/frame after the first, stage "
                      f"{d['stage_ms_median']:.3f} ms (median; set-up {d['setup_ms_mean']:.3f}), "
                      f"{d['steps_mean']:.2f} steps", flush=True)
        out["runs"] = runs
        ilv: list = []
        for rep in range(int(interleave)):  # the variants frame by frame within one track (module docs)
            calls: list = []
            with _interleaving(tuple(variants), rep, calls):
                track(r, [m], ts.frames, range(n), keyframes=kf, options=o)
            ilv.append(calls)
        if ilv:
            out["interleaved"] = {"runs": ilv, **_interleaved_summary(tuple(variants), ilv)}
            print("interleaved: " + _json_line(out["interleaved"]["per_variant"]), flush=True)
            print("  cycles: " + _json_line(out["interleaved"]["cycle_difference_ms_against_" + variants[0]]),
                  flush=True)
        out["summary"] = {v: {k: float(np.median([x[k] for x in runs[v]]))
                              for k in ("ms_per_frame_after_first", "stage_ms_median", "stage_ms_mean",
                                        "setup_ms_mean", "registration_ms_median", "steps_mean")}
                          for v in variants}
        first = variants[0]
        out["poses_against_" + first] = {
            v: {**_pose_diff(poses[first], poses[v]),
                "identical": all(np.array_equal(poses[first][k], poses[v][k]) for k in poses[v])}
            for v in variants[1:]}
        prof: dict = {}
        for v in variants if (profile or host_profile) else ():
            p: dict = {}
            if profile:
                acc: dict = {}
                with _variant_of(v, [0, 0]), _host_parts(acc):
                    track(r, [m], ts.frames, range(n), keyframes=kf, options=o)
                nb = max(acc.get("final_stage", [0, 1])[1], 1)
                p["host_parts"] = {k: {"ms_per_bone_frame": 1e3 * a[0] / nb,
                                       "calls_per_bone_frame": a[1] / nb}
                                   for k, a in sorted(acc.items(), key=lambda kv: -kv[1][0])}
                kacc: dict = {}
                box = [0, 0.0]
                with _variant_of(v, [0, 0]), _kernels(kacc, box):
                    track(r, [m], ts.frames, range(n), keyframes=kf, options=o)
                nb = max(box[0], 1)
                p["stage_wall_ms_timed"] = 1e3 * box[1] / nb
                p["device_ms_per_bone_frame"] = sum(a[0] for a in kacc.values()) / nb
                p["kernels"] = {k: {"ms_per_bone_frame": a[0] / nb, "per_bone_frame": a[1] / nb}
                                for k, a in sorted(kacc.items(), key=lambda kv: -kv[1][0])}
                top = list(p["host_parts"].items())[:14]
                print(f"profile {v}: " + ", ".join(f"{k} {a['ms_per_bone_frame']:.3f}" for k, a in top),
                      flush=True)
                top = list(p["kernels"].items())[:12]
                print(f"  device {p['device_ms_per_bone_frame']:.3f} ms of {p['stage_wall_ms_timed']:.3f}: "
                      + ", ".join(f"{k} {a['ms_per_bone_frame']:.3f}" for k, a in top), flush=True)
            if host_profile:
                import cProfile

                cp, box = cProfile.Profile(), [0]
                with _variant_of(v, [0, 0]), _cprofile(cp, box):
                    track(r, [m], ts.frames, range(n), keyframes=kf, options=o)
                p["host"] = _host_table(cp, max(box[0], 1), top=25)
            prof[v] = p
        out["profile"] = prof
    out["total_s"] = time.perf_counter() - t0
    return out


def main(argv=None) -> int:
    import json
    import pathlib

    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.stage_one_bone",
                                description=__doc__.split("\n")[0])
    p.add_argument("--device", default=None)
    p.add_argument("--frames", type=int, default=40)
    p.add_argument("--pixels", type=int, default=1024)
    p.add_argument("--voxel", type=float, default=0.5)
    p.add_argument("--variants", default="base",
                   help="comma-separated: stage_speed's variants and this study's parts (_PARTS)")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--no-profile", action="store_true")
    p.add_argument("--host-profile", action="store_true")
    p.add_argument("--workers", type=int, default=0)
    p.add_argument("--interleave", type=int, default=0,
                   help="tracks with the variants in turn frame by frame (their flags inside the stage only)")
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    out = run(device=a.device, frames=a.frames, pixels=a.pixels, voxel=a.voxel,
              variants=tuple(a.variants.split(",")), repeats=a.repeats, profile=not a.no_profile,
              host_profile=a.host_profile, workers=a.workers, interleave=a.interleave)
    text = json.dumps(out, indent=1, default=float)
    if a.out:
        pathlib.Path(a.out).write_text(text)
    print(json.dumps(out.get("summary"), indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
