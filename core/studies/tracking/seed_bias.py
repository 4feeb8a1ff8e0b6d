"""Where the held-out seed 4's runs of biased frames come from
(``python -m core.studies.tracking.seed_bias``).

On the held-out synthesis of the acceptance trial with scene seed 4 (one NVIDIA H100, 1024², both
modes; ``resources/benchmarks/tracking_acceptance_seed4_h100.json``) the tracker holds the talus
off about x over frames 0-20 and the tibia about z over frames 75-93, runs of frames biased
together that the trajectory check does not single out. This study takes such frames of the same
scene (:class:`~core.studies.tracking.acceptance.TrackingScene` with ``seed``, the grid
correction, at a CPU's size) and asks where the bias comes from, with the tracker's registration
(:func:`core.tracking.register.register` with the acceptance study's joint options: its search,
without the opt-in likelihood final stage, as the held-out run tracked) run for one bone at a time,
the other bones at their true poses:

* ``noise_free`` — from the true pose on the frame made without quantum or read noise, the other
  bones subtracted as joint tracking does: the cost's own optimum. Off by the run's bias: the
  cost, not the search, sets it;
* ``noisy`` — the same on the trial's own noisy frame (the run's noise draw): what noise adds;
* ``alone`` — the noisy frame made without the other bones (their line integrals taken out before
  the image chain): what the neighbours and their subtraction add; ``noise_free_alone`` the same
  without noise;
* ``from_run`` (with ``--stored``) — from the stored run's pose at that frame (the truth moved by
  its per-frame error) on the noisy frame: back to ``noisy``'s optimum, the optimum is unique and
  the search is not at fault; staying, the cost is flat there; ``noise_free_from_run`` the same on
  the noise-free frame;
* ``undistorted`` — the noise-free frame made without the intensifier's distortion (so none to
  undo: the correction's residual out), inside the round field; ``open_field`` — the same without
  the round field (signal out to the image's corners): what the field's rim adds; ``sharp`` —
  undistorted and without the point-spread function, the glare and the edge roll-off;
  ``bones_only`` — undistorted, of the bones' line integrals only (no soft tissue, no walkway);
  ``sharp_bones_only`` both: the frame as the tracker's model renders it, noise-free;
* ``rim`` — where the bone lies in each view's round field: the largest radius of its projected
  surface points over the field's radius, and the share of them beyond 0.9 of it.

Every error is the registration's against the truth (mm, degrees about lab axes through the
bone's centroid), with the stored run's error at the same frame beside it (``run``) and the
Cramér–Rao bound of the frames at this size.

Measured (this 2-core x86_64 machine, shared; 512², 1 mm voxels, the synthesis that keeps bones
apart, against the re-run at 1024² on one NVIDIA H100; one registration per bone-frame and
condition; ``resources/benchmarks/tracking_seed_bias_cpu.json``), mean over the stretch's frames
(talus 0, 5, 10, 15, 20 about x; tibia 75, 80, 85, 90, 93 about z) and the controls (talus 50, 60;
tibia 40, 50):

* not the search — from the run's pose the registration ends where it ends from the truth:
  noise-free talus +0.52° against +0.51°, tibia −0.64° against −0.55°; noisy +0.90° / +0.84°,
  −0.62° / −0.56°;
* the cost — noise-free, from the truth, the tibia is −0.46° to −0.65° off over 75–93 (controls
  −0.20°, −0.04°), the talus +0.29° to +0.99° over 0–20, but at this size +0.50°, +0.48° at its
  controls too (the 1024² run: +0.43° against +0.30°);
* not the field's rim (without the round field the tibia's −0.470° is the undistorted frame's
  −0.471°), a little the distortion correction (undistorted: tibia −0.47°, talus +0.47°);
* the other bones: not for the tibia (frames without them −0.72°); for the talus over frames 0–10
  (without them −0.20° to +0.06°; controls unchanged);
* the soft tissue and walkway, which the tracker's model does not render: frames of the bones
  alone through the same blur, glare and roll-off leave talus +0.04° to +0.10°, tibia +0.03° to
  +0.06° (controls ~0); without the blur too — the model's own frame — 0.000°; with tissue and
  walkway but no blur, talus +0.73° (controls +0.44°), tibia −0.36° (controls −0.09°).

So the runs of biased frames are the cost's, set by the unmodelled tissue and walkway (the blur
adding to it, and for the talus its neighbours at heel strike); why these poses more than others
was not measured. The interpenetrating truth was not their cause (the re-run at 1024²). At the
run's 0.5 mm voxels (512², frames 10 / 50 and 85 / 50) the pattern holds, smaller: noise-free
talus +0.61° / +0.29°, tibia −0.29° / −0.02°; bones only through the blur +0.08° / −0.03° and
+0.03° / 0.00°. Single noise draws.

``--stage`` (:func:`stage_run`): the likelihood final stage after that registration (from its
result, the other bones subtracted at their true poses) in the variants of
:data:`STAGE_VARIANTS` — those :mod:`core.studies.tracking.tissue_tibia`'s labels name: the default
4 px high-pass, 8 px, 8 px with the 2 mm tissue regressor (``user_tissue("fine")`` through the
estimated PSF), that with the band at the round field's rim, 4 px with the 2 mm tissue; σ in
pixels at 1024², scaled to the scene's size. Measured (this 2-core x86_64 machine, shared; 512²,
1 mm voxels; talus 0, 10, 20 against 50, 60, tibia 75, 85, 93 against 40, 50;
``resources/benchmarks/tracking_seed_bias_stage_cpu.json``), noise-free, mean over the stretch
(controls), talus about x / tibia about z: the similarity's optimum +0.62° (+0.49°) / −0.58°
(−0.12°); the stage at 4 px +0.14° (+0.05°) / +0.01° (+0.05°); 8 px +0.18° (+0.19°) / −0.01°
(+0.10°); 8 px with the 2 mm tissue +0.16° (+0.06°) / −0.02° (−0.04°); with the rim band +0.16°
(+0.06°) / +0.00° (−0.01°); 4 px with the tissue +0.12° (+0.04°) / −0.00° (+0.02°). The stage, not
its tissue regressor, takes the bias off: all of the tibia's, the talus's but ~0.1° over its
controls; the regressor adds 0.01–0.02°, the rim band nothing for the talus. On two noise
draws (the run's and another) the same: talus +0.93° → +0.25° at 4 px, tibia −0.74° → −0.06°.
Tracking the whole held-out trial with the stage (``acceptance --seed 4 --final likelihood``, 1024²,
0.5 mm voxels, one NVIDIA H100; ``tracking_acceptance_seed4_final_h100.json``) confirmed it: jointly
the talus about x over frames 0–20 +0.43° → +0.14°, the tibia about z over 75–93 −0.47° → −0.10°.
"""

from __future__ import annotations

import argparse
import json
import platform
import time

import numpy as np

__all__ = ["field_rim", "main", "run", "stage_run", "stage_summary"]

#: Frames per bone (module docs): seed 4's runs of biased frames and two unbiased controls.
DEFAULT_FRAMES = {"talus": (0, 5, 10, 15, 20, 50, 60), "tibia": (75, 80, 85, 90, 93, 40, 50)}
CONDITIONS = ("noise_free", "noise_free_from_run", "noisy", "from_run", "alone", "noise_free_alone",
              "undistorted", "open_field", "sharp", "bones_only", "sharp_bones_only")


def field_rim(ts, f: int, b: int, max_points: int = 1500) -> list[dict]:
    """Per view: the largest radius of bone ``b``'s projected surface points at frame ``f`` over
    the round field's radius (distortion scale), and the share of them beyond 0.9 of it."""
    from core.studies.tracking.acceptance import surface_points

    P = surface_points(ts.models[b], max_points)
    T = ts.truth(f)[b]
    X = P @ T[:3, :3].T + T[:3, 3]
    out = []
    for cam, m in zip(ts.scene.rig, ts.scene.imaging, strict=True):
        uv = cam.project(X)
        r = np.hypot(uv[:, 0] - m.distortion.center[0], uv[:, 1] - m.distortion.center[1])
        r = r / float(m.distortion.scale_px)
        out.append({"max_r": round(float(r.max()), 3), "beyond_0.9": round(float(np.mean(r > 0.9)), 3)})
    return out


def _without(ts, f: int, L: np.ndarray, b: int) -> np.ndarray:
    """Line integrals ``L`` of frame ``f`` with the bones other than ``b`` taken out."""
    R = ts._scene_renderer._bones.render(ts.truth(f)[None], roi="full").numpy()[0]  # (views, bones, H, W)
    keep = [k for k in range(len(ts.names)) if k != b]
    return (L - R[:, keep].sum(axis=1)).astype(L.dtype)


def _bones_only(ts, f: int) -> np.ndarray:
    """Frame ``f``'s line integrals of the bones alone (no soft tissue, no walkway)."""
    R = ts._scene_renderer._bones.render(ts.truth(f)[None], roi="full").numpy()[0]
    return R.sum(axis=1).astype(np.float64)


def _chain(ts, f: int, L: np.ndarray, noise: bool, field: str = "trial") -> list[np.ndarray]:
    """The frame through the trial's image chain (noise: the run's draw) and the trial's correction;
    ``field`` ``"undistorted"``: without the distortion (and no correction), ``"open"``: nor the
    round field, ``"sharp"``: undistorted, without the blur, the glare and the roll-off."""
    from dataclasses import replace

    out = []
    for v, m in enumerate(ts.scene.imaging):
        if not noise:
            m = replace(m, photons_per_pixel=None, read_noise_dn=0.0)
        if field != "trial":
            m = replace(m, distortion=None, aperture_radius=None if field == "open" else m.aperture_radius)
        if field == "sharp":
            m = replace(m, psf_sigma_px=0.0, psf_kernel=None, glare_fraction=0.0, rolloff_edge=1.0)
        raw = m.apply(L[v], rng=ts.scene.frame_rng(f, v) if noise else None)
        out.append(ts.correct(v, raw) if field == "trial" else m.to_float(raw).astype(np.float32))
    return out


def _register_from(ts, frame, f: int, b: int, start: np.ndarray | None, others: bool) -> np.ndarray:
    """Bone ``b`` registered in ``frame`` from ``start`` (None: the truth) as the acceptance study's
    joint tracking registers it (:func:`core.tracking.register.register`: its search, then the final
    likelihood stage), the other bones at their true poses and subtracted (``others``); its error
    against the truth (mm, degrees)."""
    from core.studies.tracking.acceptance import pose_errors, study_options
    from core.tracking.register import register

    P = ts.truth(f)
    m = ts.models[b]
    oth = [k for k in range(len(ts.names)) if k != b] if others else []
    res = register(ts.renderer, frame, bone=b, initial_pose=P[b] if start is None else start,
                   center=m.centroid, options=study_options("joint").registration,
                   others=(P[oth], oth) if oth else None)
    return pose_errors(res.pose, P[b], m.centroid)


def _stored_errors(path: str | None, mode: str, n_frames: int | None = None) -> dict:
    """``{bone: {frame: (6,) error}}`` of a stored acceptance run (``mode``'s where it has runs per
    mode), by frame number (``frames_with_pose``: a frame without a pose has no error, so the
    errors' positions are not their frames; without it, frames ``0..n-1`` where all ``n`` of the
    run's ``config.frames``, else ``n_frames``, have one)."""
    from core.studies.tracking.acceptance_goals import _by_frame

    if not path:
        return {}
    with open(path) as fh:
        d = json.load(fh)
    r = d["runs"][mode] if "runs" in d else d
    n = r.get("config", {}).get("frames", n_frames)
    out = {}
    for nm, tb in r["tracking"].items():
        e = _by_frame(tb, n)
        if e is None:
            raise ValueError(f"{path}: {nm}'s per-frame errors name no frames (frames_with_pose)")
        out[nm] = e
    return out


def run(*, seed: int = 4, pixels: int = 256, voxel: float = 1.0, frames=None, conditions=CONDITIONS,
        stored: str | None = None, mode: str = "joint", device: str | None = "cpu", correction: str = "grid",
        n_frames: int = 100, ts=None, checkpoint=None) -> dict:
    """The study (module docs); ``frames``: ``{bone: frames}`` (default :data:`DEFAULT_FRAMES`);
    ``ts``: the scene, made already (else from ``seed``, ``pixels``, ``voxel``, ``correction``,
    ``n_frames``)."""
    from core.geometry.transforms import pose_from_params
    from core.studies.tracking.acceptance import TrackingScene, cramer_rao
    from core.tracking.cost import prepare_frame

    t0 = time.perf_counter()
    frames = {k: tuple(int(f) for f in v) for k, v in (frames or DEFAULT_FRAMES).items()}
    if ts is None:
        ts = TrackingScene(n_frames=n_frames, pixels=pixels, spacing=voxel, seed=seed, device=device,
                           correction=correction, phase=(0.0, 0.6 * n_frames / 100.0))
    run_err = _stored_errors(stored, mode, ts.scene.n_frames)
    all_frames = sorted({f for v in frames.values() for f in v})
    bound = cramer_rao(ts, all_frames[::3])
    out = {"study": "core.studies.tracking.seed_bias", "machine": platform.machine(), "seed": seed,
           "pixels": pixels, "voxel_mm": voxel, "frames": {k: list(v) for k, v in frames.items()},
           "stored": stored, "mode": mode,
           "cramer_rao": {k: {"rms_mm": v["rms_mm"], "rms_deg": v["rms_deg"]} for k, v in bound.items()},
           "setup_s": time.perf_counter() - t0, "rows": []}
    for nm, fs in frames.items():
        b = ts.names.index(nm)
        for f in fs:
            L = ts.scene.line_integrals(f, renderer=ts._scene_renderer)
            row = {"bone": nm, "frame": f, "rim": field_rim(ts, f, b)}
            if f in run_err.get(nm, {}):
                row["run"] = run_err[nm][f].round(4).tolist()
            noisy = None
            for c in conditions:
                t1 = time.perf_counter()
                if c == "noise_free":
                    e = _register_from(ts, prepare_frame(_chain(ts, f, L, False)), f, b, None, True)
                elif c == "noisy":
                    noisy = noisy or prepare_frame(_chain(ts, f, L, True))
                    e = _register_from(ts, noisy, f, b, None, True)
                elif c in ("alone", "noise_free_alone"):
                    e = _register_from(ts, prepare_frame(_chain(ts, f, _without(ts, f, L, b), c == "alone")),
                                       f, b, None, False)
                elif c in ("undistorted", "open_field"):
                    fr = _chain(ts, f, L, False, "undistorted" if c == "undistorted" else "open")
                    e = _register_from(ts, prepare_frame(fr), f, b, None, True)
                elif c in ("sharp", "bones_only", "sharp_bones_only"):
                    Lc = _bones_only(ts, f) if c != "sharp" else L
                    fr = _chain(ts, f, Lc, False, "undistorted" if c == "bones_only" else "sharp")
                    e = _register_from(ts, prepare_frame(fr), f, b, None, True)
                elif c in ("from_run", "noise_free_from_run"):
                    if f not in run_err.get(nm, {}):
                        continue
                    er = run_err[nm][f]
                    start = pose_from_params(np.r_[er[:3], np.radians(er[3:])], center=ts.models[b].centroid,
                                             base=ts.truth(f)[b])
                    if c == "from_run":
                        noisy = noisy or prepare_frame(_chain(ts, f, L, True))
                        e = _register_from(ts, noisy, f, b, start, True)
                    else:
                        e = _register_from(ts, prepare_frame(_chain(ts, f, L, False)), f, b, start, True)
                else:
                    raise ValueError(f"conditions: expected some of {CONDITIONS}, got {c!r}")
                row[c] = np.asarray(e).round(4).tolist()
                row[f"{c}_s"] = round(time.perf_counter() - t1, 1)
            out["rows"].append(row)
            out["seconds"] = time.perf_counter() - t0
            if checkpoint:
                checkpoint(out)
    out["summary"] = summary(out["rows"])
    return out


def summary(rows: list) -> dict:
    """Per bone and condition: the mean error (6,) over the bone's frames and over its frames in
    the run's biased stretch (the first five of :data:`DEFAULT_FRAMES`)."""
    out: dict = {}
    for nm in sorted({r["bone"] for r in rows}):
        mine = [r for r in rows if r["bone"] == nm]
        for c in (*CONDITIONS, "run"):
            E = np.array([r[c] for r in mine if c in r])
            if len(E):
                out.setdefault(nm, {})[c] = {"mean": E.mean(0).round(4).tolist(), "n": len(E)}
    return out


#: The likelihood stage after the registration (:func:`stage_run`): label -> (high-pass σ at 1024²
#: pixels, tissue volume of :func:`~core.studies.tracking.tissue_regressor.user_tissue` or None,
#: the band at the round field's rim in σ or None) — the stage's variants that
#: :mod:`core.studies.tracking.tissue_tibia`'s labels name (``gc``: no stage).
STAGE_VARIANTS = {"gc": None, "hp4": (4.0, None, None), "hp8": (8.0, None, None),
                  "hp8_tissue_fine": (8.0, "fine", None), "hp8_tissue_fine_rim": (8.0, "fine", 3.0),
                  "hp4_tissue_fine": (4.0, "fine", None)}
#: the held-out run's biased stretches (module docs); a bone's other frames are its controls
STRETCH = {"talus": (0, 20), "tibia": (75, 93)}


def _draw(ts, f: int, L: np.ndarray, draw: int) -> list[np.ndarray]:
    """Frame ``f`` through the trial's image chain with noise draw ``draw`` (0: the run's own, as
    :func:`_chain`; others their own generator) and the trial's correction."""
    if draw == 0:
        return _chain(ts, f, L, True)
    return [ts.correct(v, m.apply(L[v], rng=np.random.default_rng([int(ts.scene.seed), 0x5CE4E, f, v, draw])))
            for v, m in enumerate(ts.scene.imaging)]


def stage_run(*, seed: int = 4, pixels: int = 512, voxel: float = 1.0, frames=None, draws=(None, 0),
              variants=tuple(STAGE_VARIANTS), device: str | None = "cpu", correction: str = "grid",
              n_frames: int = 100, ts=None, checkpoint=None) -> dict:
    """Does the likelihood stage, with the tissue regressor, take the bias off? Per bone-frame and
    frame (``draws``: None the noise-free frame, 0 the run's noise draw, k > 0 another), bone ``b``
    registered from the truth as :func:`_register_from` (``gc``: the similarity's optimum), then
    the final likelihood stage from that result per variant of :data:`STAGE_VARIANTS` (high-pass
    scaled from 1024² to ``pixels``; the model's other settings the default
    :data:`core.tracking.final_stage.MODEL`'s), the other bones at their true poses and subtracted;
    errors (mm, degrees) against the truth and whether the stage's move was taken."""
    from dataclasses import replace

    import core.tracking.final_stage as fst
    from core.studies.tracking.acceptance import TrackingScene, pose_errors, study_options
    from core.studies.tracking.tissue_stage import tissue_model
    from core.tracking.cost import prepare_frame
    from core.tracking.register import register

    t0 = time.perf_counter()
    frames = {k: tuple(int(f) for f in v) for k, v in (frames or DEFAULT_FRAMES).items()}
    if ts is None:
        ts = TrackingScene(n_frames=n_frames, pixels=pixels, spacing=voxel, seed=seed, device=device,
                           correction=correction, phase=(0.0, 0.6 * n_frames / 100.0))
    px = int(ts.scene.rig[0].width)  # (the scene given: its size)
    o = study_options("joint").registration
    models, opts = {}, {}
    kinds = {STAGE_VARIANTS[v][1] for v in variants if STAGE_VARIANTS[v] and STAGE_VARIANTS[v][1]}
    tissues = {k: tissue_model(ts, kind=k, base=fst.MODEL) for k in kinds}
    for v in variants:
        if STAGE_VARIANTS[v] is None:
            continue
        hp, kind, rim = STAGE_VARIANTS[v]
        m = tissues[kind] if kind else fst.MODEL
        models[v] = replace(m, rim_sigmas=rim) if rim else m
        opts[v] = replace(o, final="likelihood", final_highpass_px=hp * px / 1024)
    out = {"study": "core.studies.tracking.seed_bias --stage", "machine": platform.machine(), "seed": seed,
           "pixels": px, "voxel_mm": voxel, "frames": {k: list(v) for k, v in frames.items()},
           "draws": [d for d in draws], "variants": {v: STAGE_VARIANTS[v] for v in variants},
           "highpass_px": {v: oo.final_highpass_px for v, oo in opts.items()},
           "models": {v: m.to_dict() for v, m in models.items()}, "setup_s": time.perf_counter() - t0,
           "rows": []}
    for nm, fs in frames.items():
        b = ts.names.index(nm)
        m = ts.models[b]
        oth = [k for k in range(len(ts.names)) if k != b]
        for f in fs:
            L = ts.scene.line_integrals(f, renderer=ts._scene_renderer)
            P = ts.truth(f)
            kw = {"bone": b, "initial_pose": P[b], "center": m.centroid, "others": (P[oth], oth)}
            for d in draws:
                t1 = time.perf_counter()
                frame = prepare_frame(_chain(ts, f, L, False) if d is None else _draw(ts, f, L, d))
                res = register(ts.renderer, frame, options=o, **kw)
                e = pose_errors(res.pose, P[b], m.centroid)
                row = {"bone": nm, "frame": f, "draw": d, "gc": np.asarray(e).round(4).tolist()}
                for v, oo in opts.items():
                    with fst.final_model(models[v]):
                        r = fst.final_stage(ts.renderer, frame, res, options=oo,
                                            views=tuple(range(frame.n_views)), **kw)
                    row[v] = np.asarray(pose_errors(r.pose, P[b], m.centroid)).round(4).tolist()
                    row[f"{v}_taken"] = int(r.timing.get("likelihood_taken", 0))
                row["s"] = round(time.perf_counter() - t1, 1)
                out["rows"].append(row)
                out["seconds"] = time.perf_counter() - t0
                if checkpoint:
                    checkpoint(out)
    out["summary"] = stage_summary(out["rows"], variants)
    return out


def stage_summary(rows: list, variants=tuple(STAGE_VARIANTS)) -> dict:
    """Per bone, frame kind (``noise_free``, ``noisy``: every noise draw) and variant: the mean
    error (6,) over the bone's frames in its biased stretch (:data:`STRETCH`) and over its
    controls, with their frame counts."""
    out: dict = {}
    for r in rows:
        lo, hi = STRETCH.get(r["bone"], (0, -1))
        part = "stretch" if lo <= r["frame"] <= hi else "control"
        kind = "noise_free" if r["draw"] is None else "noisy"
        for v in variants:
            if v in r:
                per = out.setdefault(r["bone"], {}).setdefault(kind, {}).setdefault(v, {})
                per.setdefault(part, []).append(r[v])
    for d in out.values():
        for k in d.values():
            for v in k.values():
                for part, E in v.items():
                    v[part] = {"mean": np.mean(E, axis=0).round(4).tolist(), "n": len(E)}
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.seed_bias",
                                description=__doc__.split("\n")[0])
    p.add_argument("--seed", type=int, default=4)
    p.add_argument("--pixels", type=int, default=256)
    p.add_argument("--voxel", type=float, default=1.0)
    p.add_argument("--talus", default=",".join(map(str, DEFAULT_FRAMES["talus"])))
    p.add_argument("--tibia", default=",".join(map(str, DEFAULT_FRAMES["tibia"])))
    p.add_argument("--conditions", default=",".join(CONDITIONS))
    p.add_argument("--stored", default=None,
                   help="a stored acceptance run of the same seed (its per-frame errors)")
    p.add_argument("--mode", default="joint")
    p.add_argument("--device", default="cpu")
    p.add_argument("--stage", action="store_true", help="the likelihood stage's variants (stage_run)")
    p.add_argument("--variants", default=",".join(STAGE_VARIANTS), help="--stage: of STAGE_VARIANTS")
    p.add_argument("--draws", default="none,0", help="--stage: none (noise-free), 0 (the run's draw), k > 0")
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    from core.io.atomic import json_checkpoint, print_json

    frames = {k: [int(x) for x in v.split(",") if x] for k, v in (("talus", a.talus), ("tibia", a.tibia))}
    frames = {k: v for k, v in frames.items() if v}
    if a.stage:
        res = stage_run(seed=a.seed, pixels=a.pixels, voxel=a.voxel, frames=frames, device=a.device,
                        draws=[None if x == "none" else int(x) for x in a.draws.split(",") if x],
                        variants=tuple(x for x in a.variants.split(",") if x),
                        checkpoint=json_checkpoint(a.out, indent=2))
        print_json(res, a.out)
        return 0
    res = run(seed=a.seed, pixels=a.pixels, voxel=a.voxel, frames=frames, stored=a.stored, mode=a.mode,
              conditions=tuple(c for c in a.conditions.split(",") if c), device=a.device,
              checkpoint=json_checkpoint(a.out, indent=2))
    print_json(res, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
