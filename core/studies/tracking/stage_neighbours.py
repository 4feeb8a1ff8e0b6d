"""Joint tracking with one round: the likelihood final stage's neighbours at their predictions or at
this frame's searched poses (``python -m core.studies.tracking.stage_neighbours``).

With one joint round (the default since 8dbdcc2) the lockstep round
(:func:`core.tracking.joint.register_together`) runs every bone's similarity search to its end
first, then every converged bone's final stage side by side
(:func:`core.tracking.final_stage.final_stages`), each with its neighbours subtracted at the poses
the round began with: their constant-velocity predictions (a first frame's second round: their
round-0 poses). The searched poses of the neighbours in this very frame are known by then. This
study runs the tracker itself (:func:`core.tracking.trial.track`, the acceptance study's options
with ``final="likelihood"``) on a stretch of the acceptance scene
(:class:`~core.studies.tracking.acceptance.TrackingScene`, the grid correction) in these runs:

* ``joint`` — as the tracker runs (the stage's neighbours at their predictions);
* ``joint_searched`` — the stage's neighbours at this frame's searched poses: the module's
  :func:`stage_neighbours_at` wraps :func:`~core.tracking.final_stage.final_stages` and, in each
  call, replaces a neighbour's subtracted pose by the pose its own search of the frame found where
  that neighbour is one of the call's bones (the search's, not its stage's: the stages run side
  by side). A bone whose full-resolution search did not converge (the half-resolution fallback
  runs its own stage inside :func:`~core.tracking.register.register`), a retried registration and
  the move check's confirmation keep the predictions (counted: ``fallbacks``);
* ``joint_staged`` — every stage run twice side by side: first with the neighbours at their
  predictions (as ``joint``), then again from the same searched pose with the neighbours at the first
  pass's stage poses (the first pass's evaluations are not counted);
* ``sequential`` — sequential tracking (its stage subtracts the bones registered earlier in the
  frame at their registered poses, the others at their guesses), for joint − sequential.

Per run and bone: the per-frame errors, × the Cramér–Rao bound (over three frames of the
stretch), the frames over 4× it and those not flagged (silent), the flags; each joint run paired
with the other and with sequential frame by frame
(:func:`~core.studies.tracking.acceptance_goals.paired_units`, the acceptance study's margin,
0.125× the bound). The stage log (``stages``) gives per frame, bone and neighbour the error of the
pose the stage subtracted and of that neighbour's search in the frame (and of the truth: zero).

Parts: ``stretch`` (``--first``, ``--n``: frames ``first`` … ``first + n − 1``, the two before
given at their true poses, the history the predictions start from) and ``first`` (frames 0 …
``n − 1`` from the acceptance study's keyframes, 5 mm / 5° off the truth at frame 0).

Measured (this 2-core x86_64 machine, shared; 512², 1 mm voxels, ba7b4b0, the search before the stage
to 0.5 mm / °; ``resources/benchmarks/tracking_stage_neighbours_cpu.json``, with the same at 316e1b2's
0.25): the lockstep round does run every search before any stage (no fallback in any frame). 1024²'s
calcaneus swing along x (frames 89-91 jointly only) does not reproduce at 512²: there the calcaneus is
+0.21-0.27 mm off along x at frames 88, 89, 92 in every run, sequential too (3.03 / 2.91 × its bound in mm
jointly / sequentially over 84-95). In the stored 1024² run the calcaneus's joint − sequential error along
x at 89-91 (+0.041, −0.123, +0.087 mm) follows the talus's prediction (its last two unflagged frames
extrapolated: −0.54°, +0.58°, −0.46° about y off, after its frame 88 at −0.28°), with the sign reversed;
over the run the correlation is −0.28 (about y) and −0.40 (along z): the stage's neighbour at its
prediction. At 512² the searched poses were nearer the truth than the predictions for the talus and the
calcaneus (seed 4 frames 84-95: 0.19 / 0.66 against 0.23 / 0.74 mm / °, 0.19 / 0.28 against 0.28 / 0.36),
not the tibia's rotation (0.51° against 0.29°: its search's bias about its long axis, which its stage
takes off). × the bound (mm / °), joint → joint_searched, sequential in brackets: seed 4 84-95 tibia
1.99 / 1.34 → 1.92 / 1.32 (1.99 / 1.35), talus 1.73 / 1.65 → 1.70 / 1.74 (1.70 / 1.68), calcaneus
3.03 / 1.81 → 2.80 / 1.71 (2.91 / 1.77); frames over 4× unflagged 3 → 2 (3); joint at least as good as
sequential fails the calcaneus in both units as the tracker runs, none with the searched poses. Seed 0
40-51: all within ±0.05 × (talus 2.14 / 2.07 → 2.15 / 2.04), silent 1 → 0 (0). Seed 4 frames 0-9: tibia
1.50 / 2.25 → 1.54 / 2.29, talus 1.59 / 1.47 → 1.68 / 1.48, calcaneus 1.76 / 2.01 → 1.73 / 2.02, silent 0
→ 0 (1). ``joint_staged`` (stages twice; 0.5 only): 4 silent frames, every comparison
with sequential met, at twice the stage's cost.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from contextlib import contextmanager

import numpy as np

__all__ = ["RUNS", "main", "run", "searched_others", "stage_neighbours_at"]

#: the runs (label -> (mode, where the stage's neighbours are: :func:`stage_neighbours_at`'s ``at``))
RUNS = {"joint": ("joint", "prediction"), "joint_searched": ("joint", "searched"),
        "joint_staged": ("joint", "staged"), "sequential": ("sequential", "prediction")}


def searched_others(calls, poses=None) -> list:
    """``calls`` of :func:`~core.tracking.final_stage.final_stages` (per bone ``(res, kwargs)``) with
    each call's ``others`` poses replaced, for a neighbour that is one of the calls' bones, by that
    bone's ``res.pose`` (its search's pose in this frame; ``poses``: the calls' bones' poses to use
    instead, in the calls' order); other neighbours keep theirs. The input is not changed."""
    poses = [res.pose for res, _ in calls] if poses is None else poses
    found = {int(kw["bone"]): np.asarray(P, dtype=float) for (_, kw), P in zip(calls, poses, strict=True)}
    out = []
    for res, kw in calls:
        oth = kw.get("others")
        if oth is not None:
            P = np.asarray(oth[0], dtype=float).reshape(-1, 4, 4)
            ids = list(oth[1])
            kw = {**kw, "others": (np.stack([found.get(int(b), P[j]) for j, b in enumerate(ids)]), ids)}
        out.append((res, kw))
    return out


@contextmanager
def stage_neighbours_at(at: str | bool, log: list | None = None):
    """Inside the block joint tracking's side-by-side stages subtract the neighbours at this frame's
    searched poses (``at="searched"`` or True; :func:`searched_others`), at the poses a first pass of
    the stages found (``"staged"``: every stage run twice, the second from the same searched pose
    with the neighbours at the first pass's results) or as the tracker does (``"prediction"`` or
    False); ``log`` gets one
    row per stage call: ``frame`` (the frame :func:`core.tracking.trial.track` is registering),
    ``bone``, its searched pose, ``others`` (the poses subtracted, bones) and the neighbours'
    searched poses, and ``n_calls`` (the bones staged side by side)."""
    import core.tracking.final_stage as fst
    import core.tracking.trial as trial

    plain_stages, plain_frame = fst.final_stages, trial.track_frame
    now = {"frame": None}

    def track_frame(run, f, *a, **k):
        now["frame"] = int(f)
        return plain_frame(run, f, *a, **k)

    at = {True: "searched", False: "prediction"}.get(at, at)
    if at not in ("prediction", "searched", "staged"):
        raise ValueError(f"at: expected prediction, searched or staged, got {at!r}")

    def final_stages(renderer, frame, calls):
        if at == "staged":
            first = plain_stages(renderer, frame, list(calls))
            new = searched_others(calls, [r.pose for r in first])
        else:
            new = searched_others(calls) if at == "searched" else list(calls)
        if log is not None:
            found = {int(kw["bone"]): np.asarray(res.pose, dtype=float) for res, kw in calls}
            for res, kw in new:
                oth = kw.get("others")
                log.append({"frame": now["frame"], "bone": int(kw["bone"]),
                            "searched": np.asarray(res.pose, float),
                            "others": None if oth is None else (np.asarray(oth[0], float).reshape(-1, 4, 4),
                                                                [int(b) for b in oth[1]]),
                            "neighbours_searched": {b: P for b, P in found.items() if b != int(kw["bone"])},
                            "n_calls": len(calls)})
        return plain_stages(renderer, frame, new)

    fst.final_stages, trial.track_frame = final_stages, track_frame
    try:
        yield
    finally:
        fst.final_stages, trial.track_frame = plain_stages, plain_frame


def _err(ts, b: int, f: int, pose) -> list:
    from core.studies.tracking.acceptance_records import pose_errors

    return np.round(pose_errors(np.asarray(pose, float), ts.truth(f)[b], ts.models[b].centroid), 5).tolist()


def _stage_rows(ts, log: list) -> list:
    """The stage log as errors against the truth (mm, degrees): per stage call the bone's searched
    pose, and per neighbour the pose subtracted and its own search's."""
    rows = []
    for r in log:
        f, b = r["frame"], r["bone"]
        row = {"frame": f, "bone": ts.names[b], "searched": _err(ts, b, f, r["searched"]),
               "n_calls": r["n_calls"], "neighbours": {}}
        if r["others"] is not None:
            for P, k in zip(*r["others"], strict=True):
                s = r["neighbours_searched"].get(k)
                row["neighbours"][ts.names[k]] = {"subtracted": _err(ts, k, f, P),
                                                  "searched": None if s is None else _err(ts, k, f, s)}
        rows.append(row)
    return rows


def _norms(e) -> tuple[float, float]:
    e = np.asarray(e, dtype=float)
    return float(np.linalg.norm(e[:3])), float(np.linalg.norm(e[3:]))


def _bone_run(ts, res, b: int, frames: list, bound: dict | None) -> dict:
    """One bone's record of a run: per-frame errors, flags, × the bound, frames over 4× (silent)."""
    n = ts.names[b]
    E, flagged, notes, moves = [], [], {}, []
    for f in frames:
        fr = res.results[(n, f)]
        E.append([np.nan] * 6 if fr.pose is None else _err(ts, b, f, fr.pose))
        if fr.flags:
            flagged.append(f)
        if fr.flags or fr.notes:
            notes[f] = list(fr.flags) + [f"note: {x}" for x in fr.notes]
        moves.append((fr.timing or {}).get("likelihood_move_mm"))
    E = np.asarray(E, dtype=float)
    et, er = np.linalg.norm(E[:, :3], axis=1), np.linalg.norm(E[:, 3:], axis=1)
    out = {"per_frame_error": np.round(E, 5).tolist(), "flagged": flagged, "flags": notes,
           "stage_move_mm": [None if m is None else round(float(m), 4) for m in moves],
           "rms_mm": round(float(np.sqrt(np.nanmean(et ** 2))), 5),
           "rms_deg": round(float(np.sqrt(np.nanmean(er ** 2))), 5)}
    if bound:
        over = (et > 4 * bound["rms_mm"]) | (er > 4 * bound["rms_deg"])
        bad = [f for f, o in zip(frames, over, strict=True) if o]
        out.update(over_bound={"mm": round(out["rms_mm"] / bound["rms_mm"], 3),
                               "deg": round(out["rms_deg"] / bound["rms_deg"], 3)},
                   over_4x=bad, silent=[f for f in bad if f not in flagged])
    return out


def _track(ts, frames: list, keyframes: dict, skip: dict | None, mode: str, at: str) -> tuple:
    from core.studies.tracking.acceptance import study_options
    from core.tracking.trial import track

    log: list = []
    o = study_options(mode, final="likelihood")
    with stage_neighbours_at(at if mode == "joint" else "prediction", log):
        res = track(ts.renderer, ts.models, ts.frames, frames, keyframes=keyframes, skip=skip, options=o)
    return res, log


def _paired(A: dict, B: dict, bound: dict | None) -> dict:
    """``A`` (joint) against ``B`` (sequential or another run), per unit: the paired RMS difference
    A − B with its interval, the verdict and, with a bound, at-least-as-good at the acceptance margin."""
    from core.studies.tracking.acceptance_goals import joint_margin, paired_units

    margin = joint_margin(bound) if bound else {"mm": 0.0, "deg": 0.0}
    p = paired_units(np.asarray(B["per_frame_error"]), np.asarray(A["per_frame_error"]), margin)
    keys = ("rms_sequential", "rms_joint", "rms_difference", "interval95", "verdict", "margin",
            "at_least_as_good")
    return {u: {k: v.get(k) for k in keys} for u, v in p.items()}


def run(*, part: str = "stretch", seed: int = 4, first: int = 84, n: int = 12, pixels: int = 512,
        voxel: float = 1.0, runs=tuple(RUNS), device: str | None = None, ts=None, bound_frames: int = 3,
        progress=None) -> dict:
    """The runs of ``runs`` (:data:`RUNS`) on ``part``'s frames (module docs); ``ts``: a scene made
    already (then ``seed``, ``pixels``, ``voxel`` are its)."""
    from core.geometry.transforms import pose_from_params
    from core.studies.tracking.acceptance import TrackingScene, _random_offset, cramer_rao

    t0 = time.perf_counter()
    if ts is None:
        ts = TrackingScene(n_frames=100, pixels=pixels, spacing=voxel, seed=seed, phase=(0.0, 0.6),
                           device=device, correction="grid")
    if part == "stretch":
        given = {m: {f: ts.truth(f)[b] for f in (first - 2, first - 1)} for b, m in enumerate(ts.names)}
        frames, keyframes, skip = list(range(first - 2, first + n)), given, given
        scored = frames[2:]
    elif part == "first":
        g = np.random.default_rng(ts._seed + 7)  # the acceptance study's keyframes
        keyframes = {nm: {0: pose_from_params(_random_offset(g, 5.0, 5.0), center=m.centroid,
                                              base=ts.truth(0)[b])}
                     for b, (nm, m) in enumerate(zip(ts.names, ts.models, strict=True))}
        frames, skip = list(range(n)), None
        scored = frames
    else:
        raise ValueError(f"part: expected stretch or first, got {part!r}")
    for f in frames:
        ts.frames(f)
    bf = [int(x) for x in np.linspace(scored[0], scored[-1], bound_frames).round()] if bound_frames else []
    bound = cramer_rao(ts, sorted(set(bf))) if bf else {}
    out = {"study": "core.studies.tracking.stage_neighbours", "part": part, "machine": platform.machine(),
           "device": str(ts.renderer.device), "pixels": ts.scene.rig[0].width,
           "voxel_mm": float(ts.models[0].volume.spacing[0]), "seed": ts._seed, "frames": scored,
           "cramer_rao": {k: {"rms_mm": round(v["rms_mm"], 5), "rms_deg": round(v["rms_deg"], 5)}
                          for k, v in bound.items()},
           "scene_s": round(time.perf_counter() - t0, 1), "runs": {}, "stages": {}, "paired": {}}
    for label in runs:
        mode, at = RUNS[label]
        t1 = time.perf_counter()
        res, log = _track(ts, frames, keyframes, skip, mode, at)
        r = {"s": round(time.perf_counter() - t1, 1),
             "fallbacks": sum(1 for x in log if x["n_calls"] < len(ts.names))}
        for b, nm in enumerate(ts.names):
            r[nm] = _bone_run(ts, res, b, scored, bound.get(nm))
        out["runs"][label] = r
        if log:
            out["stages"][label] = _stage_rows(ts, [x for x in log if x["frame"] in scored])
        if progress is not None:
            keys = ("rms_mm", "rms_deg", "over_bound", "silent", "flagged")
            progress({"run": label, "s": r["s"], **{nm: {k: r[nm].get(k) for k in keys} for nm in ts.names}})
    pairs = [(a, b) for a in out["runs"] for b in out["runs"]
             if a.startswith("joint") and (b == "sequential" or (a != "joint" and b == "joint"))]
    for a, b in pairs:
        out["paired"][f"{a}_vs_{b}"] = {nm: _paired(out["runs"][a][nm], out["runs"][b][nm], bound.get(nm))
                                        for nm in ts.names}
    out["total_s"] = round(time.perf_counter() - t0, 1)
    return out


def neighbour_summary(out: dict, label: str = "joint") -> dict:
    """Per bone and neighbour over a result's stage log: the RMS error (mm, degrees) of the poses the
    stage subtracted and of the neighbours' own searches in the frame."""
    acc: dict = {}
    for row in out["stages"].get(label, []):
        for k, v in row["neighbours"].items():
            a = acc.setdefault(f"{row['bone']}<-{k}", {"subtracted": [], "searched": []})
            a["subtracted"].append(_norms(v["subtracted"]))
            if v["searched"] is not None:
                a["searched"].append(_norms(v["searched"]))
    res = {}
    for key, a in acc.items():
        res[key] = {w: None if not a[w] else [round(float(np.sqrt(np.mean(np.asarray(a[w])[:, i] ** 2))), 4)
                                              for i in (0, 1)] for w in ("subtracted", "searched")}
    return res


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.stage_neighbours",
                                description=__doc__.split("\n")[0])
    p.add_argument("--part", default="stretch", choices=("stretch", "first"))
    p.add_argument("--seed", type=int, default=4)
    p.add_argument("--first", type=int, default=84)
    p.add_argument("--n", type=int, default=12)
    p.add_argument("--pixels", type=int, default=512)
    p.add_argument("--voxel", type=float, default=1.0)
    p.add_argument("--runs", default=",".join(RUNS))
    p.add_argument("--device", default=None)
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    res = run(part=a.part, seed=a.seed, first=a.first, n=a.n, pixels=a.pixels, voxel=a.voxel,
              runs=[r.strip() for r in a.runs.split(",")], device=a.device,
              progress=lambda d: print(json.dumps(d), flush=True))
    for label in res["stages"]:
        res.setdefault("neighbour_rms", {})[label] = neighbour_summary(res, label)
    from core.io.atomic import print_json

    print_json(res, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
