"""The likelihood final stage's host time per bone-frame, the device's work taken out
(``python -m core.studies.tracking.stage_host``).

The benchmark's kind of trial (:class:`~core.studies.tracking.acceptance.TrackingScene`, by default 128²,
1.5 mm voxels, 8 frames) is tracked once with the likelihood stage (the talus alone, or the three bones
jointly: ``--bones three``), every stage call (:func:`core.tracking.final_stage.final_stage_steps`'
arguments) kept. The calls after the first frame's are then replayed, ``--repeats`` times under each
variant (:data:`VARIANTS`, their order rotated call by call), each stage run to its end
(:func:`~core.tracking.engine_likelihood.run_steps`; several bones of a frame side by side, as
:func:`~core.tracking.final_stage.final_stages` runs them), each after its frame was put on the device as
tracking puts it there (:func:`core.tracking.engine_upload.share`, untimed; on the CPU too unless
``--no-held``: the stage's set-up then reads its regions from that upload, as on a CUDA device).

Each stage's time is split into the device's part and the rest, the host's work (Python, numpy, the
runtime calls), in wall time and in this thread's CPU time (:func:`time.thread_time`: what other
processes of a loaded machine take is not counted; the CPU's figure to compare). On Warp's CPU device a
kernel runs inside its launch, so the device's part is the kernels' invocations, the CPU renderer's
threads, the radix sorts and the recorded graphs' replays, each timed; on a CUDA device it is the host's
waits for the device (:func:`warp.synchronize_event`, :func:`warp.synchronize_device`). Per variant: the
host's and the device's ms per bone-frame (median over the calls of each call's median over the repeats;
mean), the stage's steps; against the first variant the median over the calls of each call's median
difference of the host's CPU time (``host_cpu_ms_diff_median_<first>``) and whether every pose,
covariance, step count and taken flag is the same to the bit (else the largest differences); the Python
function calls a bone-frame (one pass of the calls under :mod:`cProfile`: a count that does not depend
on the machine's load). ``--cprofile``: the first variant's stages under :mod:`cProfile` (the functions
with the most own time per bone-frame). JSON on stdout (``--out``: also to a file).

Variants: ``base`` the modules' defaults (``again``: the same under another name, against ``base`` the floor
of the comparisons: a CUDA device's float atomics sum in another order from run to run); ``graph`` a step's
recorded work replayed on every device (:data:`~core.tracking.engine_likelihood.STEP_GRAPH` True: on the CPU
the path a CUDA device takes, its launches one by one); ``cpugraph`` that and the step's work captured as a
Warp CPU graph too (:data:`~core.tracking.likelihood_graph.CAPTURE_CPU`: one replay a step, as a CUDA
graph's); ``devsteps`` / ``devrender`` :data:`~core.tracking.engine_likelihood.DEVICE_STEPS` True /
``"render"``; ``segments`` / ``nosegments`` :data:`~core.tracking.likelihood_segments.SEGMENT_GRAPHS` True /
False (the stage's set-up, robust factors, sandwich and the robust step's moments as recorded graphs on
every device / on none); ``prev`` the stage's host cuts of :data:`PREV` off (as before them); ``a+b`` both.
"""

from __future__ import annotations

import time
from contextlib import ExitStack, contextmanager

import numpy as np

__all__ = ["PREV", "VARIANTS", "main", "run"]

#: the host cuts' switches (module, name, value before them)
PREV: tuple = ()

#: the variants' switches (module, name, value), beside ``prev``
VARIANTS = {"base": (), "again": (), "graph": (("core.tracking.engine_likelihood", "STEP_GRAPH", True),),
            "cpugraph": (("core.tracking.engine_likelihood", "STEP_GRAPH", True),
                         ("core.tracking.likelihood_graph", "CAPTURE_CPU", True)),
            "devsteps": (("core.tracking.engine_likelihood", "DEVICE_STEPS", True),),
            "devrender": (("core.tracking.engine_likelihood", "DEVICE_STEPS", "render"),),
            "segments": (("core.tracking.likelihood_segments", "SEGMENT_GRAPHS", True),),
            "nosegments": (("core.tracking.likelihood_segments", "SEGMENT_GRAPHS", False),)}


def _switches(name: str) -> list:
    out = []
    for part in name.split("+"):
        if part == "prev":
            out += list(PREV)
        elif part in VARIANTS:
            out += list(VARIANTS[part])
        else:
            raise ValueError(f"unknown variant {part!r} (known: prev, {', '.join(VARIANTS)})")
    return out


@contextmanager
def _variant(name: str):
    import importlib

    kept = []
    try:
        for mod, attr, value in _switches(name):
            m = importlib.import_module(mod)
            kept.append((m, attr, getattr(m, attr)))
            setattr(m, attr, value)
        yield
    finally:
        for m, attr, value in reversed(kept):
            setattr(m, attr, value)


class _KernelClock:
    """The device's work the host does not do: on Warp's CPU device the kernel invocations timed
    (``warp._src.context.invoke`` and ``invoke_cpu_blocks``), the CPU renderer's launches in its threads
    (:func:`core.render.drr.run_parallel`), the radix sorts and recorded graphs' replays
    (:func:`warp.capture_launch`) as a whole; on a CUDA device the host's waits for it
    (:func:`warp.synchronize_event`, :func:`warp.synchronize_device`)."""

    def __init__(self) -> None:
        self.s = 0.0  # wall seconds inside
        self.c = 0.0  # this thread's CPU seconds inside
        self.n = 0
        self._inside = 0

    @contextmanager
    def installed(self, cuda: bool = False):
        import warp as wp
        from warp._src import context as C

        import core.render.drr as drr
        import core.tracking.cpu_threads as ct

        if cuda:
            places = [(wp, "synchronize_event"), (wp, "synchronize_device")]
        else:
            places = [(C, "invoke"), (C, "invoke_cpu_blocks"), (drr, "run_parallel"), (ct, "run_parallel"),
                      (wp, "capture_launch"), (wp.utils, "radix_sort_pairs")]
        plain = [(m, k, getattr(m, k)) for m, k in places]

        def timed(f):
            def g(*a, **k):
                if self._inside:
                    return f(*a, **k)
                self._inside += 1
                t, c = time.perf_counter(), time.thread_time()
                try:
                    return f(*a, **k)
                finally:
                    self.s += time.perf_counter() - t
                    self.c += time.thread_time() - c
                    self.n += 1
                    self._inside -= 1
            return g

        try:
            for m, k, f in plain:
                setattr(m, k, timed(f))
            yield self
        finally:
            for m, k, f in plain:
                setattr(m, k, f)


def _capture(ts, bones, frames: int):
    """Track ``frames`` frames of ``ts`` with the stage; the stage calls (per frame, the list of
    ``(res, kwargs)``; several: one frame's bones side by side) and the run."""
    from dataclasses import replace

    import core.tracking.final_stage as fs
    from core.tracking.trial import TrackingOptions, track

    models = [ts.models[b] for b in bones]
    from core.render import DRRRenderer

    r = DRRRenderer(ts.scene.rig, [m.volume.to_attenuation(ts.scene.bone_transfer) for m in models],
                    device=ts.device)
    kf = {m.name: {0: ts.truth(0)[b]} for m, b in zip(models, bones, strict=True)}
    o = replace(TrackingOptions(mode="joint"), refine_likelihood=True)
    calls: list = []
    plain = fs.final_stage_steps

    def kept(renderer, frame, res, **kw):
        calls.append((renderer, frame, res, dict(kw)))
        return plain(renderer, frame, res, **kw)

    fs.final_stage_steps = kept
    try:
        run = track(r, models, ts.frames, range(frames), keyframes=kf, options=o)
    finally:
        fs.final_stage_steps = plain
    groups: list = []  # (the calls of one frame's side-by-side stages together: same frame object)
    for c in calls:
        if c[3].get("side_by_side") and groups and groups[-1][0][3].get("side_by_side") \
                and groups[-1][0][1] is c[1] and len(groups[-1]) < len(bones):
            groups[-1].append(c)
        else:
            groups.append([c])
    return groups, run


def _hold(group) -> None:
    """The group's frame put on the device as tracking puts it there (:func:`core.tracking.engine_upload.
    share`: the stage then reads its regions from that upload, :data:`~core.tracking.likelihood_frames.
    HELD_FRAME`), outside the timed stage; nothing where the shared upload does not apply."""
    import warp as wp

    from core.tracking import engine_upload as eu

    renderer, frame = group[0][0], group[0][1]
    eu.share(wp.get_device(str(renderer.device)), frame)


def _replay(group) -> list:
    """One frame's stage calls run again (side by side where they were); their results."""
    from core.tracking.engine_likelihood import StepClock, run_side_by_side, run_steps
    from core.tracking.final_stage import final_stage_steps

    if len(group) == 1:
        renderer, frame, res, kw = group[0]
        kw = {k: v for k, v in kw.items() if k not in ("clock", "side_by_side")}
        return [run_steps(final_stage_steps(renderer, frame, res, **kw))]
    clocks = [StepClock() for _ in group]
    gens = [final_stage_steps(renderer, frame, res, **{**kw, "clock": c})
            for (renderer, frame, res, kw), c in zip(group, clocks, strict=True)]
    return run_side_by_side(gens, clocks)


def _record(res) -> dict:
    fit = getattr(res, "fit", None)
    t = res.timing or {}
    nan = np.full((6, 6), np.nan)
    return {"pose": np.asarray(res.pose, dtype=float),
            "cov": np.asarray(getattr(fit, "covariance", nan) if fit is not None else nan, dtype=float),
            "steps": float(t.get("likelihood_steps", np.nan)),
            "taken": float(t.get("likelihood_taken", np.nan))}


def _compare(a: list, b: list) -> dict:
    same, dp, dc = True, 0.0, 0.0
    for x, y in zip(a, b, strict=True):
        for k in x:
            eq = np.array_equal(x[k], y[k], equal_nan=True)
            same &= bool(eq)
        dp = max(dp, float(np.nanmax(np.abs(x["pose"] - y["pose"]))))
        with np.errstate(invalid="ignore"):
            rel = np.abs(x["cov"] - y["cov"]) / np.maximum(np.abs(x["cov"]), 1e-300)
        dc = max(dc, float(np.nanmax(rel)) if np.any(np.isfinite(rel)) else 0.0)
    return {"identical": same, "pose_max_diff": dp, "cov_max_rel_diff": dc}


def run(*, device: str | None = "cpu", frames: int = 8, pixels: int = 128, voxel: float = 1.5,
        bones: str = "one", variants=("base",), repeats: int = 5, cprofile: bool = False,
        held: bool = True, workers: int = 0) -> dict:
    """The study (module docs); ``held``: the frames shared on the device on every device kind, as
    tracking shares them on a CUDA device (:data:`core.tracking.engine_upload.DEVICES`; the stage's
    set-up reads its regions there); ``workers``: processes for the frames' image chain before the run
    (:func:`core.studies.tracking.trial_frames.synthesise`, the same frames)."""
    from core.tracking import engine_upload as eu

    kept = eu.DEVICES
    if held:
        eu.DEVICES = ("cuda", "cpu")
    try:
        return _run(device=device, frames=frames, pixels=pixels, voxel=voxel, bones=bones, variants=variants,
                    repeats=repeats, cprofile=cprofile, held=held, workers=workers)
    finally:
        eu.DEVICES = kept


def _run(*, device, frames, pixels, voxel, bones, variants, repeats, cprofile, held, workers) -> dict:
    import platform

    import warp as wp

    from core.studies.tracking.acceptance import TrackingScene

    wp.config.quiet = True
    wp.init()
    idx = [1] if bones == "one" else [0, 1, 2]
    ts = TrackingScene(n_frames=max(frames, 2), pixels=pixels, spacing=voxel,
                       phase=(0.0, 0.6 * max(frames, 2) / 100.0), device=device)
    from core.studies.tracking.trial_frames import synthesise

    synthesise(ts, range(frames), int(workers))  # (the same frames, whatever the workers)
    groups, _ = _capture(ts, idx, frames)
    groups = groups[1:]  # (the first frame's stage sets up the engine's buffers: not timed)
    cuda = wp.get_device(str(ts.renderer.device)).is_cuda
    clock = _KernelClock()
    n_bf = sum(len(g) for g in groups)
    per = {v: {q: [[] for _ in groups] for q in ("wall", "kern", "cpu", "kcpu")} for v in variants}
    recs: dict = {}
    with ExitStack() as es:
        es.enter_context(clock.installed(cuda))
        for v in variants:  # (once each first: kernels and buffers of every variant made)
            with _variant(v):
                for g in groups:
                    _hold(g)
                    _replay(g)
        for rep in range(int(repeats)):
            for gi, g in enumerate(groups):
                for k in range(len(variants)):
                    v = variants[(k + rep + gi) % len(variants)]
                    _hold(g)
                    with _variant(v):
                        s0, k0 = clock.s, clock.c
                        t0, c0 = time.perf_counter(), time.thread_time()
                        out = _replay(g)
                        wall, cpu = time.perf_counter() - t0, time.thread_time() - c0
                    per[v]["wall"][gi].append(wall)
                    per[v]["kern"][gi].append(clock.s - s0)
                    per[v]["cpu"][gi].append(cpu)
                    per[v]["kcpu"][gi].append(clock.c - k0)
                    if rep == 0:
                        recs.setdefault(v, []).extend(_record(x) for x in out)
    res = {"study": "core.studies.tracking.stage_host", "machine": platform.machine(),
           "device": str(ts.renderer.device), "device_name": getattr(wp.get_device(str(ts.renderer.device)),
                                                                     "name", ""),
           "pixels": pixels, "voxel_mm": voxel, "frames": frames, "bones": bones, "repeats": int(repeats),
           "held_frames": bool(held),
           "bone_frames_timed": n_bf, "variants": {}}
    nb = np.array([len(g) for g in groups])

    def host_cpu(v):  # (per call, per repeat: this thread's CPU time outside the device's part)
        return [(np.array(c) - np.array(k)) * 1e3 / n for c, k, n in zip(per[v]["cpu"], per[v]["kcpu"], nb,
                                                                           strict=True)]

    for v in variants:
        w = np.array([np.median(x) for x in per[v]["wall"]]) * 1e3
        kk = np.array([np.median(x) for x in per[v]["kern"]]) * 1e3
        host = (w - kk) / nb
        hc = np.array([np.median(x) for x in host_cpu(v)])
        steps = [r["steps"] for r in recs[v]]
        res["variants"][v] = {"switches": [f"{m}.{a}={val!r}" for m, a, val in _switches(v)],
                              "host_ms_per_bone_frame_median": float(np.median(host)),
                              "host_ms_per_bone_frame_mean": float(np.mean(host)),
                              "host_cpu_ms_per_bone_frame_median": float(np.median(hc)),
                              "host_cpu_ms_per_bone_frame_mean": float(np.mean(hc)),
                              "device_ms_per_bone_frame_mean": float(np.mean(kk / nb)),
                              "wall_ms_per_bone_frame_mean": float(np.mean(w / nb)),
                              "steps_mean": float(np.nanmean(steps))}
        if v != variants[0]:
            a, b = host_cpu(variants[0]), host_cpu(v)
            d = np.array([np.median(np.array(y) - np.array(x)) for x, y in zip(a, b, strict=True)])
            res["variants"][v]["host_cpu_ms_diff_median_" + variants[0]] = float(np.median(d))
            res["variants"][v]["against_" + variants[0]] = _compare(recs[variants[0]], recs[v])
    for v in variants:  # (the Python function calls a bone-frame: one pass under cProfile)
        res["variants"][v]["python_calls_per_bone_frame"] = _calls(groups, v, n_bf)
    if cprofile:
        res["cprofile"] = _profile(groups, variants[0], n_bf)
    return res


def _profiled(groups, variant: str):
    """The replays of ``groups`` under ``variant`` with cProfile on (the holds outside it): their stats."""
    import cProfile
    import pstats

    prof = cProfile.Profile()
    with _variant(variant):
        for g in groups:
            _hold(g)
            prof.enable()
            _replay(g)
            prof.disable()
    return pstats.Stats(prof)


def _calls(groups, variant: str, n_bf: int) -> float:
    return float(sum(v[1] for v in _profiled(groups, variant).stats.values()) / n_bf)


def _profile(groups, variant: str, n_bf: int, top: int = 30) -> list:
    st = _profiled(groups, variant)
    rows = []
    for (fn, line, name), (_, nc, tt, ct, _) in st.stats.items():
        rows.append({"function": f"{fn.split('/core/')[-1] if '/core/' in fn else fn.split('/')[-1]}:{line}"
                                 f"({name})", "calls_per_bone_frame": nc / n_bf,
                     "own_ms_per_bone_frame": tt * 1e3 / n_bf, "cum_ms_per_bone_frame": ct * 1e3 / n_bf})
    rows.sort(key=lambda r: -r["own_ms_per_bone_frame"])
    return rows[:top]


def main(argv=None) -> int:
    from core.studies.tracking import _study_cli as cli

    p = cli.parser("core.studies.tracking.stage_host", __doc__)
    p.add_argument("--device", default="cpu")
    p.add_argument("--frames", type=int, default=8)
    p.add_argument("--pixels", type=int, default=128)
    p.add_argument("--voxel", type=float, default=1.5)
    p.add_argument("--bones", choices=("one", "three"), default="one")
    p.add_argument("--variants", default="base")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--cprofile", action="store_true")
    p.add_argument("--workers", type=int, default=0, help="processes for the frames' image chain")
    p.add_argument("--no-held", action="store_true",
                   help="the frames not shared on the device where tracking would not (the CPU)")
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    res = run(device=a.device, frames=a.frames, pixels=a.pixels, voxel=a.voxel, bones=a.bones,
              variants=tuple(a.variants.split(",")), repeats=a.repeats, cprofile=a.cprofile,
              held=not a.no_held, workers=a.workers)
    from core.io.atomic import print_json

    print_json(res, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
