"""A stored acceptance run's frames not converged for a σ flag, again on this machine
(``python -m core.studies.tracking.stage_sigma_frames``): the final stage's σ from where the search stopped
and from the similarity's optimum (:mod:`core.tracking.stage_sigma`).

Part ``search`` (per ``--frames``, the acceptance scene of the stored run's seed at ``--pixels`` /
``--voxel``): the bone's searched pose in the stored run, rebuilt from its ``search_error``, and its
neighbours at their constant-velocity predictions rebuilt from the stored errors of the two frames before
(the joint stage's neighbours); the final stage from the searched pose (as the run had it), then
:func:`~core.tracking.stage_sigma.remeasured` (the similarity searched on to its own tolerance, the σ's
move from there) and the final stage from that optimum too. Per case the error, the stage's move, σ and
the σ check's verdict (:func:`core.tracking.checks.sigma_check` against the stored run's σ of the bone's
last ten unflagged frames before it, the tracker's rule).

Part ``decompose`` (``--decompose-pixels``, 1 mm voxels): the stage from the truth on the run's noise draw,
noise-free, with the other bones' line integrals taken out, and on each image part
(:func:`core.studies.tracking.stage_limits.component_frames`): where the stage's own optimum lies.

Part ``walking``: the tests' ideal walking talus (128², 1.5 mm, no tissue, frames 0-19 from the true pose,
the Gauss–Newton search and the stage) tracked with :data:`core.tracking.stage_sigma.REMEASURE` off and on:
per frame the error, σ, flags, whether re-measured, evaluations; the frames converged.
"""

from __future__ import annotations

import json
import time
from dataclasses import replace

import numpy as np

from core.studies.tracking import _study_cli as cli

__all__ = ["main", "run"]

STORED = "resources/benchmarks/tracking_acceptance_seed0_final_d262386_h100.json"


def _rebuild(e, truth, center) -> np.ndarray:
    """The pose whose :func:`~core.studies.tracking.acceptance_records.pose_errors` against ``truth``
    is ``e``."""
    from core.geometry.transforms import pose_from_params

    e = np.asarray(e, dtype=float)
    return pose_from_params(np.r_[e[:3], np.radians(e[3:])], center=center, base=truth)


def _recent(t: dict, f: int, n: int = 10) -> list:
    """The stored run's σ lengths (mm, degrees) of the bone's last ``n`` unflagged frames before ``f``."""
    flagged = {int(k) for k in t["flag_reasons"]}
    S = [np.full(6, np.nan) if s is None else np.asarray(s, dtype=float) for s in t["per_frame_sigma"]]
    good = [g for g in range(f) if g not in flagged and np.all(np.isfinite(S[g]))]
    return [(float(np.linalg.norm(S[g][:3])), float(np.linalg.norm(S[g][3:]))) for g in good[-n:]]


def _case(ts, b: int, f: int, r, start, sigmas, o) -> dict:
    """A stage's result ``r`` from ``start``: error, move, σ (the tracker's, options ``o``), the σ check."""
    from core.studies.tracking.acceptance_records import pose_errors
    from core.tracking.attempt import confidence_of
    from core.tracking.checks import sigma_check

    c, P = ts.models[b].centroid, ts.truth(f)[b]
    conf = confidence_of(r.fit, o)
    return {"error": pose_errors(r.pose, P, c).round(4).tolist(),
            "start": pose_errors(start, P, c).round(4).tolist(),
            "move": pose_errors(r.pose, start, c).round(4).tolist(),
            "sigma": np.round(conf["sigma"], 4).tolist(),
            "sigma_mm_deg": [round(conf["translation_mm"], 4), round(conf["rotation_deg"], 4)],
            "flag": (sigma_check(conf, sigmas) or [None])[0], "steps": r.timing.get("likelihood_steps")}


def search_part(ts, stored: dict, mode: str, bone: str, frames) -> list:
    """Part ``search`` (module docs)."""
    from core.studies.tracking.acceptance import study_options
    from core.tracking.cost import prepare_frame
    from core.tracking.final_stage import final_stage
    from core.tracking.frame_state import predict_pose
    from core.tracking.register import register
    from core.tracking.stage_sigma import remeasured

    tr = stored["runs"][mode]["tracking"]
    b = ts.names.index(bone)
    c = ts.models[b].centroid
    oth = [k for k in range(len(ts.names)) if k != b]
    to = study_options(mode, final="likelihood")
    o = to.registration
    rows = []
    for f in frames:
        t0 = time.perf_counter()
        P, fr = ts.truth(f), prepare_frame(ts.frames(f))
        Ps = _rebuild(tr[bone]["per_frame_signals"]["search_error"][f], P[b], c)
        pred = np.stack([predict_pose([(g, _rebuild(tr[ts.names[k]]["per_frame_error"][g], ts.truth(g)[k],
                                                     ts.models[k].centroid)) for g in (f - 2, f - 1)],
                                      f, ts.models[k].centroid) for k in oth])
        others = (pred, oth)
        sigmas = _recent(tr[bone], f)
        # the search's result as the stage got it: a registration from the searched pose, its pose that one
        base = register(ts.renderer, fr, bone=b, initial_pose=Ps, center=c, options=replace(o, final=None),
                        others=others)
        searched = replace(base, pose=Ps)
        staged = final_stage(ts.renderer, fr, searched, bone=b, initial_pose=Ps, center=c, options=o,
                             views=tuple(range(fr.n_views)), others=others)
        t = tr[bone]
        row = {"frame": f, "stored": {"search_error": t["per_frame_signals"]["search_error"][f],
                                      "error": t["per_frame_error"][f], "sigma": t["per_frame_sigma"][f],
                                      "flags": t["flag_reasons"].get(str(f), [])},
               "recent_sigma_median": [round(float(np.median([s[i] for s in sigmas])), 4) for i in (0, 1)],
               "from_searched": _case(ts, b, f, staged, Ps, sigmas, to)}
        got = remeasured(ts.renderer, fr, staged, bone=b, center=c, options=o, others=others)
        if got is not None:
            new, conv = got
            row["remeasured"] = {**_case(ts, b, f, new, conv.pose, sigmas, to),
                                 "search_steps": int(conv.generations)}
            again = final_stage(ts.renderer, fr, conv, bone=b, initial_pose=conv.pose, center=c, options=o,
                                views=tuple(range(fr.n_views)), others=others)
            row["from_optimum"] = _case(ts, b, f, again, conv.pose, sigmas, to)
        row["s"] = round(time.perf_counter() - t0, 1)
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


def decompose_part(seed: int, pixels: int, bone: str, frames) -> list:
    """Part ``decompose`` (module docs)."""
    from core.studies.tracking.acceptance import TrackingScene
    from core.studies.tracking.stage_limits import COMPONENTS, component_frames
    from core.studies.tracking.stage_residue import _frames_of, stage_from
    from core.tracking.cost import prepare_frame

    ts = TrackingScene(n_frames=100, pixels=pixels, spacing=1.0, seed=seed, phase=(0.0, 0.6),
                       correction="grid")
    b = ts.names.index(bone)
    rows = []
    for f in frames:
        P = ts.truth(f)
        row = {"frame": f,
               "run_draw": stage_from(ts, prepare_frame(ts.frames(f)), f, b, P[b], highpass_px=4.0)["error"]}
        for kind in ("noise_free", "alone"):
            row[kind] = stage_from(ts, _frames_of(ts, f, b, kind), f, b, P[b], highpass_px=4.0,
                                   others=kind != "alone")["error"]
        for cfg, imgs in component_frames(ts, f, COMPONENTS).items():
            row[cfg] = stage_from(ts, prepare_frame(imgs), f, b, P[b], highpass_px=4.0)["error"]
        rows.append(row)
        print(json.dumps(row), flush=True)
    return rows


def walking_part(n: int = 20) -> dict:
    """Part ``walking`` (module docs): the ideal 128² walking talus, frames 0 … ``n`` − 1, with the stage,
    :data:`~core.tracking.stage_sigma.REMEASURE` off then on."""
    import core.tracking.stage_sigma as ss
    from core.render import DRRRenderer
    from core.studies.tracking.acceptance_records import pose_errors
    from core.synthetic import make_foot_scene
    from core.tracking.bones import bone_model
    from core.tracking.register import RegistrationOptions
    from core.tracking.trial import TrackingOptions, track

    sc = make_foot_scene(n_frames=60, pixels=128, spacing=1.5, names=("talus",), beads_per_bone=0,
                         soft_tissue=False, imaging="ideal", floor_thickness_mm=0)
    model = bone_model(sc.bones[0], mesh=False)
    r = DRRRenderer(sc.rig, [sc.bones[0].to_attenuation(sc.bone_transfer)], device="cpu")
    cache: dict = {}

    def frames(i):
        if i not in cache:
            out = []
            for m, f in zip(sc.imaging, sc.render_frame(i), strict=True):
                x = m.to_float(f)
                out.append(x if m.distortion is None else m.distortion.unwarp(x))
            cache[i] = out
        return cache[i]

    F = list(range(n))
    keys = {model.name: {0: sc.poses(0)[0]}}
    reg = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")
    o = TrackingOptions(verify_restarts=0, refine_likelihood=True, registration=reg)
    out, plain = {}, ss.REMEASURE
    try:
        for on in (False, True):
            ss.REMEASURE = on
            t0 = time.perf_counter()
            res = track(r, [model], frames, F, keyframes=keys, options=o)
            rows = []
            for f in F:
                fr = res.results[(model.name, f)]
                e = pose_errors(fr.pose, sc.poses(f)[0], model.centroid)
                cf = fr.confidence or {}
                rows.append({"frame": f, "error_mm": round(float(np.linalg.norm(e[:3])), 5),
                             "error_deg": round(float(np.linalg.norm(e[3:])), 5),
                             "sigma_mm_deg": [cf.get("translation_mm"), cf.get("rotation_deg")],
                             "converged": bool(fr.converged), "flags": list(fr.flags),
                             "remeasured": any("similarity's optimum" in x for x in fr.notes),
                             "evaluations": int(fr.evaluations)})
            out["on" if on else "off"] = {"s": round(time.perf_counter() - t0, 1),
                                          "converged": sum(x["converged"] for x in rows), "frames": rows}
    finally:
        ss.REMEASURE = plain
    return out


def run(*, stored: str = STORED, mode: str = "joint", bone: str = "talus", frames=(6, 69), pixels: int = 1024,
        voxel: float = 0.5, parts=("search", "decompose", "walking"), decompose_pixels: int = 512,
        decompose_frames=(69,)) -> dict:
    """The study (module docs); JSON-ready."""
    from core.studies.tracking.acceptance import TrackingScene

    with open(stored) as fh:
        st = json.load(fh)
    seed = int(st.get("seed", 0))
    out = cli.header("core.studies.tracking.stage_sigma_frames", stored=stored,
                     stored_commit=st.get("commit"), seed=seed, mode=mode, bone=bone, pixels=pixels,
                     voxel_mm=voxel)
    t0 = time.perf_counter()
    if "search" in parts:
        ts = TrackingScene(n_frames=100, pixels=pixels, spacing=voxel, seed=seed, phase=(0.0, 0.6),
                           correction="grid")
        out["search"] = search_part(ts, st, mode, bone, list(frames))
    if "decompose" in parts:
        out["decompose"] = {"pixels": decompose_pixels, "voxel_mm": 1.0,
                            "rows": decompose_part(seed, decompose_pixels, bone, list(decompose_frames))}
    if "walking" in parts:
        out["walking"] = walking_part()
    out["total_s"] = round(time.perf_counter() - t0, 1)
    return out


def main(argv=None) -> int:
    p = cli.parser("core.studies.tracking.stage_sigma_frames", __doc__)
    p.add_argument("--stored", default=STORED)
    p.add_argument("--mode", default="joint")
    p.add_argument("--bone", default="talus")
    p.add_argument("--frames", default="6,69")
    p.add_argument("--pixels", type=int, default=1024)
    p.add_argument("--voxel", type=float, default=0.5)
    p.add_argument("--parts", default="search,decompose,walking")
    p.add_argument("--decompose-pixels", type=int, default=512)
    p.add_argument("--decompose-frames", default="69")
    cli.add_output(p)
    a = p.parse_args(argv)
    res = run(stored=a.stored, mode=a.mode, bone=a.bone, frames=cli.ints(a.frames), pixels=a.pixels,
              voxel=a.voxel, parts=cli.names(a.parts), decompose_pixels=a.decompose_pixels,
              decompose_frames=cli.ints(a.decompose_frames))
    return cli.finish(res, a)


if __name__ == "__main__":
    raise SystemExit(main())
