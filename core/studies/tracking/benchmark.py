"""Tracking speed benchmark: ``python -m core.studies.tracking.benchmark [--device cuda:0] [--quick]
[--search newton|local] [--compare]``.

Cases (synthetic walking trial of :mod:`core.studies.tracking.acceptance`, frames synthesised before the
clock starts; frame 0 starts from the true pose so the numbers are steady-state tracking):

* ``one_bone`` — the talus over ``frames`` frames, two views of ``pixels``²;
* ``three_bones`` — tibia, talus and calcaneus over the same frames.

Besides the whole run, ``first_frame_ms`` (frame 0: the first-frame global search and its
restart check) and ``ms_per_frame_after_first`` / ``frames_per_second_after_first`` (the frames
that follow it, wall clock from the end of frame 0 to the end of the run) are reported;
``frame_clock`` takes the median run frame by frame (the median, mean and longest frame from the end
of the one before, the three slowest, and the run after its last frame: the backward check and the
trajectory post-pass; :func:`core.studies.tracking.loop_clock.frame_walls`; with the slow frames' records,
what ran in them, :class:`core.studies.tracking.loop_clock.FrameClock`), ``gc_runs`` each run's
garbage collections (:class:`core.tracking.gc_pause.GcWatch`) and
``registration_ms_mean_after_first_frame`` the mean beside the median: a host pause inside the run shows
in the mean and the longest frame, not in the medians.

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

Per bone, the per-frame RMS errors are divided by the Cramér–Rao bound of the same trial
(:func:`core.studies.tracking.acceptance.cramer_rao`, every tenth frame; ``bound_ratio``);
``flagged`` / ``flagged_frames`` count the frames flagged for review, ``over_4x_bound`` the
frames whose translation or rotation error exceeds 4× that per-frame bound (RMS over those
frames) and ``silent_failures`` / ``silent_failure_frames`` those of them not flagged (the
issue's acceptance asks for none).

Physical floor (``floor``, Gauss–Newton engine only): the time of the device work alone — the DRR
launches and the metric graphs of the evaluations the tracker used per frame (its 13-pose steps
and single-pose scores, per bone and pyramid scale), enqueued back to back with one
synchronisation at the end — so the ratio of the end-to-end time to what the GPU must do is
visible.

``--search`` picks the tracking search (``newton``: the Gauss–Newton engine,
:mod:`core.tracking.engine`; ``local``: the quadratic-model search); ``--compare`` runs both on
the same scene and device. ``--final`` picks the final stage (``none``, the default, or
``likelihood``: :attr:`~core.tracking.options.TrackingOptions.refine_likelihood`, the search before it
stopping at :data:`~core.tracking.register_options.STAGE_SEARCH_TOL`; ``likelihood_full``: the stage
after the search to its own tolerance, as before that constant, under ``<case>_likelihood_full``;
``likelihood_first``: the stage straight from the prediction, :data:`core.tracking.register.STAGE_FIRST`,
one bone's registrations only; each stage case's ``stage_search_tol`` saying which); a comma-separated
list runs each case once per entry in that order on the same scene (``none,likelihood,likelihood,none``:
the stage's cost end to end, alternated), the results under ``<case>``, ``<case>_likelihood`` and, for
an entry's second occurrence, ``<case>_2`` / ``<case>_likelihood_2``; the device floor counts the
Gauss–Newton engine's evaluations only, not the stage's. Full size: 1024² views, 0.5 mm voxels,
100 frames (a GPU); ``--quick``: 192² views, 1 mm voxels, 8 frames (this machine's CPU);
``--pixels``, ``--voxel``, ``--frames`` override; ``--workers``: the frames' image chain in that many
processes (the same frames, made before the clock starts). JSON on stdout.
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from contextlib import contextmanager

import numpy as np

__all__ = ["FINALS", "main", "run"]


def _floor(r, frames: int, results, bone_names) -> dict | None:
    """Device time of the evaluations the tracker used (module docs), or None without the
    Gauss-Newton engine."""
    import warp as wp

    from core.tracking.engine import _CACHE, step_design

    costs = [c for c in _CACHE.get(r, {}).values() if c.roi is not None]
    if not costs:
        return None
    names = {i: m for i, m in enumerate(bone_names)}
    per_frame = 0.0
    detail = {}
    for c in costs:
        key = f"{names.get(c.bone, c.bone)}@{c.scale:g}"
        mine = [x for x in results if x.bone == names.get(c.bone)]
        n13 = sum((x.timing or {}).get(f"engine_steps_x{c.scale:g}", 0) for x in mine) / frames
        n1 = sum((x.timing or {}).get(f"engine_scores_x{c.scale:g}", 0) for x in mine) / frames
        if not (n13 or n1):
            continue
        out, wall = {}, {}
        for B in (13, 1):
            X = step_design(np.zeros(6), np.full(6, 0.25))[:B]
            P = c.poses(X)
            Hc, Wc = c._cap
            c._evaluate(X)  # the pipeline of this batch exists
            pipe = c._pipes[B]
            reps = 50

            def once(P=P, X=X, c=c, pipe=pipe, Hc=Hc, Wc=Wc):
                if getattr(pipe, "render", None):  # the poses' table and the DRRs in the graph
                    pipe.x_np[:] = X
                else:
                    r.render(P[:, None], views=c.views, bones=[c.bone], roi=c.roi[None, :, None, :],
                             scale=c.scale, out_shape=(Hc, Wc))
                if pipe.graph is not None:
                    wp.capture_launch(pipe.graph)
                else:
                    pipe._enqueue()

            wp.synchronize_device(r.device)
            t0 = time.perf_counter()
            for _ in range(reps):
                once()
            wp.synchronize_device(r.device)
            wall[B] = (time.perf_counter() - t0) / reps
            if r.device.is_cuda:  # the device's own time: kernels, graphs and copies, from CUDA events
                wp.timing_begin(cuda_filter=wp.TIMING_KERNEL | wp.TIMING_GRAPH | wp.TIMING_MEMCPY)
                for _ in range(reps):
                    once()
                res = wp.timing_end()
                out[B] = sum(t.elapsed for t in res) / 1e3 / reps
            else:
                out[B] = wall[B]
        ms = 1e3 * (n13 * out[13] + n1 * out[1])
        detail[key] = {"steps_per_frame": n13, "scores_per_frame": n1, "ms_per_13_poses": 1e3 * out[13],
                       "ms_per_pose": 1e3 * out[1], "ms_per_frame": ms,
                       "enqueued_ms_per_13_poses": 1e3 * wall[13], "enqueued_ms_per_pose": 1e3 * wall[1]}
        per_frame += ms
    return {"ms_per_frame": per_frame, "per_bone_scale": detail}


def _case(ts, bones: list[int], options, frames: int, repeats: int = 3, bound: dict | None = None) -> dict:
    from core.render import DRRRenderer
    from core.studies.tracking.acceptance import FRAME_RATE_HZ, pose_errors
    from core.studies.tracking.loop_clock import FrameClock
    from core.tracking.gc_pause import GcWatch
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
        walls, firsts, clocks, gcs, runs = [], [], [], [], []
        for _ in range(1 if prof else repeats):  # the median of repeats: host timing is noisy
            clock = FrameClock()  # when each frame's last bone finished, and what ran in the frame
            with GcWatch() as gw, clock.watching():
                t0 = time.perf_counter()
                runs.append(track(r, models, ts.frames, range(frames), keyframes=kf, options=o,
                                  progress=clock.progress))
                walls.append(time.perf_counter() - t0)
            firsts.append(clock.ends[0][0] - t0 if 0 in clock.ends else 0.0)
            clocks.append(clock.report(range(frames), t0, walls[-1]))
            gcs.append(gw.to_dict())
        wall = float(np.median(walls))
        k = int(np.argsort(walls)[len(walls) // 2])  # the median run: its results, timings and clock
        res = runs[k]
        del runs
        rs = list(res.results.values())
        tim = {k: float(sum((x.timing or {}).get(k, 0.0) for x in rs))
               for k in ("render_s", "metric_s", "host_s", "optimizer_s", "other_s")}
        errs = np.array([pose_errors(x.pose, ts.truth(x.frame)[bones[[m.name for m in models].index(x.bone)]],
                                     models[[m.name for m in models].index(x.bone)].centroid)
                         for x in rs if x.pose is not None])
        names = [m.name for m in models]
        per_bone = {}
        for m, b in zip(models, bones, strict=True):
            e = np.array([pose_errors(x.pose, ts.truth(x.frame)[b], m.centroid)
                          for x in rs if x.bone == m.name and x.pose is not None]).reshape(-1, 6)
            pb = {"rms_error_mm": float(np.sqrt(np.mean(np.sum(e[:, :3] ** 2, axis=1)))),
                  "rms_error_deg": float(np.sqrt(np.mean(np.sum(e[:, 3:] ** 2, axis=1)))),
                  "max_error_deg": float(np.max(np.linalg.norm(e[:, 3:], axis=1))),
                  "flagged": sum(bool(x.flags) for x in rs if x.bone == m.name),
                  "flagged_frames": sorted(x.frame for x in rs if x.bone == m.name and x.flags),
                  "retried": sum(bool(x.retried) for x in rs if x.bone == m.name)}
            cb = (bound or {}).get(ts.names[b])
            if cb:
                pb["bound_mm"], pb["bound_deg"] = cb["rms_mm"], cb["rms_deg"]
                pb["bound_ratio"] = {"mm": pb["rms_error_mm"] / cb["rms_mm"],
                                     "deg": pb["rms_error_deg"] / cb["rms_deg"]}
                # frames off by more than 4x the per-frame bound, and those of them not flagged
                mine = [x for x in rs if x.bone == m.name and x.pose is not None]
                over = ((np.linalg.norm(e[:, :3], axis=1) > 4 * cb["rms_mm"])
                        | (np.linalg.norm(e[:, 3:], axis=1) > 4 * cb["rms_deg"]))
                pb["over_4x_bound"] = int(over.sum())
                silent = sorted(x.frame for x, o in zip(mine, over, strict=True) if o and not x.flags)
                pb["silent_failures"] = len(silent)
                pb["silent_failure_frames"] = silent
            sig = [x.confidence for x in rs if x.bone == m.name and x.pose is not None and x.confidence]
            if sig and len(sig) == len(e) and all(c.get("sigma") and None not in c["sigma"] for c in sig):
                S = np.array([c["sigma"] for c in sig])
                pb["within_2_sigma"] = float(np.mean(np.all(np.abs(e) <= 2 * S, axis=1)))
            per_bone[m.name] = pb
        del names
        per_frame = {}
        for x in rs:
            per_frame[x.frame] = per_frame.get(x.frame, 0.0) + x.time_s
        later = [per_frame[f] for f in sorted(per_frame) if f > 0]  # frame 0: the global first-frame search
        entry = {"wall_s": wall, "runs_wall_s": walls, "frames_per_second": frames / wall,
                 "registration_ms_median_after_first_frame": 1e3 * float(np.median(later)) if later else None,
                 "registration_ms_mean_after_first_frame": 1e3 * float(np.mean(later)) if later else None,
                 # the median run frame by frame (a host pause shows in the max and the mean) and each
                 # run's garbage collections (counts per generation, pauses)
                 "frame_clock": clocks[k], "gc_runs": gcs,
                 "frames_per_second_range": [frames / max(walls), frames / min(walls)],
                 "ms_per_frame": 1e3 * wall / frames,
                 # the first frame (global search, restarts) apart: the tracking that follows it
                 "first_frame_ms": 1e3 * firsts[k],
                 "ms_per_frame_after_first": 1e3 * (walls[k] - firsts[k]) / max(frames - 1, 1),
                 "frames_per_second_after_first": max(frames - 1, 1) / max(walls[k] - firsts[k], 1e-9),
                 "evaluations_per_frame": float(np.mean([x.evaluations for x in rs])) * len(bones),
                 "generations": int(sum(x.timing.get("calls", 0) for x in rs if x.timing)),
                 "converged_fraction": res.summary()["converged_fraction"],
                 "rms_error_mm": float(np.sqrt(np.mean(np.sum(errs[:, :3] ** 2, axis=1)))),
                 "rms_error_deg": float(np.sqrt(np.mean(np.sum(errs[:, 3:] ** 2, axis=1)))),
                 "per_bone": per_bone}
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
        else:
            fl = _floor(r, frames, rs, [m.name for m in models])
            if fl is not None:
                fl["end_to_end_over_floor"] = entry["ms_per_frame"] / max(fl["ms_per_frame"], 1e-9)
                entry["floor"] = fl
        out[label] = entry
    return out


def _final_runs(final: str, options) -> list:
    """(key suffix, options) per entry of ``final`` (one of :data:`FINALS` or a comma-separated
    list of them), in order: ``""`` / ``"_likelihood"``, a second occurrence's
    suffix ending in ``_2`` (a third's ``_3``); the likelihood entries' options with
    ``refine_likelihood``. ``options`` None: only checks ``final``."""
    from dataclasses import replace

    finals = [f.strip() for f in str(final).split(",")]
    if not all(f in FINALS for f in finals):
        raise ValueError(f"final: expected one of {FINALS} or a comma-separated list of them, got {final!r}")
    out, seen = [], {}
    for f in finals:
        seen[f] = seen.get(f, 0) + 1
        suffix = ("" if f == "none" else "_" + f) + (f"_{seen[f]}" if seen[f] > 1 else "")
        oo = options if options is None or f == "none" else replace(options, refine_likelihood=True)
        out.append((suffix, oo))
    return out


#: the ``--final`` entries: no stage, the likelihood stage after the search at its looser tolerance
#: (:data:`core.tracking.register_options.STAGE_SEARCH_TOL`, the default), after the search run to
#: its own tolerance (``likelihood_full``: that constant None, as before), or straight from the
#: prediction (``likelihood_first``: the study switch :data:`core.tracking.register.STAGE_FIRST`, one
#: bone's registrations only)
FINALS = ("none", "likelihood", "likelihood_full", "likelihood_first")


@contextmanager
def _search_tol(entry: str):
    """:data:`~core.tracking.register_options.STAGE_SEARCH_TOL` for a ``--final`` entry's runs (None
    for ``likelihood_full``; the module's value otherwise), and :data:`core.tracking.register.
    STAGE_FIRST` on for ``likelihood_first``."""
    import core.tracking.register as reg
    import core.tracking.register_options as ro

    kept, first = ro.STAGE_SEARCH_TOL, reg.STAGE_FIRST
    if entry == "likelihood_full":
        ro.STAGE_SEARCH_TOL = None
    reg.STAGE_FIRST = entry == "likelihood_first"
    try:
        yield ro.STAGE_SEARCH_TOL if not reg.STAGE_FIRST else "first"
    finally:
        ro.STAGE_SEARCH_TOL, reg.STAGE_FIRST = kept, first


def run(*, quick: bool = False, device: str | None = None, frames: int | None = None,
        pixels: int | None = None, cases: str = "both", repeats: int = 3, search: str = "newton",
        compare: bool = False, voxel: float | None = None, bound: bool = True,
        metric: str = "magnitudes", final: str = "none", workers: int = 0) -> dict:
    """Run the cases (``"one"``, ``"three"`` or ``"both"``) with the tracking ``search``
    (``compare``: ``newton`` and ``local`` both, the second under ``"<case>_local"``) and the
    gradient correlation of the gradient ``metric`` (``"magnitudes"``, the default term, or
    ``"components"``: the gc term's ``components`` option) and the final stage(s) ``final``
    (one of :data:`FINALS` or a comma-separated list of them, module docs); returns the JSON-ready
    results. ``workers``: processes for the frames' image chain before the clock starts (0: this
    one; :func:`core.studies.tracking.trial_frames.synthesise`, the same frames)."""
    if int(repeats) != repeats or repeats < 1:
        raise ValueError(f"repeats: expected a whole number >= 1, got {repeats!r}")
    if cases not in ("one", "three", "both"):
        raise ValueError(f"cases: expected 'one', 'three' or 'both', got {cases!r}")
    if metric not in ("magnitudes", "components"):
        raise ValueError(f"metric: expected 'magnitudes' or 'components', got {metric!r}")
    _final_runs(final, None)  # checks it before the scene is made
    from dataclasses import replace

    import warp as wp

    from core.studies.tracking.acceptance import TrackingScene, cramer_rao
    from core.tracking.trial import TrackingOptions

    n = frames or (8 if quick else 100)
    px = pixels or (192 if quick else 1024)
    vox = float(voxel or (1.0 if quick else 0.5))
    ts = TrackingScene(n_frames=max(n, 2), pixels=px, spacing=vox,
                       phase=(0.0, 0.6 * max(n, 2) / 100.0), device=device)
    t0 = time.perf_counter()
    from core.studies.tracking.trial_frames import synthesise

    synthesise(ts, range(ts.scene.n_frames), int(workers))  # (the same frames, whatever the workers)
    synth = time.perf_counter() - t0
    base = TrackingOptions(mode="joint")  # synthetic frames: DRR intensities match the images
    if metric == "components":
        reg = base.registration
        base = replace(base, registration=replace(reg, terms=tuple(
            replace(t, options={**t.options, "components": True}) if t.kind == "gc" else t
            for t in reg.terms)))
    o = replace(base, registration=replace(base.registration, search=search))
    t0 = time.perf_counter()
    cr = cramer_rao(ts, range(0, n, max(1, n // 10))) if bound else {}
    bound_s = time.perf_counter() - t0
    dev = wp.get_device(str(ts.renderer.device))
    res = {"benchmark": "core.tracking", "machine": platform.machine(), "cpu_count": os.cpu_count(),
           "processor": platform.processor() or platform.machine(), "device": str(dev),
           "device_name": getattr(dev, "name", str(dev)), "quick": quick,
           "sizes": {"pixels": px, "voxel_mm": vox, "frames": n,
                     "volumes_kji": {m.name: list(m.volume.data.shape) for m in ts.models}},
           "synthesis_s": synth, "repeats": int(repeats), "options": o.registration.to_dict()}
    res["mode"] = o.mode
    res["joint_rounds"] = o.joint_rounds  # the three-bone cases' rounds (1 since 8dbdcc2; 2 before)
    res["search"] = search
    res["metric"] = metric
    res["cramer_rao"] = cr
    res["cramer_rao_s"] = bound_s
    res["threads"] = {k: os.environ.get(k) for k in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}
    finals = [f.strip() for f in str(final).split(",")]
    res["final"] = finals if len(finals) > 1 else finals[0]
    runs = _final_runs(final, o)
    if compare:
        other = "local" if search != "local" else "newton"
        runs.append((f"_{other}", replace(base, registration=replace(base.registration, search=other))))
    for case, bones in (("one_bone", [1]), ("three_bones", [0, 1, 2])):
        if cases in (case.split("_")[0], "both"):
            for (suffix, oo), entry in zip(runs, finals + ["none"] * (len(runs) - len(finals)), strict=True):
                with _search_tol(entry if oo.refine_likelihood else "none") as tol:
                    res[case + suffix] = _case(ts, bones, oo, n, int(repeats), cr)
                # what this case ran: the top level's "options" are the runs' without the final stage
                res[case + suffix]["final"] = "likelihood" if oo.refine_likelihood else "none"
                if oo.refine_likelihood:  # the search's tolerance before the stage (None: its own 0.02)
                    res[case + suffix]["stage_search_tol"] = tol
    res["autoscoper_reference_s_per_frame_per_bone"] = [3.0, 13.0]
    return res


def main(argv=None, *, prog: str = "python -m core.studies.tracking.benchmark") -> int:
    """The command line; ``prog`` names it in the usage (``talus bench track`` passes its own)."""
    p = argparse.ArgumentParser(prog=prog,
                                description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="192² views, 1 mm voxels, 8 frames")
    p.add_argument("--device", default=None, help="Warp device (cpu, cuda:0); default CUDA when present")
    p.add_argument("--frames", type=int, default=None)
    p.add_argument("--pixels", type=int, default=None)
    p.add_argument("--cases", choices=("one", "three", "both"), default="both",
                   help="one bone (talus), three bones (joint), or both")
    p.add_argument("--repeats", type=int, default=3,
                   help="end-to-end runs per case; the median is reported (default 3)")
    p.add_argument("--voxel", type=float, default=None, help="CT voxel size, mm (default 0.5; --quick 1)")
    p.add_argument("--search", choices=("newton", "local"), default="newton",
                   help="tracking search: the Gauss-Newton engine (default) or the quadratic-model search")
    p.add_argument("--compare", action="store_true", help="also run the other search on the same scene")
    p.add_argument("--metric", choices=("magnitudes", "components"), default="magnitudes",
                   help="gradient correlation of the gradient magnitudes (default) or components")
    p.add_argument("--final", default="none",
                   help="final stage: none (default), likelihood (after the search at its looser "
                        "tolerance before a stage), likelihood_full (after the search to its own tolerance, "
                        "as before), likelihood_first (the stage from the prediction; one bone), or a "
                        "comma-separated list run in turn on the same scene (e.g. none,likelihood)")
    p.add_argument("--no-bound", action="store_true", help="skip the Cramér-Rao bound")
    p.add_argument("--workers", type=int, default=0,
                   help="processes for the frames' image chain before the clock starts (default 0: this one)")
    p.add_argument("--out", default=None, help="also write the JSON here")
    a = p.parse_args(argv)
    res = run(quick=a.quick, device=a.device, frames=a.frames, pixels=a.pixels, cases=a.cases,
              repeats=a.repeats, search=a.search, compare=a.compare, voxel=a.voxel, bound=not a.no_bound,
              metric=a.metric, final=a.final, workers=a.workers)
    from core.io.atomic import print_json

    print_json(res, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
