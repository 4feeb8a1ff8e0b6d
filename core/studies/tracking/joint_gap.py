"""Why joint tracking is slightly worse than sequential on the acceptance trial (``python -m
core.studies.tracking.joint_gap``).

Joint tracking (:func:`core.tracking.frame_step.track_frame`, ``mode="joint"``) is not one search
over 18 parameters: it is ``joint_rounds`` (2 here) rounds of the bones' own 6-parameter Gauss–Newton
searches in lockstep (:func:`core.tracking.joint.register_together`), each with its neighbours'
DRRs subtracted — in round 0 every bone from its prediction with the neighbours at theirs, in
round 1 every bone from its round-0 pose with the neighbours at their round-0 poses. Each bone's
cost is its own gradient correlation over its own search regions, the neighbours' DRRs subtracted
from the frame as in sequential tracking (no pixel is scored twice, no sum of DRRs is scored), and
the contact penalty is off by default. Sequential tracking (``sequential_subtract``) runs one
search per bone from its prediction, the bones registered before it in the frame subtracted at
their poses, the others at their predictions. What the modes differ in is (1) where the last
search starts — the prediction, or round 0's pose — and (2) the poses the neighbours are
subtracted at.

``stored`` (no tracking; ``--stored FILE``, the acceptance run with both modes, and the other
syntheses' stored runs, :data:`SEEDS_JSON`, :data:`HELD_OUT_JSONS`): per bone and axis the
correlation, over frames, of joint − sequential with the offset of the constant-velocity
prediction from the sequential estimate (the prediction proxied from the run's own estimates of
the two frames before); negative: sequential sits nearer its start than joint does; and ``k``, the
least-squares share in joint − sequential = −k (prediction − sequential).

``probe`` (this machine's CPU): the acceptance scene (:class:`core.studies.tracking.acceptance.
TrackingScene`, ``--pixels`` views, ``--voxel`` mm voxels, the grid correction), frames
``--frames``, ``--draws`` noise draws per frame (the trial's own, then independent ones; the same
draw in every case). The tracker's start is each bone's constant-velocity prediction from the
true poses of the two frames before with the stored run's per-frame errors applied
(``--stored``: the joint run's errors, the tracker's starts as they were; by default the stored
run of the same scene ``--seed``, :data:`HISTORY_BY_SEED` — seed 3's the joint run of today's
synthesis in ``tracking_joint_restart_acceptance_seed3_h100.json``, not the held-out run of 56350ae's,
whose tibia differs in frames 91–99; another seed's run is refused). Per frame and draw,
every bone registered by the tracker's default options in the cases (start; neighbours
subtracted at):

* ``S`` — sequential: the prediction; the bones before at their ``S`` poses, the others at their
  predictions;
* ``J0``, ``J1`` — joint's rounds in lockstep: the prediction; the predictions — then round 0's
  pose; round 0's poses (``J1`` is joint tracking's result);
* ``J1p`` — joint's last round from the prediction: the prediction; round 0's poses (the start
  candidate: ``J1`` − ``J1p`` is the start's share, ``J1p`` − ``S`` the neighbours');
* ``opt`` — the same cost as ``J1`` searched to its optimum (Gauss–Newton steps until one is below
  0.002 mm / ° and no stop on the predicted decrease, at most 16) from the prediction;
* ``TJ``, ``TS`` — from the TRUE pose: round 0's poses (joint's neighbours), the ``S`` case's
  neighbours.

Per case and bone: the RMS error (mm, °) over frames and draws, joint's-style paired comparison
with ``S`` (:func:`paired_by_frame`: the RMS difference with a bootstrap over frames, a frame's
draws resampled together), and how much of its start the search kept: the least-squares fraction ``k`` of the
start's offset from ``opt`` left in the result's (rotation, degrees; 0: at the cost's optimum, 1:
at the start). Study only: it reads the truth. JSON on stdout (and ``--out``).

``--stretch FIRST,N`` (:func:`track_stretch`) runs the tracker itself on N frames, joint, joint
with :data:`core.tracking.frame_step.RESTART_FROM_PREDICTION` and sequential (``--runs``: also
joint with one round); ``--acceptance`` (:func:`acceptance_restart`) the acceptance study with those
four runs (a GPU's work).

Findings
--------
* **Stored runs** (1024², one NVIDIA H100; seeds 0–4: ``tracking_acceptance_near_rule_h100.json``,
  ``sequential_drift_seeds_h100.json``, ``tracking_acceptance_seed3_h100.json``, ``…seed4…``, seed
  4's run redone on the synthesis that keeps touching bones apart): joint − sequential is
  anti-correlated with the prediction's offset from the sequential estimate — the tibia about lab z
  (its long axis) −0.60, −0.58, −0.73, −0.52, −0.57 (k 0.05–0.18; joint's mean-square error there
  +0.0013 to +0.0046 deg² on seeds 0–3, −0.0067 deg² on seed 4: keeping part of the prediction
  helps only where it is the better estimate; these are over frames 2–99, the frames with two
  before — over all 100 seed 4's is +0.0102 deg², its frame 0 alone, where no prediction is made,
  jointly −1.17° against sequentially +0.21°), the calcaneus about lab x (its long axis) −0.26 to
  −0.71 (k 0.006–0.027, +0.0003 to +0.0005 deg², joint worse on all five); the talus mixed.
* **Why** (``resources/benchmarks/tracking_joint_gap_cpu.json``, 512², 1 mm voxels, 10 frames × 2
  draws, this 2-core x86_64 machine, shared): the Gauss–Newton search stops (its next step's
  predicted decrease under a tenth of the cost's roughness) with part of its start's offset left
  along the cost's flat directions, the long axes. Sequential's one search keeps 0.157 of the
  prediction's offset (tibia rotation), joint's second search, from round 0's pose, 0.063, from
  the prediction 0.111. The prediction carries the earlier frames' evidence; keeping part
  of it is a small, accidental temporal smoothing: the cost's own optimum (``opt``) is worse than
  either — tibia 0.2615° RMS against sequential's 0.2399° (+0.0217 [+0.0011, +0.0370]), joint
  0.2514° (+0.0115 [−0.0017, +0.0217], not resolved over 10 frames), joint's last round from the
  prediction 0.2471° (+0.0073 [−0.0064, +0.0179]); the calcaneus joint +0.0032° [+0.0001,
  +0.0064], from the prediction +0.00001° [−0.00007, +0.00008] (the same as sequential). The
  neighbours' poses (round 0's against sequential's) are not resolved: tibia ``J1p`` − ``S`` above,
  from the truth ``TJ`` − ``TS`` +0.0082° [−0.0038, +0.0172], the calcaneus 0.0000°, the talus
  −0.002 to −0.003°. (Intervals resample frames with both their draws, which share the start and
  the scene; resampled as 20 independent registrations joint's tibia read +0.0115° [+0.0001,
  +0.0212], resolved.) Not the cause:
  an 18-parameter search (there is none), the contact penalty (off in those runs, and no bones
  interpenetrated), a pixel scored twice (each bone scores its own regions, the others' DRRs
  subtracted, as sequentially), the prediction (the same in both modes).
* **The fix, opt-in** (``RESTART_FROM_PREDICTION``; ``tracking_joint_gap_stretch_cpu.json``, the
  tracker on frames 40–63 and 70–93, 512², same machine, pooled by :func:`pool_stretches`): joint −
  sequential calcaneus +0.0057° [+0.0014, +0.0106], tibia +0.0018° [−0.0080, +0.0112]; with the
  restart −0.00001° and −0.00002° (against joint −0.0057° [−0.0106, −0.0014] and −0.0018° [−0.0075,
  +0.0053]; frames 40–63 alone the tibia −0.0065° [−0.0100, −0.0027], 70–93 +0.0032° [−0.0077,
  +0.0163]). The talus's translation is +0.0006 mm [+0.00005, +0.0011] jointly either way: what the
  modes still differ in, the calcaneus subtracted at its round-0 pose rather than its prediction.
  It costs the second round's steps: 38 / 48 / 46 evaluations per bone-frame (tibia, talus,
  calcaneus) → 50 / 69 / 65 (sequential 25 / 34 / 33).
* **One round** (``joint_rounds=1``, same frames): against sequential −0.0008° [−0.0021, +0.0003]
  (tibia), +0.0006° (talus; −0.00002 mm), −0.0004° (calcaneus) at 25 / 34 / 32 evaluations;
  against joint as it is the calcaneus −0.0061° [−0.0132, −0.0002]. What the second round is for
  (poor neighbour predictions, first frames) these stretches from true poses do not test.
* **Held-out seed 3 at 1024²** (``--acceptance --seed 3``, one NVIDIA H100 at 782362a;
  ``tracking_joint_restart_acceptance_seed3_h100.json``): the restart leaves the tibia's rotation
  worse than sequential (+0.0143° [+0.0015, +0.0305]; joint +0.0147° [+0.0052, +0.0264], margin
  0.0123°), matches it for the calcaneus; one round matches sequential for every bone (tibia
  +0.0018° [−0.0011, +0.0064]) at 121 evaluations a frame (joint 202, restarted 242, sequential 123).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

import numpy as np

__all__ = ["ACCEPTANCE_RUNS", "CASES", "EXTRA_RUNS", "HISTORY_BY_SEED", "PAIRS", "RUN_SEEDS", "STRETCH_RUNS",
           "acceptance_restart", "history_for", "main", "paired_by_frame", "pool_stretches", "probe",
           "probe_summary", "stored", "track_stretch"]

ACCEPTANCE_JSON = "resources/benchmarks/tracking_acceptance_near_rule_h100.json"
CASES = ("S", "J0", "J1", "J1p", "opt", "TJ", "TS")


def _per_frame(d: dict, mode: str, bone: str) -> dict[int, np.ndarray]:
    t = d["runs"][mode]["tracking"][bone]
    return {int(f): np.asarray(e, float)
            for f, e in zip(t["frames_with_pose"], t["per_frame_error"], strict=True)}


SEEDS_JSON = "resources/benchmarks/sequential_drift_seeds_h100.json"
#: Held-out syntheses (scene seeds 3 and 4) with both modes, read by :func:`stored` too.
HELD_OUT_JSONS = ("resources/benchmarks/tracking_acceptance_seed3_h100.json",
                  "resources/benchmarks/tracking_acceptance_seed4_h100.json")


def _compare(J: dict, S: dict) -> dict:
    """Per axis: joint − sequential (per-frame errors ``J``, ``S``: frame -> (6,)) against the
    prediction's offset from the sequential estimate (module docs, ``stored``)."""
    fr = [f for f in sorted(J) if f in S and f - 1 in S and f - 2 in S]
    Jm = np.array([J[f] for f in fr])
    Sm = np.array([S[f] for f in fr])
    P = np.array([2 * S[f - 1] - S[f - 2] for f in fr])  # the prediction's error (proxy)
    D = Jm - Sm
    rows = []
    for a in range(6):
        off = P[:, a] - Sm[:, a]
        rms = float(np.sqrt(np.mean(D[:, a] ** 2)))
        rows.append({"axis": a, "rms_joint_minus_sequential": round(rms, 5),
                     "corr_with_prediction_offset": round(float(np.corrcoef(D[:, a], off)[0, 1]), 3),
                     # least squares: joint - sequential = -k (prediction - sequential)
                     "start_share_k": round(float(-(off @ D[:, a]) / max(off @ off, 1e-30)), 4),
                     "mean_sq_joint_minus_sequential": round(float(np.mean(Jm[:, a] ** 2 - Sm[:, a] ** 2)),
                                                             7)})
    return {"frames": len(fr), "axes": rows}


def stored(path: str = ACCEPTANCE_JSON, seeds: str | None = SEEDS_JSON, held_out=HELD_OUT_JSONS) -> dict:
    """The ``stored`` analysis (module docs) of an acceptance JSON with both modes, and of the
    :mod:`~core.studies.tracking.sequential_drift` runs of other syntheses in ``seeds`` (joint
    against ``sequential_subtracted``; None: not read) and the acceptance JSONs ``held_out``."""
    with open(path) as fh:
        d = json.load(fh)
    out = {"source": path, "bones": {b: _compare(_per_frame(d, "joint", b), _per_frame(d, "sequential", b))
                                     for b in d["runs"]["joint"]["tracking"]}}
    for extra in held_out or ():  # more syntheses of the trial, acceptance JSONs with both modes
        with open(extra) as fh:
            dx = json.load(fh)
        out.setdefault("held_out", {})[extra] = {
            b: _compare(_per_frame(dx, "joint", b), _per_frame(dx, "sequential", b))
            for b in dx["runs"]["joint"]["tracking"]}
    if seeds:
        with open(seeds) as fh:
            ds = json.load(fh)
        out["seeds_source"] = seeds
        out["seeds"] = {}
        for key, r in ds["runs"].items():
            def pf(mode, b, r=r):
                t = r["runs"][mode][b]
                return {int(f): np.asarray(e, float)
                        for f, e in zip(t["frames"], t["per_frame_error"], strict=True)}

            out["seeds"][key] = {b: _compare(pf("joint", b), pf("sequential_subtracted", b))
                                 for b in r["runs"]["joint"]}
    return out


def _pose(err6, truth, center) -> np.ndarray:
    """The pose whose :func:`~core.studies.tracking.acceptance.pose_errors` against ``truth`` is ``err6``."""
    from core.geometry.transforms import pose_from_params

    e = np.asarray(err6, float)
    return pose_from_params(np.r_[e[:3], np.radians(e[3:])], center=center, base=truth)


def _tight(reg):
    from dataclasses import replace

    from core.tracking.register_options import FINAL_STEP, Level

    return replace(reg, levels=(Level(scale=1.0, method="gauss_newton", sigma=FINAL_STEP, max_generations=16,
                                      tol_x=0.002, options={"tol_noise": 1e-4}),))


def _one_frame(ts, f: int, draw: int, starts: list, reg) -> dict:
    """Every case (module docs) of frame ``f``, noise draw ``draw``: per case the poses of the bones."""
    from core.studies.tracking.tibia_cost import _chain
    from core.tracking.cost import prepare_frame
    from core.tracking.joint import JointJob, register_together
    from core.tracking.register import register

    L = ts.scene.line_integrals(f, renderer=ts._scene_renderer)
    frame = prepare_frame(_chain(ts, L, True, f, draw=draw))
    n = len(ts.names)
    T = ts.truth(f)
    M = ts.models

    def nb(i, poses):
        ids = [k for k in range(n) if k != i]
        return np.stack([poses[k] for k in ids]), ids

    def one(i, start, poses, opts=reg):
        r = register(ts.renderer, frame, bone=i, initial_pose=start, center=M[i].centroid, options=opts,
                     others=nb(i, poses), outline=M[i].outline)
        return r.pose

    def together(st, poses, rois=None):
        jobs = [JointJob(i, st[i], M[i].centroid, M[i].outline, nb(i, poses),
                         None if rois is None else rois[i]) for i in range(n)]
        got = register_together(ts.renderer, frame, jobs, reg)
        for g in got:
            if isinstance(g, Exception):
                raise g
        return [g.pose for g in got], [j.roi for j in jobs]

    out = {}
    S = list(starts)
    for i in range(n):
        S[i] = one(i, starts[i], S)
    out["S"] = S
    J0, rois = together(starts, starts)
    out["J0"] = J0
    out["J1"], _ = together(J0, J0, rois)
    out["J1p"], _ = together(starts, J0, rois)
    tight = _tight(reg)
    out["opt"] = [one(i, starts[i], J0, tight) for i in range(n)]
    out["TJ"] = [one(i, T[i], J0) for i in range(n)]
    seq_nb = [[S[k] if k < i else starts[k] for k in range(n)] for i in range(n)]
    out["TS"] = [one(i, T[i], seq_nb[i]) for i in range(n)]
    return out


#: The stored joint run of each synthesis the probe can start from (``--stored``): seed 0's
#: acceptance run, seed 3's of today's synthesis (the ``--acceptance`` run, 782362a), seed 4's
#: held-out run (:data:`HELD_OUT_JSONS`; its synthesis unchanged since a5fd412).
HISTORY_BY_SEED = {0: ACCEPTANCE_JSON,
                   3: "resources/benchmarks/tracking_joint_restart_acceptance_seed3_h100.json",
                   4: HELD_OUT_JSONS[1]}
#: The stored runs' scene seeds, those :data:`HISTORY_BY_SEED` does not name included.
RUN_SEEDS = {v: k for k, v in HISTORY_BY_SEED.items()} | {HELD_OUT_JSONS[0]: 3}


def history_for(seed: int, history: str | None = None) -> str:
    """The stored run whose errors give the probe's starts on scene ``seed``: ``history`` where
    given, else :data:`HISTORY_BY_SEED`'s. A run of another seed's trial would start every bone
    from that trial's errors: ValueError where ``history`` is a known run of another seed, or no
    run of ``seed`` is known (a known run however its path is written: the same file)."""
    if history is None:
        if seed not in HISTORY_BY_SEED:
            raise ValueError(f"seed {seed}: no stored run known (HISTORY_BY_SEED); give its history")
        return HISTORY_BY_SEED[seed]
    real = os.path.realpath(history)
    other = next((s for p, s in RUN_SEEDS.items() if os.path.realpath(p) == real), seed)
    if other != seed:
        raise ValueError(f"history {history} is seed {other}'s run, not seed {seed}'s")
    return history


def probe(*, frames=(12, 21, 30, 39, 48, 57, 66, 75, 84, 93), draws: int = 2, pixels: int = 512,
          voxel: float = 1.0, history: str | None = None, seed: int = 0, device: str | None = None,
          progress=None) -> dict:
    """The ``probe`` (module docs); JSON-ready results. ``history``: the stored joint run of the
    same scene seed (default :func:`history_for`'s). ``progress``: called with each frame and
    draw's row as it is done."""
    from core.studies.tracking.acceptance import TrackingScene, pose_errors, study_options
    from core.tracking.frame_state import predict_pose

    history = history_for(seed, history)
    t0 = time.perf_counter()
    ts = TrackingScene(n_frames=100, pixels=pixels, spacing=voxel, seed=seed, phase=(0.0, 0.6), device=device,
                       correction="grid")
    with open(history) as fh:
        hist = json.load(fh)
    errs = {b: _per_frame(hist, "joint", b) for b in ts.names}
    reg = study_options("joint").registration
    t_scene = time.perf_counter() - t0
    rows = []
    for f in frames:
        pred = []
        for b, (n, m) in enumerate(zip(ts.names, ts.models, strict=True)):
            h = [(k, _pose(errs[n][k], ts.truth(k)[b], m.centroid)) for k in (f - 2, f - 1)]
            pred.append(predict_pose(h, f, m.centroid))
        for d in range(draws):
            t1 = time.perf_counter()
            got = _one_frame(ts, f, d, pred, reg)
            T = ts.truth(f)
            row = {"frame": f, "draw": d, "s": round(time.perf_counter() - t1, 1), "errors": {}}
            for c, P in got.items():
                row["errors"][c] = [pose_errors(P[b], T[b], m.centroid).round(5).tolist()
                                    for b, m in enumerate(ts.models)]
            row["start_errors"] = [pose_errors(pred[b], T[b], m.centroid).round(5).tolist()
                                   for b, m in enumerate(ts.models)]
            rows.append(row)
            if progress is not None:
                progress(row)
    return {"study": "core.studies.tracking.joint_gap", "machine": platform.machine(),
            "device": str(ts.renderer.device), "pixels": pixels, "voxel_mm": voxel, "seed": seed,
            "frames": list(frames), "draws": draws, "history": history, "scene_s": round(t_scene, 1),
            "total_s": round(time.perf_counter() - t0, 1), "summary": probe_summary(rows, ts.names),
            "rows": rows}


#: :func:`probe_summary`'s pairs beyond each case against ``S``: (case, against, what it measures)
PAIRS = (("J1", "J1p", "start"), ("J1p", "S", "neighbours"), ("TJ", "TS", "neighbours_from_truth"))


def probe_summary(rows: list, names) -> dict:
    """Per bone of :func:`probe`'s ``rows``: per case the RMS errors, the paired comparison with
    ``S`` and, for the cases from the prediction, the share of its start kept (module docs); the
    paired comparisons of :data:`PAIRS` (:func:`paired_by_frame`: the draws of a frame share its
    start and scene, so they are resampled together); the RMS error about each rotation axis per case."""
    groups = np.array([r.get("frame", k) for k, r in enumerate(rows)])

    def paired(E, a, b, sl):  # a's RMS minus b's, paired by registration, a frame's draws resampled together
        return paired_by_frame(np.linalg.norm(E[b][:, sl], axis=1), np.linalg.norm(E[a][:, sl], axis=1),
                               groups)

    mm, deg = slice(0, 3), slice(3, 6)
    summary = {}
    for b, n in enumerate(names):
        per = {}
        E = {c: np.array([r["errors"][c][b] for r in rows]) for c in CASES}
        st = np.array([r["start_errors"][b] for r in rows])
        for c in CASES:
            e = E[c]
            row = {"rms_mm": round(float(np.sqrt(np.mean(np.sum(e[:, mm] ** 2, 1)))), 5),
                   "rms_deg": round(float(np.sqrt(np.mean(np.sum(e[:, deg] ** 2, 1)))), 5),
                   "rms_deg_per_axis": np.sqrt(np.mean(e[:, deg] ** 2, 0)).round(5).tolist()}
            if c != "S":
                row["vs_S_mm"], row["vs_S_deg"] = paired(E, c, "S", mm), paired(E, c, "S", deg)
            if c in ("S", "J0", "J1", "J1p"):  # the start's share left: (x - opt) = k (start - opt)
                a = (st[:, deg] - E["opt"][:, deg]).ravel()
                y = (e[:, deg] - E["opt"][:, deg]).ravel()
                row["start_kept_rotation"] = round(float(a @ y / max(a @ a, 1e-30)), 3)
            per[c] = row
        per["start"] = {"rms_mm": round(float(np.sqrt(np.mean(np.sum(st[:, mm] ** 2, 1)))), 5),
                        "rms_deg": round(float(np.sqrt(np.mean(np.sum(st[:, deg] ** 2, 1)))), 5)}
        per["pairs"] = {f"{a}-{c}": {"measures": what, "mm": paired(E, a, c, mm), "deg": paired(E, a, c, deg)}
                        for a, c, what in PAIRS}
        summary[n] = per
    return summary


def paired_by_frame(seq, joint, groups, *, n_boot: int = 4000, seed: int = 0) -> dict:
    """``joint``'s RMS minus ``seq``'s (per-registration error lengths, paired) with a 95 % bootstrap
    interval that resamples the ``groups`` (frames) with all their registrations (noise draws):
    registrations of one frame share its start and scene and are not independent. The fields of
    :func:`~core.studies.tracking.hard_trial_stats.paired_comparison` that :func:`probe_summary` keeps."""
    a, b, groups = np.asarray(seq, float), np.asarray(joint, float), np.asarray(groups)
    ok = np.isfinite(a) & np.isfinite(b)
    members = [np.flatnonzero(ok & (groups == k)) for k in np.unique(groups[ok])]
    if not members:
        return {"n_frames": 0, "verdict": "no frames"}
    sa, sb = (np.array([np.sum(x[m] ** 2) for m in members]) for x in (a, b))
    cnt = np.array([len(m) for m in members])
    pick = np.random.default_rng(seed).integers(0, len(members), (n_boot, len(members)))
    drms = np.sqrt(sb[pick].sum(1) / cnt[pick].sum(1)) - np.sqrt(sa[pick].sum(1) / cnt[pick].sum(1))
    lo, hi = np.quantile(drms, [0.025, 0.975])
    return {"n_frames": len(members), "rms_difference": round(float(np.sqrt(np.mean(b[ok] ** 2))
                                                                  - np.sqrt(np.mean(a[ok] ** 2))), 5),
            "interval95": [round(float(lo), 5), round(float(hi), 5)],
            "verdict": "worse" if lo > 0 else "better" if hi < 0 else "not resolved",
            "frames_joint_worse": round(float(np.mean(b[ok] > a[ok])), 3)}


def _brief(p: dict) -> dict:
    return {k: p[k] for k in ("rms_difference", "interval95", "verdict", "frames_joint_worse") if k in p}


#: :func:`track_stretch`'s runs: (label, mode, rounds after the first from the prediction[, joint_rounds])
STRETCH_RUNS = (("joint", "joint", False, 2), ("joint_restart", "joint", True, 2),  # two rounds as measured
                ("sequential", "sequential", False))
#: More runs :func:`track_stretch` knows (``--runs``): joint tracking with one round (``joint_rounds=1``:
#: every bone from its prediction, the neighbours at theirs; round 0 alone)
EXTRA_RUNS = {"joint_one_round": ("joint", False, 1)}


def track_stretch(*, first: int = 40, n: int = 16, pixels: int = 512, voxel: float = 1.0, seed: int = 0,
                  device: str | None = None, runs=STRETCH_RUNS, progress=None) -> dict:
    """The tracker itself (:func:`core.tracking.trial.track`, the acceptance options of each mode)
    on frames ``first`` … ``first + n - 1`` of the acceptance scene (as :func:`probe`'s), the two
    frames before given at their true poses (the history the predictions start from): per run and
    bone the per-frame errors and evaluations, and each joint run paired with the sequential run
    and with each other, frame by frame (:func:`~core.studies.tracking.hard_trial_stats.
    paired_comparison`, circular blocks)."""
    from dataclasses import replace

    import core.tracking.frame_step as fs
    from core.studies.tracking.acceptance import TrackingScene, pose_errors, study_options
    from core.studies.tracking.hard_trial_stats import paired_comparison
    from core.tracking.trial import track

    t0 = time.perf_counter()
    ts = TrackingScene(n_frames=100, pixels=pixels, spacing=voxel, seed=seed, phase=(0.0, 0.6), device=device,
                       correction="grid")
    given = {m: {f: ts.truth(f)[b] for f in (first - 2, first - 1)} for b, m in enumerate(ts.names)}
    frames = list(range(first - 2, first + n))
    for f in frames:
        ts.frames(f)
    out = {"study": "core.studies.tracking.joint_gap (stretch)", "machine": platform.machine(),
           "device": str(ts.renderer.device), "pixels": pixels, "voxel_mm": voxel, "seed": seed,
           "frames": frames[2:], "scene_s": round(time.perf_counter() - t0, 1), "runs": {}, "paired": {}}
    for label, mode, restart, *rounds in runs:
        t1 = time.perf_counter()
        fs.RESTART_FROM_PREDICTION = restart
        o = study_options(mode)
        if rounds:
            o = replace(o, joint_rounds=int(rounds[0]))
        try:
            res = track(ts.renderer, ts.models, ts.frames, frames, keyframes=given, skip=given, options=o)
        finally:
            fs.RESTART_FROM_PREDICTION = False
        run = {"s": round(time.perf_counter() - t1, 1)}
        for b, (name, m) in enumerate(zip(ts.names, ts.models, strict=True)):
            E, ev = [], []
            for f in frames[2:]:
                fr = res.results[(name, f)]
                T = ts.truth(f)[b]
                E.append([np.nan] * 6 if fr.pose is None else pose_errors(fr.pose, T, m.centroid))
                ev.append(int(fr.evaluations))
            E = np.asarray(E, float)
            run[name] = {"per_frame_error": E.round(5).tolist(), "evaluations": ev,
                         "rms_mm": round(float(np.sqrt(np.nanmean(np.sum(E[:, :3] ** 2, 1)))), 5),
                         "rms_deg": round(float(np.sqrt(np.nanmean(np.sum(E[:, 3:] ** 2, 1)))), 5),
                         "mean_evaluations": round(float(np.mean(ev)), 1)}
        out["runs"][label] = run
        if progress is not None:
            progress({"run": label, "s": run["s"], **{k: {"rms_mm": v["rms_mm"], "rms_deg": v["rms_deg"]}
                                                     for k, v in run.items() if k != "s"}})
    pairs = [(a, b) for a in out["runs"] for b in out["runs"] if a != b and a.startswith("joint")
             and (b == "sequential" or (a, b) == ("joint_restart", "joint"))]
    for a, b in pairs:
        key = f"{a}_vs_{b}"
        out["paired"][key] = {}
        for name in ts.names:
            A = np.asarray(out["runs"][a][name]["per_frame_error"])
            B = np.asarray(out["runs"][b][name]["per_frame_error"])
            out["paired"][key][name] = {
                u: _brief(paired_comparison(np.linalg.norm(B[:, sl], axis=1),
                                            np.linalg.norm(A[:, sl], axis=1), margin=0.0))
                for u, sl in (("mm", slice(0, 3)), ("deg", slice(3, 6)))}
    out["total_s"] = round(time.perf_counter() - t0, 1)
    return out


def pool_stretches(results) -> dict:
    """:func:`track_stretch` results of several stretches (same runs) joined: per pair of runs (as
    ``paired``) and bone the frames of every stretch paired together, and each run's RMS errors."""
    from core.studies.tracking.hard_trial_stats import paired_comparison

    results = list(results)
    runs = list(results[0]["runs"])
    names = [k for k in results[0]["runs"][runs[0]] if k != "s"]

    def errors(run, name):
        return np.concatenate([np.asarray(r["runs"][run][name]["per_frame_error"], float) for r in results])

    out = {"frames": sum(len(r["frames"]) for r in results), "rms": {}, "paired": {}}
    for run in runs:
        out["rms"][run] = {n: {u: round(float(np.sqrt(np.nanmean(np.sum(errors(run, n)[:, sl] ** 2, 1)))), 5)
                               for u, sl in (("mm", slice(0, 3)), ("deg", slice(3, 6)))} for n in names}
    for key in results[0]["paired"]:
        a, b = key.split("_vs_")
        out["paired"][key] = {n: {u: _brief(paired_comparison(np.linalg.norm(errors(b, n)[:, sl], axis=1),
                                                              np.linalg.norm(errors(a, n)[:, sl], axis=1),
                                                              margin=0.0))
                                  for u, sl in (("mm", slice(0, 3)), ("deg", slice(3, 6)))} for n in names}
    return out


#: :func:`acceptance_restart`'s runs: (label, mode, RESTART_FROM_PREDICTION, joint_rounds or None)
ACCEPTANCE_RUNS = (("joint", "joint", False, 2), ("joint_restart", "joint", True, 2),
                   ("joint_one_round", "joint", False, 1), ("sequential", "sequential", False, None))


def acceptance_restart(*, seed: int = 0, quick: bool = False, n_frames: int | None = None, workers: int = 0,
                       device: str | None = None, runs=ACCEPTANCE_RUNS) -> dict:
    """The acceptance study (:func:`core.studies.tracking.acceptance.run`, the capture range off) on
    one scene, the runs of ``runs`` on the same frames: joint tracking as it is, with its last round
    from the prediction (:data:`core.tracking.frame_step.RESTART_FROM_PREDICTION`), with one round
    (``joint_rounds=1``), and sequential tracking; each joint run against the sequential one and
    the others against joint as it is (:func:`~core.studies.tracking.acceptance_goals.compare_modes`,
    the run compared as ``"joint"``)."""
    from dataclasses import replace

    import core.studies.tracking.acceptance as acc
    import core.tracking.frame_step as fs
    from core.studies.tracking.acceptance_goals import compare_modes

    t0 = time.perf_counter()
    ts = acc.tracking_scene(quick=quick, device=device, seed=seed, n_frames=n_frames)
    out = {"study": "core.studies.tracking.joint_gap (acceptance)", "seed": seed, "quick": quick, "runs": {}}
    base = acc.study_options
    for label, mode, restart, rounds in runs:
        fs.RESTART_FROM_PREDICTION = restart
        if rounds is not None:
            acc.study_options = lambda *a, r=rounds, **k: replace(base(*a, **k), joint_rounds=r)
        try:
            out["runs"][label] = acc.run(quick=quick, capture_trials=0, mode=mode, ts=ts, workers=workers,
                                         device=device)
        finally:
            fs.RESTART_FROM_PREDICTION = False
            acc.study_options = base
    got = out["runs"]
    for label in got:
        if label.startswith("joint") and "sequential" in got:
            out[f"{label}_vs_sequential"] = compare_modes({"joint": got[label],
                                                           "sequential": got["sequential"]})
        if label != "joint" and label.startswith("joint") and "joint" in got:
            out[f"{label}_vs_joint"] = compare_modes({"joint": got[label], "sequential": got["joint"]})
    out["total_s"] = round(time.perf_counter() - t0, 1)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.joint_gap",
                                description="Why joint tracking is slightly worse than sequential on the "
                                            "acceptance trial (module docs).")
    p.add_argument("--stored", default=None,
                   help="acceptance JSON with both modes (the stored analysis; the probe's history; "
                        "default the run of --seed, HISTORY_BY_SEED)")
    p.add_argument("--probe", action="store_true", help="also run the CPU probe (module docs)")
    p.add_argument("--frames", default="12,21,30,39,48,57,66,75,84,93", help="the probe's frames")
    p.add_argument("--draws", type=int, default=2, help="the probe's noise draws per frame")
    p.add_argument("--pixels", type=int, default=512)
    p.add_argument("--voxel", type=float, default=1.0)
    p.add_argument("--stretch", default=None, metavar="FIRST,N",
                   help="run track_stretch instead: the tracker on frames FIRST … FIRST+N-1 in each mode")
    p.add_argument("--runs", default=None,
                   help="with --stretch: the runs, comma-separated (default joint,joint_restart,sequential; "
                        "also joint_one_round)")
    p.add_argument("--acceptance", action="store_true",
                   help="run acceptance_restart instead (joint, from the prediction, one round; sequential)")
    p.add_argument("--quick", action="store_true", help="with --acceptance: 256², 1 mm, 20 frames")
    p.add_argument("--seed", type=int, default=0,
                   help="the trial's seed (--acceptance, --stretch, --probe; the stored run's by default)")
    p.add_argument("--workers", type=int, default=0, help="with --acceptance: processes for the chain")
    p.add_argument("--device", default=None)
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    if a.stretch:
        first, n = (int(v) for v in a.stretch.split(","))
        known = {r[0]: r for r in STRETCH_RUNS} | {k: (k, *v) for k, v in EXTRA_RUNS.items()}
        runs = STRETCH_RUNS if not a.runs else tuple(known[k.strip()] for k in a.runs.split(","))
        out = track_stretch(first=first, n=n, pixels=a.pixels, voxel=a.voxel, seed=a.seed, device=a.device,
                            runs=runs, progress=lambda r: print(json.dumps(r), file=sys.stderr, flush=True))
    elif a.acceptance:
        out = acceptance_restart(seed=a.seed, quick=a.quick, workers=a.workers, device=a.device)
    else:
        try:
            history = history_for(a.seed, a.stored)
        except ValueError as e:
            p.error(str(e))
        out = {"stored": stored(history)}
        if a.probe:
            out["probe"] = probe(frames=tuple(int(v) for v in a.frames.split(",")), draws=a.draws,
                                 pixels=a.pixels, voxel=a.voxel, history=history, seed=a.seed,
                                 device=a.device,
                                 progress=lambda r: print(json.dumps(r), file=sys.stderr, flush=True))
    from core.io.atomic import print_json

    print_json(out, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
