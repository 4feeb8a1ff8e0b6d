"""Frames over 4x their bound left unflagged, and the good frames the trajectory check flags, on every
stored run (``python -m core.studies.tracking.trajectory_silent``).

At b797131 the trajectory check (:mod:`core.tracking.flags_post`) with the pair rule left three
bone-frames over 4x their bound silent on the acceptance trial's seed 4: jointly the tibia's frames 0 and
7, and the calcaneus's frame 53 in both modes. This study asks, of each, what a user's run holds that sets
it apart from good frames (:func:`signals`), and measures the two rules made for them (:func:`counts`):
``along`` (:mod:`core.tracking.flags_along`: a frame next to a flagged one and off the same way) and
``one_sided`` (:mod:`core.tracking.flags_gaps`: a frame at a trial's end whose neighbours are flagged,
which the check cannot judge, flagged for review instead of noted), and what the check's limit costs for
the third (:func:`tradeoff`).

Runs (1024², 100 frames, jointly and sequentially, tracked on one NVIDIA H100; the check here on the CPU),
their poses rebuilt from the kept per-frame errors and the seed's truth as
:mod:`core.studies.tracking.trajectory_gaps` does (the per-frame checks' and the backward check's flags
kept: those frames neither judged nor in the fits):

* ``b797131``: seeds 0, 3 and 4 with the final stage at b797131 (``tracking_acceptance_seed{0,3,4}_final_
  b797131_h100.json``) — the runs the silent frames are in, so the rules' *form* was made on them (seed 4)
  and is not held out; the check without the two rules gives their stored flags exactly (``reproduced``);
* held out: ``nostage`` (seeds 0 and 4 at 445a8ae, seed 3 at 782362a, without the stage:
  ``tracking_joint_one_round_acceptance_seed{0,4}_h100.json``, ``tracking_joint_restart_acceptance_seed3_
  h100.json``), ``ea76c8b`` (seeds 0-2, their poses kept, ``tracking_silent_checks_per_frame_h100.json``),
  ``56350ae`` (seed 3, and seed 4 with the bones interpenetrating, ``4i``) and ``a5fd412`` (seed 4 with the
  bones kept apart) — older trackers, many more frames over 4x.

A frame is *over* when its translation or rotation error exceeds 4x the bone's RMS bound, *good* when both
are under 2x (frames between are neither). The numbers are in the module's JSON
(``resources/benchmarks/tracking_trajectory_silent_cpu.json``, at d904484, this 2-core x86_64 machine,
shared) and :mod:`core.tracking.flags_along`'s docs.

What sets the three apart (:func:`signals`; each value with the share of b797131's unflagged good frames
that reach as high). The JSONs keep per frame the error, the confidence σ and the flags with their reasons;
no score, stage move or searched pose but for the silent frames themselves, so those could not be set
against good frames. The tibia's frame 0 has no fit once frame 2 is flagged (with frame 2 in it, 1.12x the
median: 58 % of good frames as high); its backward registration landed 0.83x the median away (the limit
1.25x, not allowed under 1: seed 3's good first frame came back 1.00x); its σ 1.39x the bone's median (28 %)
and 1.05x the frames about it (58 %). Frame 7: 1.11x with frame 8 in its fit (58 %), 2.11x without (4 %),
the same way as frame 8 (cosine 0.99 about the long axis); σ 1.57x / 1.03x (18 % / 64 %). The calcaneus's
frame 53: 2.39x jointly and 2.20x sequentially (1.3 % and 2.8-3.9 %) with no flagged neighbour, σ 1.15x /
1.10x (47 % / 43 %), within its 2σ (0.18 mm against σx 0.23 mm): the tail of the bone's spread along x.

So frame 7 is caught by its residual without its flagged neighbour and its direction (``along``), frame 0
only by sending a trial's end beside flagged frames for review (``one_sided``); together, silent over 4x
4 -> 2 of 17, good frames flagged 65 -> 87 of 1385 (4.7 -> 6.3 %); held out 282 -> 266 of 455 and 83 -> 126
of 2800 (3.0 -> 4.5 %). Frame 53 has no signal of its own: the check's limit (:func:`tradeoff`, the two
rules on) 2.5 / 2.4 / 2.3 / 2.2 / 2.1 / 2.0 leaves 2 / 2 / 1 / 1 / 1 / 1 silent on b797131 for 87 / 105 /
127 / 180 / 221 / 268 good frames flagged (2.3 catches it jointly, not sequentially; at 2.2 and below both
are caught but the joint tibia frame 0 gets a fit and is left silent again), held out 126 / 182 / 271 / 309
/ 369 / 440 of 2800 good frames flagged (silent 266 / 260 / 236 / 222 / 208 / 201 of 455). No limit reaches
zero on these runs, and 2.3 already flags 9.2 % of b797131's good frames. The search's pose before the final
stage, kept by the later runs (b941103, d262386), sets it apart: :mod:`core.tracking.flags_stage` (24ec33e)
flags it in both modes (:mod:`core.studies.tracking.stage_silent`).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from core.studies.tracking.trajectory_gaps import BENCH, BONES, KEPT, _rebuilt, truth

__all__ = ["AFTER", "BEFORE", "SETS", "counts", "injected", "main", "runs", "signals", "tradeoff"]

#: Set name -> (label, scene seed, the bones kept apart, the acceptance study's JSON) of each stored run.
SETS = {
    "b797131": [(s, s, True, f"tracking_acceptance_seed{s}_final_b797131_h100.json") for s in "034"],
    "nostage": [("0", "0", True, "tracking_joint_one_round_acceptance_seed0_h100.json"),
                ("3", "3", True, "tracking_joint_restart_acceptance_seed3_h100.json"),
                ("4", "4", True, "tracking_joint_one_round_acceptance_seed4_h100.json")],
    "ea76c8b": [],  # the kept poses of seeds 0-2 (:data:`KEPT`)
    "56350ae": [("3", "3", False, "tracking_acceptance_seed3_h100.json"),
                ("4i", "4", False, "tracking_acceptance_seed4_interpenetrating_h100.json")],
    "a5fd412": [("4", "4", True, "tracking_acceptance_seed4_h100.json")],
}
#: The check without the rules this study measures (the check at b797131).
BEFORE = {"along": None, "one_sided": False, "ends": False}
#: The check with them, as measured (d904484; the trial's ends as then: :mod:`core.tracking.flags_ends`
#: came after, :mod:`core.studies.tracking.trajectory_ends` measures it).
AFTER = {"ends": False}


def _row(sets, label, mode, b, E, S, own, bound, c, traj=None):
    ratio = np.c_[np.linalg.norm(E[:, :3], axis=1), np.linalg.norm(E[:, 3:], axis=1)] / bound
    return {"set": sets, "run": f"{label}_{mode}", "mode": mode, "bone": b, "E": E, "S": S, "own": own,
            "bound": bound, "ratio": ratio, "over": ratio.max(axis=1) > 4.0, "good": ratio.max(axis=1) < 2.0,
            "c": c, "stored": traj}


def runs(bench: Path = BENCH, sets=None, table=None):
    """Dicts of every stored run and bone (``sets``: only those of :data:`SETS`): ``set``, ``run``
    (label and mode), ``mode``, ``bone``, the rebuilt poses ``P`` (NaN where the per-frame or backward
    checks flagged), ``E`` the errors, ``S`` the confidence σ (or None), ``own`` those flags, ``ratio``
    each frame's error over the bound (mm, degrees), ``bound`` (RMS mm, degrees), ``over``, ``good``,
    centre ``c``, ``stored`` the run's own trajectory flags (b797131's and d262386's; None for the older
    sets, judged by an older check), ``T`` the true poses (the rebuilt runs only). ``table``: set name ->
    runs as :data:`SETS` (default), for another study's sets."""
    from core.studies.tracking.silent_checks import load

    center = {b: g["center"] for b, g in load(f"{bench / KEPT}#0_joint").items()}
    truths: dict = {}
    for name, items in (SETS if table is None else table).items():
        if sets is not None and name not in sets:
            continue
        if name == "ea76c8b":
            for s in range(3):
                for mode in ("joint", "sequential"):
                    for b, g in load(f"{bench / KEPT}#{s}_{mode}").items():
                        bd = np.array([g["bound"]["rms_mm"], g["bound"]["rms_deg"]])
                        r = _row(name, str(s), mode, b, g["err"], g["sigma"], g["own"], bd, g["center"])
                        r["P"] = g["pose"].copy()
                        r["P"][g["own"]] = np.nan
                        yield r
            continue
        for label, seed, apart, file in items:
            d = json.loads((bench / file).read_text())
            T = truths.setdefault((seed, apart), truth(int(seed), apart=apart))
            for mode in ("joint", "sequential"):
                for b in BONES:
                    t = d["runs"][mode]["tracking"][b]
                    n = T.shape[1]
                    E = np.full((n, 6), np.nan)
                    E[t["frames_with_pose"]] = t["per_frame_error"]
                    S = None
                    if "per_frame_sigma" in t:
                        S = np.full((n, 6), np.nan)
                        S[t["frames_with_pose"]] = t["per_frame_sigma"]
                    traj = set(t["flagged_off_trajectory_only"])
                    own = np.zeros(n, dtype=bool)
                    own[[f for f in t["flagged_frames"] if f not in traj]] = True
                    cr = t["cramer_rao"]
                    stored = sorted(traj) if name in ("b797131", "d262386") else None  # older: older checks
                    r = _row(name, label, mode, b, E, S, own, np.array([cr["rms_mm"], cr["rms_deg"]]),
                             center[b], stored)
                    r["T"] = T[BONES.index(b)]
                    r["P"] = _rebuilt(E, r["T"], center[b])
                    r["P"][own] = np.nan
                    yield r


def _review(r, **kw):
    from core.tracking.flags_post import trajectory_review

    return trajectory_review(np.arange(len(r["P"])), r["P"], r["c"], **kw)[0]


def _ok(r):
    return np.all(np.isfinite(r["P"].reshape(len(r["P"]), -1)), axis=1)


def _tally(rs, flags) -> dict:
    """Per set, per set and mode and bone: over, silent, good, good flagged (``flags``: per run, the
    frames flagged, in ``rs``'s order)."""
    out: dict = {}
    for r, fl in zip(rs, flags, strict=True):
        ok = _ok(r)
        hit = np.isin(np.arange(len(ok)), list(fl))
        for key in (r["set"], f"{r['set']}/{r['mode']}/{r['bone']}"):
            s = out.setdefault(key, {"over": 0, "silent": 0, "good": 0, "good_flagged": 0})
            s["over"] += int((r["over"] & ok).sum())
            s["silent"] += int((r["over"] & ok & ~hit).sum())
            s["good"] += int((r["good"] & ok).sum())
            s["good_flagged"] += int((r["good"] & ok & hit).sum())
            if r["set"] == "b797131" and "/" not in key:  # the few left: named
                s.setdefault("silent_frames", []).extend(
                    f"{r['run']}/{r['bone']}/{f}" for f in np.flatnonzero(r["over"] & ok & ~hit))
    return out


def counts(rs) -> dict:
    """The check without the two rules (:data:`BEFORE`) and with them (the defaults), per set and per set,
    mode and bone: frames over 4x, silent, good frames and good frames flagged; each run's frames the
    rules flag (their error over the bound, over 4x or not, the message) and its silent frames after;
    and whether the check without them gives each run's stored flags (where kept)."""
    before = [_review(r, **BEFORE) for r in rs]
    after = [_review(r, **AFTER) for r in rs]
    a, b = _tally(rs, before), _tally(rs, after)
    per = {}
    for k in a:
        per[k] = {"over": a[k]["over"], "good": a[k]["good"], "silent_before": a[k]["silent"],
                  "silent_after": b[k]["silent"], "good_flagged_before": a[k]["good_flagged"],
                  "good_flagged_after": b[k]["good_flagged"]}
        if "silent_frames" in a[k]:
            per[k].update(silent_frames_before=a[k]["silent_frames"],
                          silent_frames_after=b[k]["silent_frames"])
    runs_out = {}
    for r, fb, fa in zip(rs, before, after, strict=True):
        ok = _ok(r)
        row = {"silent_after": [int(f) for f in np.flatnonzero(r["over"] & ok) if f not in fa],
               "newly_flagged": {str(f): {"x_bound": [round(float(x), 2) for x in r["ratio"][f]],
                                          "over_4x": bool(r["over"][f]), "good": bool(r["good"][f]),
                                          "message": fa[f]} for f in sorted(set(fa) - set(fb))},
               "unflagged": sorted(set(fb) - set(fa))}
        if r["stored"] is not None:
            row["reproduced"] = sorted(fb) == r["stored"]
        runs_out.setdefault(f"{r['set']}/{r['run']}", {})[r["bone"]] = row
    return {"per_set": {k: v for k, v in per.items() if "/" not in k},
            "per_set_mode_bone": {k: v for k, v in per.items() if "/" in k}, "runs": runs_out}


def tradeoff(rs, limits=(2.5, 2.4, 2.3, 2.2, 2.1, 2.0), alongs=(None, 0.0, 0.5, 0.8)) -> dict:
    """Silent frames over 4x and good frames flagged per set: the check's limit (``limit``, the rules'
    defaults otherwise), and the rule's cosine (``along``; None: off)."""
    out = {"limit": {}, "along": {}}
    for lim in limits:
        t = _tally(rs, [_review(r, limit=lim, **AFTER) for r in rs])
        out["limit"][f"{lim:g}"] = {k: v for k, v in t.items() if "/" not in k}
    for al in alongs:
        t = _tally(rs, [_review(r, along=al, **AFTER) for r in rs])
        out["along"][str(al)] = {k: v for k, v in t.items() if "/" not in k}
    return out


def _z(r, kw):
    """Per frame: its first residual (every good neighbour in its fit) and its residual with the frames
    the check flags (``kw``: its keywords) left out, over the bone's median, the larger of mm and degrees
    (NaN where none), and the frames flagged."""
    from core.tracking.flags_fit import _Table
    from core.tracking.flags_post import DEGREE, HALF_WINDOW

    P, ok = r["P"], _ok(r)
    t = _Table(np.arange(len(P)), P, ok, r["c"], HALF_WINDOW, DEGREE)
    first = t.residuals(ok)
    med = np.median(first[np.isfinite(first).all(axis=1)], axis=0)
    fl = _review(r, **kw)
    use = ok & ~np.isin(np.arange(len(P)), list(fl))
    R = np.full_like(first, np.nan)
    for i in range(len(P)):
        if ok[i]:
            u = use.copy()
            u[i] = True
            R[i] = t.residual(i, u)
    return (first / med).max(axis=1), (R / med).max(axis=1), fl


#: The silent frames at b797131 (set, run, bone, frame).
SILENT = (("b797131", "4_joint", "tibia", 0), ("b797131", "4_joint", "tibia", 7),
          ("b797131", "4_joint", "calcaneus", 53), ("b797131", "4_sequential", "calcaneus", 53))


def signals(rs, frames=SILENT):
    """For each of ``frames`` (set, run, bone, frame): what the run holds about it — its first residual
    and its residual with the flagged frames left out (over the bone's median), its σ over the bone's
    median σ and over the median of the 10 frames about it (the largest axis), each with the share of the
    set's good frames the check leaves unflagged (without the two rules) that reach as high."""
    vals: dict = {}
    for r in rs:
        first, without, fl = _z(r, BEFORE)
        ok = _ok(r)
        S = r["S"]
        sb = sr = np.full(len(ok), np.nan)
        if S is not None:
            sb = (S / np.nanmedian(S, axis=0)).max(axis=1)
            recent = np.array([np.nanmedian(S[max(0, i - 5):i + 6], axis=0) for i in range(len(S))])
            sr = (S / recent).max(axis=1)
        vals[(r["set"], r["run"], r["bone"])] = (first, without, sb, sr, ok & r["good"] & ~np.isin(
            np.arange(len(ok)), list(fl)))
    out = []
    names = ("first_residual", "residual_without_flagged", "sigma_over_bone", "sigma_over_recent")
    for key in frames:
        v = vals[key[:3]]
        row = {"frame": "/".join(str(k) for k in key)}
        for m, name in enumerate(names):
            x = float(v[m][key[3]])
            pool = np.concatenate([w[m][w[4]] for k, w in vals.items() if k[0] == key[0]])
            pool = pool[np.isfinite(pool)]
            row[name] = None if not np.isfinite(x) else round(x, 2)
            row[f"{name}_good_share_as_high"] = (None if not np.isfinite(x) or not len(pool)
                                                 else round(float(np.mean(pool >= x)), 4))
        out.append(row)
    return out


def injected(rs, k=(4.3, 6.0), every: int = 3) -> dict:
    """Seed 4's tibia frames 7 and 8 in small, put into ``rs``'s tracks: frames ``f`` and ``f + 1`` turned
    ``k`` × the bone's RMS rotation bound more about the error's z axis (the same way, signs alternating
    between pairs), every ``every``-th frame 4-94 in turn, each on its own; how often the check without
    the two rules and with them flags frame ``f`` (the smaller), and both."""
    out = {"before": {"f": 0, "both": 0}, "after": {"f": 0, "both": 0}, "pairs": 0}
    for r in rs:
        for f in range(4, 95, every):
            E = r["E"].copy()
            if not np.all(np.isfinite(E[f:f + 2])) or r["own"][f:f + 2].any():
                continue
            sign = 1 if (f // every) % 2 else -1
            E[f, 5] += sign * k[0] * r["bound"][1]
            E[f + 1, 5] += sign * k[1] * r["bound"][1]
            q = dict(r, P=_rebuilt(E, r["T"], r["c"]))
            q["P"][r["own"]] = np.nan
            out["pairs"] += 1
            for name, kw in (("before", BEFORE), ("after", AFTER)):
                got = _review(q, **kw)
                out[name]["f"] += f in got
                out[name]["both"] += f in got and f + 1 in got
    return out


def main(argv=None) -> int:
    from ._study_cli import stored_parser, write_stamped

    p = stored_parser("trajectory_silent", __doc__, "the results")
    p.add_argument("--no-tradeoff", action="store_true", help="skip the limit and cosine sweeps")
    a = p.parse_args(argv)
    rs = list(runs())
    got = {"signals": signals(rs), **counts(rs)}
    got["reproduced"] = all(row.get("reproduced", True) for r in got["runs"].values() for row in r.values())
    seed0 = [r for r in rs if r["set"] == "b797131" and r["run"].startswith("0_")]
    got["injected_seed0_b797131"] = injected(seed0)
    if not a.no_tradeoff:
        got["tradeoff"] = tradeoff(rs)
    for row in got["signals"]:
        print(row)
    for key, s in got["per_set"].items():
        print(f"{key}: silent {s['silent_before']} -> {s['silent_after']} of {s['over']}, good flagged "
              f"{s['good_flagged_before']} -> {s['good_flagged_after']} of {s['good']}")
    print("injected pairs (seed 0):", got["injected_seed0_b797131"])
    print("stored trajectory flags reproduced:", got["reproduced"])
    if a.out:
        write_stamped(a.out, "core.studies.tracking.trajectory_silent", argv, a.machine_name, got)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
