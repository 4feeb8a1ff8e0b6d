"""Where the likelihood final stage's time goes, and the stage's variants against each other on the
same frames (``python -m core.studies.tracking.stage_speed``).

The acceptance trial (:class:`core.studies.tracking.acceptance.TrackingScene`, by default 1024²,
0.5 mm voxels, ``--frames`` frames; the grid-estimated distortion correction, measured glare
undone — the frames of :mod:`core.studies.tracking.tissue_stage`) is tracked by
:func:`core.tracking.trial.track` (Gauss–Newton search, three bones jointly) with the
registrations' final likelihood stage (:mod:`core.tracking.final_stage`) at each high-pass σ of
``--highpass``, once per stage variant (:data:`VARIANTS`) and repeat, the variants alternated.
Per run: the stage's time per bone-frame (``likelihood_s`` of the registrations: set-up, steps,
robust factors and sandwich, each bone's share of the side-by-side stages' wall time), its set-up
and steps, the frame's wall time, and per bone the RMS error over the Cramér–Rao bound of the
same frames (every tenth) and frames over 4× it; the largest difference of every variant's
poses from the first variant's (mm, degrees); and every pair of variants (``variant_pairs``, the
first repeats): poses, the confidences' σ (largest relative difference) and whether both are equal
to the bit.

``--profile-frames N`` (the first ``N`` frames, once per variant and σ, not timed as above):
``kernels`` — the device's time per activity inside the stages (Warp's CUDA activity timing,
:func:`warp.timing_begin`, around :func:`~core.tracking.final_stage.final_stages`: each kernel,
copy and memset by name, total and count per bone-frame), against the stages' wall time there;
``parts`` — the engine's methods each timed with a device synchronisation before and after (the
stages then run one after another: a serial breakdown, not the overlapped wall time);
``--host-profile``: ``host`` — the stages run side by side under :mod:`cProfile` (per bone-frame, the
functions with the most own time and the most time inside them; a wait for the device is the own time
of the call that waits).
Only this study reads the truth. JSON on stdout (``--out``: also to a file).

Variants: ``base`` the modules' defaults; ``plain`` every speed flag off (the stage as first
measured, the fewer steps' flags off too); ``exact`` the blocked blur and the median by per-view
sorts (values unchanged); ``fast`` those and the design's differences
(:mod:`core.tracking.likelihood_fast`; ``exact`` and ``fast`` with the fewer steps off, as they were
measured against ``plain``); ``strict`` the
refinements' uphill test on every rise of χ² (as first measured; now on resolved steps only);
``jitter`` the stage's first refinement started 10⁻⁶ mm and degrees off (the stage's own spread
under a perturbation of rounding's size: what ``variant_pairs`` of the others compare with);
``last``, ``devreg``, ``stop<c>`` the fewer steps' flags set one by one and ``old`` all off (the
stage before them; :mod:`core.tracking.engine_likelihood`: Fewer steps) — since 41d036e ``last`` and
``devreg`` are the defaults, so alone they are ``base`` and ``stop<c>`` runs with both (the JSON's
call 1, before, had them off): one at a time on the stage before is ``old+last``, ``old+stop4`` —,
``fwd`` the forward design,
``chord`` the later steps with the design's centre alone rendered,
``sc<n>`` / ``meat<n>`` / ``mc<n>`` the sandwich's / its meat's / the moments' pixels a thread block;
``hostprev`` phase 3's exact host changes off (:data:`core.tracking.roi.BOX_CORNERS`,
:data:`core.tracking.likelihood_launches.BUFFERS_PER_SIZE`), ``ol<c>`` the region
from the bone's DRR support grown by ``c`` more high-pass σ (:data:`core.tracking.final_stage.REGION_OUTLINE`;
changes the poses);
``stageprev`` the sandwich after the robust step off (:data:`core.tracking.final_stage.SANDWICH_AFTER_STEP`;
the stage's regions from the search's upload and their smaller chunks, which it turned off too, are
removed);
``prev`` this work's step graphs (:mod:`core.tracking.likelihood_graph`), moments' triangle and the
sandwich's row-wise autocovariance and half-lag meat off (the defaults before them), ``nograph`` the
step graphs alone off;
``a+b`` both (e.g. ``plain+jitter``, ``fast+strict``). With the step graphs the kernel profile sees
a step's DRRs, blurs and moments as one ``graph`` activity. Measured:
``resources/benchmarks/tracking_stage_speed_h100.json`` (one NVIDIA H100, 30 frames; its ``base``
is today's ``plain``, its ``diff`` ``DIFF_IMAGES`` alone) and ``tracking_stage_speed_fast_h100.json``
(``plain``, ``exact``, ``fast``; ``fast`` is today's default; the numbers in
:mod:`core.tracking.likelihood_fast`); ``tracking_stage_fewer_steps_h100.json`` (``old`` against
the fewer steps, two calls); ``tracking_stage_h2_h100.json`` (``prev``, ``base``, ``nograph``) and
``tracking_stage_h2_host_h100.json`` (``prev``, ``base`` with ``--host-profile``);
``tracking_stage_h3_h100.json`` (``hostprev``, ``base``, ``ol0``, ``ol2`` with ``--host-profile``, then
``base``, ``ol4``, ``ol8``).
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict
from contextlib import ExitStack, contextmanager
from dataclasses import replace

import numpy as np

__all__ = ["VARIANTS", "main", "run"]


@contextmanager
def _base():
    yield


@contextmanager
def _flag(module: str, name: str, value):
    import importlib

    with _patched(importlib.import_module(module), name, value):
        yield


#: the fewer steps' flags off (the stage's defaults before 41d036e; engine_likelihood: Fewer steps)
_OLD_STEPS = {"STOP_PRED": 0.0, "ROBUST_FROM_LAST": False, "DEVICE_REGIONS": False, "MEAT_CHUNK": None}
#: the recorded steps, the moments' triangle and the sandwich's rows and half lags off (the defaults
#: before them: engine_likelihood.STEP_GRAPH, MOMENTS_TRI; likelihood_confidence.AUTOCOV_ROWS, MEAT_HALF)
_PREV = {"STEP_GRAPH": False, "MOMENTS_TRI": False, "AUTOCOV_ROWS": False, "MEAT_HALF": False}
#: phase 3's exact host changes off (roi.BOX_CORNERS, likelihood_launches.BUFFERS_PER_SIZE)
_HOST_PREV = {"BOX_CORNERS": False, "BUFFERS_PER_SIZE": False}
#: the stage's variants by name: a context manager factory each (the module flags they set)
VARIANTS: dict = {
    "base": _base,
    # the 13 images as centre and differences before the low-pass (engine_likelihood.DIFF_IMAGES)
    "diff": lambda: _flag("core.tracking.engine_likelihood", "DIFF_IMAGES", True),
    "nodiff": lambda: _flag("core.tracking.engine_likelihood", "DIFF_IMAGES", False),
    # the changes that keep every value: blocked blurs, the median's count by bisection (the fewer
    # steps off, as measured: against plain)
    "exact": lambda: _flags(BLOCK_BLUR=True, MEDIAN_BISECT=True, DIFF_IMAGES=False, **_OLD_STEPS),
    # those and the differences' images (the fewer steps off)
    "fast": lambda: _flags(BLOCK_BLUR=True, MEDIAN_BISECT=True, DIFF_IMAGES=True, **_OLD_STEPS),
    # every speed flag off (the stage as first measured; the fewer steps too)
    "plain": lambda: _flags(BLOCK_BLUR=False, MEDIAN_BISECT=False, DIFF_IMAGES=False, **_OLD_STEPS),
    # the refinements' uphill test on any rise of χ² (engine_likelihood.UPHILL_RESOLVED 0, as first measured)
    "strict": lambda: _flag("core.tracking.engine_likelihood", "UPHILL_RESOLVED", 0.0),
    # the stage's first refinement from 1e-6 mm and degrees off its start: the stage's own spread
    # under a perturbation of rounding's size (a variant "a+b" combines two)
    "jitter": lambda: _jitter(1e-6),
    # the robust round from the first refinement's last design (final_stage.ROBUST_FROM_LAST)
    "last": lambda: _flag("core.tracking.final_stage", "ROBUST_FROM_LAST", True),
    # the regions' line integrals made on the device (engine_likelihood.DEVICE_REGIONS)
    "devreg": lambda: _flag("core.tracking.engine_likelihood", "DEVICE_REGIONS", True),
    # a refinement's later steps with the centre alone rendered (engine_likelihood.CHORD_STEPS)
    "chord": lambda: _flag("core.tracking.engine_likelihood", "CHORD_STEPS", True),
    # the 7-pose forward design (engine_likelihood.FORWARD_DESIGN)
    "fwd": lambda: _flag("core.tracking.engine_likelihood", "FORWARD_DESIGN", True),
    # the stage's defaults before the fewer steps: every refinement to tol, the robust round's own
    # factor step, the regions on the host
    "old": lambda: _flags(**_OLD_STEPS),
    # this work's device and host changes off (the defaults before them): the steps' launches one by
    # one with the item table on the host, the full moments table, the autocovariance a pass per lag,
    # the meat over every lag
    "prev": lambda: _flags(**_PREV),
    # the steps' launches one by one (engine_likelihood.STEP_GRAPH off), the new kernels kept
    "nograph": lambda: _flag("core.tracking.engine_likelihood", "STEP_GRAPH", False),
    # phase 3's exact host changes off: search_roi's volume box by auto_roi, the buffers made anew per size
    "hostprev": lambda: _flags(**_HOST_PREV),
    # the sandwich after the robust step off (the sandwich before the robust factors)
    "stageprev": lambda: _flags(SANDWICH_AFTER_STEP=False),
    # (and "stop<c>": a refinement ends after a step below c χ²/N, engine_likelihood.STOP_PRED = c;
    # "ol<c>": the region from the bone's DRR support grown by c more high-pass σ, final_stage.REGION_OUTLINE)
}
_FLAG_HOME = {"BLOCK_BLUR": "core.tracking.engine_likelihood",
              "DIFF_IMAGES": "core.tracking.engine_likelihood",
              "MEDIAN_BISECT": "core.tracking.likelihood_kernels",
              "STOP_PRED": "core.tracking.engine_likelihood",
              "DEVICE_REGIONS": "core.tracking.engine_likelihood",
              "ROBUST_FROM_LAST": "core.tracking.final_stage",
              "MEAT_CHUNK": "core.tracking.likelihood_confidence",
              "STEP_GRAPH": "core.tracking.engine_likelihood",
              "MOMENTS_TRI": "core.tracking.engine_likelihood",
              "AUTOCOV_ROWS": "core.tracking.likelihood_confidence",
              "MEAT_HALF": "core.tracking.likelihood_confidence",
              "BOX_CORNERS": "core.tracking.roi",
              "BUFFERS_PER_SIZE": "core.tracking.likelihood_launches",
              "SANDWICH_AFTER_STEP": "core.tracking.final_stage"}


@contextmanager
def _jitter(eps: float):
    import core.tracking.engine_likelihood as el

    plain = el.LikelihoodEngine.refine_steps

    def shifted(self, x0=None, **kw):
        return plain(self, np.full(6, float(eps)) if x0 is None else x0, **kw)

    with _patched(el.LikelihoodEngine, "refine_steps", shifted):
        yield


def _variant(name: str):
    """The context of variant ``name`` (``"a+b"``: both of :data:`VARIANTS`'s, in that order)."""
    st = ExitStack()
    for part in name.split("+"):
        num = _numbered(part)
        if num is not None:
            for module, flag in _NUMBERED[num[0]]:
                st.enter_context(_flag(module, flag, num[1]))
        else:
            st.enter_context(VARIANTS[part]())
    return st


#: variants with a number: ``stop<c>`` (engine_likelihood.STOP_PRED = c), ``sc<n>`` (the sandwich's
#: pixels a block, both kernels: likelihood_confidence.MEAT_CHUNK and AUTOCOV_CHUNK), ``meat<n>`` (its
#: meat kernel's alone), ``mc<n>`` (the moments': engine_likelihood.MOMENTS_CHUNK), ``stride<n>`` (the
#: sandwich over the pixels of a sub-lattice: likelihood_confidence.SANDWICH_STRIDE)
_NUMBERED = {"stop": (("core.tracking.engine_likelihood", "STOP_PRED"),),
             "sc": (("core.tracking.likelihood_confidence", "MEAT_CHUNK"),
                    ("core.tracking.likelihood_confidence", "AUTOCOV_CHUNK")),
             "meat": (("core.tracking.likelihood_confidence", "MEAT_CHUNK"),),
             "mc": (("core.tracking.engine_likelihood", "MOMENTS_CHUNK"),),
             "ol": (("core.tracking.final_stage", "REGION_OUTLINE"),),
             "stride": (("core.tracking.likelihood_confidence", "SANDWICH_STRIDE"),)}


def _numbered(part: str):
    """``(prefix, value)`` of a numbered variant (:data:`_NUMBERED`), or None."""
    if part in VARIANTS:
        return None
    for pre in _NUMBERED:
        if part.startswith(pre):
            try:
                x = (float if pre in ("stop", "ol") else int)(part[len(pre):])
            except ValueError:
                return None
            return (pre, x) if x >= 0 else None
    return None


def _known(part: str) -> bool:
    """Whether ``part`` names a variant (:data:`VARIANTS`, or a numbered one: :data:`_NUMBERED`)."""
    return part in VARIANTS or _numbered(part) is not None


@contextmanager
def _flags(**kw):
    with ExitStack() as st:
        for k, v in kw.items():
            st.enter_context(_flag(_FLAG_HOME[k], k, v))
        yield


@contextmanager
def _patched(obj, name: str, new):
    old = getattr(obj, name)
    setattr(obj, name, new)
    try:
        yield
    finally:
        setattr(obj, name, old)


def _kernel_profile(n_bone_frames_box: list, acc: dict):
    """A wrapper of :func:`~core.tracking.final_stage.final_stages` that times the device's
    activities inside it (``acc`` name -> [ms, count]; ``n_bone_frames_box[0]`` counts the bones
    whose stage ran, ``[1]`` the wall time in s)."""
    import warp as wp

    import core.tracking.final_stage as fst

    plain = fst.final_stages

    def wrapped(renderer, frame, calls):
        wp.timing_begin(cuda_filter=wp.TIMING_ALL)
        t = time.perf_counter()
        try:
            return plain(renderer, frame, calls)
        finally:
            res = wp.timing_end()
            n_bone_frames_box[1] += time.perf_counter() - t
            # (the joint rounds before the last call it too, without a stage: options.final None)
            n_bone_frames_box[0] += sum(kw["options"].final is not None for _, kw in calls)
            for x in res:
                a = acc.setdefault(x.name, [0.0, 0])
                a[0] += x.elapsed
                a[1] += 1

    return _patched(fst, "final_stages", wrapped)


def _host_profile(box: list, prof):
    """A wrapper of :func:`~core.tracking.final_stage.final_stages` run under ``prof`` (a
    :class:`cProfile.Profile`: the stages' host work, their waits for the device inside the C
    functions that wait); ``box[0]`` counts the bones whose stage ran."""
    import core.tracking.final_stage as fst

    plain = fst.final_stages

    def wrapped(renderer, frame, calls):
        prof.enable()
        try:
            return plain(renderer, frame, calls)
        finally:
            prof.disable()
            box[0] += sum(kw["options"].final is not None for _, kw in calls)

    return _patched(fst, "final_stages", wrapped)


def _host_table(prof, n: int, top: int = 30) -> dict:
    """The functions of ``prof`` with the most own time and the most time inside them (ms and calls
    per bone-frame over ``n`` bone-frames)."""
    import pstats

    st = pstats.Stats(prof).stats  # (file, line, name) -> (calls, primitive calls, tottime, cumtime, callers)

    def row(k, v):
        return {"function": f"{k[0].rsplit('/', 1)[-1]}:{k[1]}({k[2]})", "calls": v[1] / n,
                "own_ms": 1e3 * v[2] / n, "inside_ms": 1e3 * v[3] / n}

    items = list(st.items())
    return {"own": [row(k, v) for k, v in sorted(items, key=lambda kv: -kv[1][2])[:top]],
            "inside": [row(k, v) for k, v in sorted(items, key=lambda kv: -kv[1][3])[:top]]}


#: (robust_scale: the stage's default robust round, robust_weights and scale_weights as one recorded piece;
#: it calls those two where the weights are counted, their time then inside its own)
_PARTS = ("set_frame", "set_tissue", "step_launch", "step_result", "robust_weights", "sandwich_launch",
          "sandwich_result", "scale_weights", "robust_scale", "reset_weights")


def _parts_profile(acc: dict):
    """The engine's methods (:data:`_PARTS`) and :func:`~core.tracking.engine_likelihood.solve_moments`
    each timed with a synchronisation before and after (``acc`` name -> [s, count])."""
    import warp as wp

    import core.tracking.engine_likelihood as el

    stack = ExitStack()

    def timed(name, f):
        def g(*a, **k):
            wp.synchronize()
            t = time.perf_counter()
            try:
                return f(*a, **k)
            finally:
                wp.synchronize()
                x = acc.setdefault(name, [0.0, 0])
                x[0] += time.perf_counter() - t
                x[1] += 1
        return g

    E = el.LikelihoodEngine
    for name in _PARTS:
        stack.enter_context(_patched(E, name, timed(name, getattr(E, name))))
    stack.enter_context(_patched(el, "solve_moments", timed("solve_moments (host)", el.solve_moments)))
    return stack


def _pose_diff(a: dict, b: dict) -> dict:
    """The largest difference between two runs' poses (mm of the translation, degrees of the
    rotation), over their common bone-frames."""
    from core.geometry.transforms import matrix_to_rotvec

    mm, deg, ent = 0.0, 0.0, 0.0
    for k in a.keys() & b.keys():
        mm = max(mm, float(np.linalg.norm(a[k][:3, 3] - b[k][:3, 3])))
        deg = max(deg, float(np.degrees(np.linalg.norm(matrix_to_rotvec(a[k][:3, :3] @ b[k][:3, :3].T)))))
        ent = max(ent, float(np.max(np.abs(a[k] - b[k]))))
    return {"max_mm": mm, "max_deg": deg, "max_entry": ent}


def _run_diff(a: tuple, b: tuple) -> dict:
    """Two runs (poses, confidences by bone-frame) against each other: :func:`_pose_diff`, the
    largest relative difference of the confidences' σ (``sigma_max_rel``) and whether poses and
    σ are equal to the bit (``identical``)."""
    d = _pose_diff(a[0], b[0])
    rel, same = 0.0, all(np.array_equal(a[0][k], b[0][k]) for k in a[0].keys() & b[0].keys())
    for k in a[1].keys() & b[1].keys():
        sa = np.asarray((a[1][k] or {}).get("sigma") or [], float)
        sb = np.asarray((b[1][k] or {}).get("sigma") or [], float)
        if sa.shape != sb.shape:
            same, rel = False, np.inf
            continue
        same = same and np.array_equal(sa, sb, equal_nan=True)
        ok = np.isfinite(sa) & np.isfinite(sb) & (sa > 0)
        if ok.any():
            rel = max(rel, float(np.max(np.abs(sb[ok] - sa[ok]) / sa[ok])))
    return {**d, "sigma_max_rel": rel, "identical": bool(same)}


@contextmanager
def _frame_cache(folder):
    """The trial's frames kept in ``folder`` (``.npy``, by size, length and frame) and taken from
    there when present (processes measuring different trees on the same frames)."""
    if not folder:
        yield
        return
    import pathlib

    from core.studies.tracking import acceptance as A

    plain = A.TrackingScene.frames

    def frames(self, i):
        if i not in self._cache:
            f = pathlib.Path(folder) / f"{self.scene.rig[0].width}_{self.scene.n_frames}_{i}.npy"
            if f.exists():
                self._cache[i] = list(np.load(f))
            else:
                v = plain(self, i)
                f.parent.mkdir(parents=True, exist_ok=True)
                np.save(f, np.stack(v))
                return v
        return self._cache[i]

    with _patched(A.TrackingScene, "frames", frames):
        yield


def run(*, device: str | None = None, frames: int = 40, pixels: int = 1024, voxel: float = 0.5,
        highpass=(4.0, 8.0), variants=("base",), repeats: int = 2, profile_frames: int = 20,
        correction: str = "grid", glare: bool = True, warm_frames: int = 3, checkpoint=None,
        frame_cache=None, poses_out=None, host_profile: bool = False) -> dict:
    """Run the study (module docs); returns the JSON-ready results. ``frame_cache``: a folder the
    frames are kept in (:func:`_frame_cache`); ``poses_out``: an ``.npz`` file every run's poses
    are written to (``<variant>/hp<σ>/<bone>``: ``(frames, 4, 4)``, the first repeat's)."""
    with _frame_cache(frame_cache):
        return _run(device=device, frames=frames, pixels=pixels, voxel=voxel, highpass=highpass,
                    variants=variants, repeats=repeats, profile_frames=profile_frames, correction=correction,
                    glare=glare, warm_frames=warm_frames, checkpoint=checkpoint, poses_out=poses_out,
                    host_profile=host_profile)


def _run(*, device, frames, pixels, voxel, highpass, variants, repeats, profile_frames, correction, glare,
         warm_frames, checkpoint, poses_out, host_profile=False) -> dict:
    import core.tracking.final_stage as fst
    from core.render import DRRRenderer
    from core.studies.tracking.ml_cost import _scene
    from core.studies.tracking.tissue_stage import _record
    from core.tracking.trial import TrackingOptions, track

    n = int(frames)
    t0 = time.perf_counter()
    ts, out, bound = _scene(n, pixels, voxel, device, 0,
                            {"study": "core.studies.tracking.stage_speed", "highpass_px": list(highpass),
                             "variants": list(variants), "repeats": repeats, "correction": correction,
                             "glare_undone": glare, "stage_model": fst.MODEL.to_dict()},
                            glare=glare, correction=correction)
    out["setup_s"] = time.perf_counter() - t0
    print(f"scene: {out['setup_s']:.1f} s", flush=True)
    bones = [0, 1, 2]
    models = [ts.models[b] for b in bones]
    names = [ts.names[b] for b in bones]
    r = DRRRenderer(ts.scene.rig, [m.volume.to_attenuation(ts.scene.bone_transfer) for m in models],
                    device=ts.device)
    kf = {m.name: {0: ts.truth(0)[b]} for m, b in zip(models, bones, strict=True)}
    base = TrackingOptions(mode="joint")
    plain = replace(base, registration=replace(base.registration, search="newton"))
    opts = {hp: replace(plain, registration=replace(plain.registration, final_highpass_px=float(hp)),
                        refine_likelihood=True) for hp in highpass}
    for v in variants:  # warm-up: kernels compiled, buffers made
        for hp in highpass:
            with _variant(v):
                track(r, models, ts.frames, range(min(n, warm_frames)), keyframes=kf, options=opts[hp])
        print(f"warm-up {v}: {time.perf_counter() - t0:.1f} s", flush=True)
    runs: dict = defaultdict(list)
    poses: dict = {}
    confs: dict = {}
    for rep in range(int(repeats)):
        order = list(variants) if rep % 2 == 0 else list(variants)[::-1]
        for v in order:
            for hp in highpass:
                ends: dict = {}

                def progress(done, total, fr, ends=ends):
                    ends[fr.frame] = time.perf_counter()

                with _variant(v):
                    t1 = time.perf_counter()
                    res = track(r, models, ts.frames, range(n), keyframes=kf, options=opts[hp],
                                progress=progress)
                    dt = time.perf_counter() - t1
                d = _record(ts, res, names, n, dt, ends, bound)
                d["likelihood_renders_per_bone_frame"] = float(np.mean(
                    [(res.results[(nm, f)].timing or {}).get("likelihood_renders", 0)  # (as steps: 0 without)
                     for nm in names for f in range(n)]))
                for nm in names:
                    d[nm].pop("error", None)
                d["repeat"] = rep
                runs[f"{v}/hp{hp:g}"].append(d)
                poses.setdefault(f"{v}/hp{hp:g}", {(nm, f): res.results[(nm, f)].pose
                                                   for nm in names for f in range(n)})
                confs.setdefault(f"{v}/hp{hp:g}", {(nm, f): res.results[(nm, f)].confidence
                                                   for nm in names for f in range(n)})
                ob = {nm: d[nm].get("over_bound", {}) for nm in names}
                print(f"{v} hp{hp:g} rep {rep}: {dt:.2f} s, stage {d['likelihood_ms_per_bone_frame']:.2f} ms "
                      f"per bone-frame ({d['likelihood_steps_per_bone_frame']:.2f} steps) " + " ".join(
                          f"{nm} {ob[nm].get('mm', np.nan):.3f}/{ob[nm].get('deg', np.nan):.3f}"
                          for nm in names),
                      flush=True)
                out["runs"] = runs
                if checkpoint:
                    checkpoint(out)
    out["summary"] = {k: {"likelihood_ms_per_bone_frame": [x["likelihood_ms_per_bone_frame"] for x in v],
                          "median_ms": float(np.median([x["likelihood_ms_per_bone_frame"] for x in v])),
                          "ms_per_frame": [x["ms_per_frame"] for x in v],
                          "steps": v[0]["likelihood_steps_per_bone_frame"],
                          "over_bound": {nm: v[0][nm].get("over_bound") for nm in names}}
                      for k, v in runs.items()}
    if poses_out:
        np.savez(poses_out, **{f"{k}/{nm}": np.stack([p[(nm, f)] for f in range(n)])
                               for k, p in poses.items() for nm in names})
    first = variants[0]
    out["pose_difference_from_" + first] = {k: _pose_diff(poses[f"{first}/hp{k.split('/hp')[1]}"], p)
                                            for k, p in poses.items() if not k.startswith(first + "/")}
    # every pair of variants at each σ: poses, confidences' σ, equal to the bit or not (first repeats)
    out["variant_pairs"] = {f"{a}~{b}/hp{hp:g}": _run_diff((poses[f"{a}/hp{hp:g}"], confs[f"{a}/hp{hp:g}"]),
                                                         (poses[f"{b}/hp{hp:g}"], confs[f"{b}/hp{hp:g}"]))
                            for i, a in enumerate(variants) for b in variants[i + 1:] for hp in highpass}
    for k, x in out["variant_pairs"].items():
        print(f"{k}: {'identical' if x['identical'] else 'differ'}; poses {x['max_mm']:.2g} mm "
              f"{x['max_deg']:.2g} deg, sigma {x['sigma_max_rel']:.2g} relative", flush=True)
    if profile_frames:
        prof: dict = {}
        m = min(n, int(profile_frames))
        for v in variants:
            for hp in highpass:
                acc: dict = {}
                box = [0, 0.0]
                with _variant(v), _kernel_profile(box, acc):
                    track(r, models, ts.frames, range(m), keyframes=kf, options=opts[hp])
                nb = max(box[0], 1)
                kern = {k: {"ms_per_bone_frame": a[0] / nb, "per_bone_frame": a[1] / nb}
                        for k, a in sorted(acc.items(), key=lambda kv: -kv[1][0])}
                parts: dict = {}
                with _variant(v), _parts_profile(parts):
                    res = track(r, models, ts.frames, range(m), keyframes=kf, options=opts[hp])
                tim = [res.results[(nm, f)].timing or {} for nm in names for f in range(m)]
                nbf = len(tim)
                host = None
                if host_profile:
                    import cProfile

                    hp_box, cp = [0], cProfile.Profile()
                    with _variant(v), _host_profile(hp_box, cp):
                        track(r, models, ts.frames, range(m), keyframes=kf, options=opts[hp])
                    host = _host_table(cp, max(hp_box[0], 1))
                prof[f"{v}/hp{hp:g}"] = {
                    "bone_frames": box[0],
                    "stage_wall_ms_per_bone_frame": 1e3 * box[1] / nb,
                    "device_ms_per_bone_frame": sum(a[0] for a in acc.values()) / nb,
                    "kernels": kern,
                    "serial_parts": {k: {"ms_per_bone_frame": 1e3 * a[0] / nbf, "per_bone_frame": a[1] / nbf}
                                     for k, a in sorted(parts.items(), key=lambda kv: -kv[1][0])},
                    "serial_stage_ms_per_bone_frame": 1e3 * float(np.mean([t.get("likelihood_s", 0.0)
                                                                             for t in tim])),
                    **({"host": host} if host is not None else {}),
                }
                pr = prof[f"{v}/hp{hp:g}"]
                print(f"profile {v} hp{hp:g}: wall {pr['stage_wall_ms_per_bone_frame']:.2f}"
                      f" device {pr['device_ms_per_bone_frame']:.2f} ms per bone-frame; "
                      + ", ".join(f"{k} {a['ms_per_bone_frame']:.3f}" for k, a in list(kern.items())[:8]),
                      flush=True)
                out["profile"] = prof
                if checkpoint:
                    checkpoint(out)
    import core.tracking.likelihood_graph as lg

    out["step_graph_capture_failed"] = lg.FAILED  # (None: every capture the device was asked for made)
    out["total_s"] = time.perf_counter() - t0
    return out


def main(argv=None) -> int:
    import json
    import pathlib

    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.stage_speed",
                                description=__doc__.split("\n")[0])
    p.add_argument("--device", default=None)
    p.add_argument("--frames", type=int, default=40)
    p.add_argument("--pixels", type=int, default=1024)
    p.add_argument("--voxel", type=float, default=0.5)
    p.add_argument("--highpass", default="4,8", help="high-pass σ values, comma-separated (pixels)")
    p.add_argument("--variants", default="base", help=f"comma-separated, of {sorted(VARIANTS)}")
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--profile-frames", type=int, default=20)
    p.add_argument("--warm-frames", type=int, default=3)
    p.add_argument("--correction", default="grid", choices=("grid", "model"))
    p.add_argument("--out", default=None)
    p.add_argument("--frame-cache", default=None, help="a folder the trial's frames are kept in")
    p.add_argument("--poses-out", default=None, help="an .npz file for every run's poses")
    p.add_argument("--host-profile", action="store_true",
                   help="also profile the stages' host work (cProfile) over the profile frames")
    a = p.parse_args(argv)
    variants = tuple(a.variants.split(","))
    for v in variants:
        if not all(_known(x) for x in v.split("+")):
            p.error(f"--variants: {v!r} is not one of {sorted(VARIANTS)} or stop<c>")

    def save(d):
        if a.out:
            pathlib.Path(a.out).write_text(json.dumps(d, indent=1, default=float))

    out = run(device=a.device, frames=a.frames, pixels=a.pixels, voxel=a.voxel,
              highpass=tuple(float(x) for x in a.highpass.split(",")), variants=variants, repeats=a.repeats,
              profile_frames=a.profile_frames, correction=a.correction, warm_frames=a.warm_frames,
              checkpoint=save, frame_cache=a.frame_cache, poses_out=a.poses_out, host_profile=a.host_profile)
    save(out)
    print(json.dumps({k: v for k, v in out.items() if k not in ("runs",)}, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
