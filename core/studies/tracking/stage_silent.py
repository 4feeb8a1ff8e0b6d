"""The last silent frame over 4x its bound (seed 4's calcaneus, frame 53) and the rule made for it, on every
stored run (``python -m core.studies.tracking.stage_silent``).

At b941103 the acceptance trial's seeds 0 and 3 had every frame over 4x its Cramér–Rao bound flagged;
on seed 4 the calcaneus's frame 53 was over 4x (4.27x jointly, 4.13x sequentially, in translation) and
not flagged, in both modes. This study asks what a run holds about it (:func:`signals`: each signal with
the share of the unflagged good frames that reach as high) and measures the rule made for it,
:mod:`core.tracking.flags_stage` (:func:`counts`: frames over 4x left silent and good frames flagged,
before and with it, per set; :func:`sweep`: its two limits; :func:`injected`: frames like frame 53 put
into the held-out seeds' tracks).

Runs (1024², 100 frames, jointly and sequentially, tracked on one NVIDIA H100; the check run here on the
CPU), their poses rebuilt from the kept per-frame errors and the seed's truth as
:mod:`core.studies.tracking.trajectory_gaps` does (the per-frame checks' flags kept: those frames neither
judged nor in the fits): ``b941103`` and ``d262386`` (seeds 0, 3, 4 with the final stage:
``tracking_acceptance_seed{0,3,4}_final_{b941103,d262386}_h100.json``), which keep each frame's
``per_frame_signals`` — the search's pose's error before the stage among them, so the search's pose is
rebuilt too (the pose itself where the stage's move was rejected); and the older sets of
:mod:`core.studies.tracking.trajectory_silent` (``b797131``, ``nostage``, ``ea76c8b``, ``56350ae``,
``a5fd412``), which keep no search's pose: the rule cannot act on them (it neither catches nor costs
there), and they are counted to show the check is otherwise unchanged. *Over*: the translation or
rotation error over 4x the bone's RMS bound; *good*: both under 2x; *mid*: neither.

The numbers are in ``resources/benchmarks/tracking_stage_silent_cpu.json`` and the docs of
:mod:`core.tracking.flags_stage`.
"""

from __future__ import annotations

import json

import numpy as np

from core.studies.tracking.trajectory_ends import TABLE as ENDS_TABLE
from core.studies.tracking.trajectory_silent import _ok, _review

__all__ = ["SIGNAL_SETS", "TABLE", "counts", "injected", "main", "runs", "signals", "sweep"]

#: The stored runs: b941103's (the silent frame's) and :mod:`core.studies.tracking.trajectory_ends`' sets.
TABLE = {"b941103": [(s, s, True, f"tracking_acceptance_seed{s}_final_b941103_h100.json") for s in "034"],
         **ENDS_TABLE}
#: The sets whose runs keep the search's pose's error (``per_frame_signals``).
SIGNAL_SETS = ("b941103", "d262386")
#: The silent frame (set, run, bone, frame) in each signal set and mode.
SILENT = tuple((s, f"4_{m}", "calcaneus", 53) for s in SIGNAL_SETS for m in ("joint", "sequential"))


def runs(table=None):
    """:func:`core.studies.tracking.trajectory_silent.runs` over :data:`TABLE` (or ``table``, alike), each
    with ``searched`` the search's poses (None: the older sets) and, for :data:`SIGNAL_SETS`, ``sig`` the
    stored ``per_frame_signals`` (b941103's with ``stored``, its stored trajectory flags)."""
    from core.studies.tracking.trajectory_gaps import BENCH, _rebuilt
    from core.studies.tracking.trajectory_silent import runs as stored

    table = TABLE if table is None else table
    for r in stored(table=table):
        r["searched"] = None
        if r["set"] in SIGNAL_SETS:
            file = dict((lab, f) for lab, _, _, f in table[r["set"]])[r["run"].split("_")[0]]
            t = json.loads((BENCH / file).read_text())["runs"][r["mode"]]["tracking"][r["bone"]]
            sig = t["per_frame_signals"]
            if r["set"] == "b941103":
                r["stored"] = sorted(t["flagged_off_trajectory_only"])
            E = r["E"].copy()
            for k, f in enumerate(t["frames_with_pose"]):
                if sig["search_error"][k] is not None:
                    E[f] = sig["search_error"][k]
            r["searched"] = _rebuilt(E, r["T"], r["c"])
            r["searched"][~_ok(r)] = np.nan
            r["sig"] = {k: [None] * len(r["E"]) for k in sig}
            for k, v in sig.items():
                for m, f in enumerate(t["frames_with_pose"]):
                    r["sig"][k][f] = v[m]
        yield r


def _kw(r, **kw):
    return {**kw, "searched": r["searched"]} if r["searched"] is not None else kw


def _tally(rs, flags) -> dict:
    """Per set: frames over 4x, silent, good, good flagged, mid flagged; the silent frames named."""
    out: dict = {}
    for r, fl in zip(rs, flags, strict=True):
        ok = _ok(r)
        hit = np.isin(np.arange(len(ok)), list(fl))
        mid = ~r["over"] & ~r["good"]
        s = out.setdefault(r["set"], {"over": 0, "silent": 0, "good": 0, "good_flagged": 0, "mid_flagged": 0,
                                      "silent_frames": []})
        s["over"] += int((r["over"] & ok).sum())
        s["silent"] += int((r["over"] & ok & ~hit).sum())
        s["good"] += int((r["good"] & ok).sum())
        s["good_flagged"] += int((r["good"] & ok & hit).sum())
        s["mid_flagged"] += int((mid & ok & hit).sum())
        s["silent_frames"] += [f"{r['run']}/{r['bone']}/{f}" for f in np.flatnonzero(r["over"] & ok & ~hit)]
    return out


def counts(rs) -> dict:
    """The check before the rule (``stage=None``) and with it (the defaults, the search's poses given where
    kept): per set (:func:`_tally`), the frames the rule flags (their error over the bound, the message),
    and whether the check before gives b941103's stored flags."""
    before = [_review(r, stage=None) for r in rs]
    after = [_review(r, **_kw(r)) for r in rs]
    a, b = _tally(rs, before), _tally(rs, after)
    new = {}
    reproduced = []
    for r, fb, fa in zip(rs, before, after, strict=True):
        if r["set"] == "b941103":
            reproduced.append(sorted(fb) == r["stored"])
        for f in sorted(set(fa) - set(fb)):
            new.setdefault(f"{r['set']}/{r['run']}/{r['bone']}", {})[str(f)] = {
                "x_bound": [round(float(x), 2) for x in r["ratio"][f]], "over_4x": bool(r["over"][f]),
                "good": bool(r["good"][f]), "message": fa[f]}
    return {"per_set": {k: {"before": a[k], "after": b[k]} for k in a}, "newly_flagged": new,
            "unflagged_by_rule": sum(len(set(fb) - set(fa)) for fb, fa in zip(before, after, strict=True)),
            "b941103_reproduced": bool(reproduced) and all(reproduced)}


def sweep(rs, stages=(0.8, 0.85, 0.9, 0.95), ratios=(0.3, 0.4, 0.5, 0.6)) -> dict:
    """Over the runs with a search's pose: silent frames and good (and mid) frames flagged for each
    ``stage`` and ``stage_ratio``, and the check before."""
    sig = [r for r in rs if r["searched"] is not None]
    tot = {"before": _sum(_tally(sig, [_review(r, stage=None) for r in sig]))}
    for st in stages:
        for q in ratios:
            got = [_review(r, **_kw(r, stage=st, stage_ratio=q)) for r in sig]
            tot[f"{st:g}/{q:g}"] = _sum(_tally(sig, got))
    return tot


def _sum(t: dict) -> dict:
    keys = ("over", "silent", "good", "good_flagged", "mid_flagged")
    out = {k: sum(v[k] for v in t.values()) for k in keys}
    out["silent_frames"] = [f"{s}/{x}" for s, v in t.items() for x in v["silent_frames"]]
    return out


def injected(rs, *, k: float = 4.3, every: int = 3, sets=("b941103",), seeds=("0", "3")) -> dict:
    """Frames like frame 53 put into the held-out tracks (``sets``' runs of ``seeds``, which the rule was
    not made on): frame ``f`` (every ``every``-th of 4-94 in turn, each on its own, a good frame not
    flagged by the per-frame checks) moved along x, the way its error already points, until its
    translation error is ``k`` × the bone's RMS bound; its search's pose the frame's own pose before
    (the stage moved it off). Per bone and in all: the frames put in, and those the check flags before
    the rule and with it."""
    from core.studies.tracking.trajectory_gaps import _rebuilt

    out: dict = {"all": {"frames": 0, "before": 0, "after": 0}}
    for r in rs:
        if r["set"] not in sets or r["run"].split("_")[0] not in seeds:
            continue
        row = out.setdefault(r["bone"], {"frames": 0, "before": 0, "after": 0})
        for f in range(4, 95, every):
            e = r["E"][f]
            if r["own"][f] or not r["good"][f] or not np.all(np.isfinite(e)):
                continue
            E = r["E"].copy()
            t = k * r["bound"][0]
            rest = float(e[1] ** 2 + e[2] ** 2)
            if t * t <= rest:
                continue
            E[f, 0] = np.copysign(np.sqrt(t * t - rest), e[0] if e[0] != 0 else 1.0)
            P = _rebuilt(E, r["T"], r["c"])
            P[~_ok(r)] = np.nan
            S = np.full_like(P, np.nan)
            S[f] = r["P"][f]
            q = dict(r, P=P)
            before = f in _review(q, stage=None)
            after = f in _review(q, searched=S)
            for w in (row, out["all"]):
                w["frames"] += 1
                w["before"] += before
                w["after"] += after
    return out


def _share(x: float, pool: np.ndarray):
    pool = pool[np.isfinite(pool)]
    return None if not np.isfinite(x) or not len(pool) else round(float(np.mean(pool >= x)), 4)


def _signal_table(r, fl) -> dict:
    """Per frame of a signal run: each signal (larger: more suspect)."""
    from core.tracking.flags_fit import _Table
    from core.tracking.flags_post import DEGREE, HALF_WINDOW
    from core.tracking.flags_stage import searched_residual

    n, sg = len(r["P"]), r["sig"]
    ok = _ok(r)
    use = ok & ~np.isin(np.arange(n), list(fl))
    t = _Table(np.arange(n), r["P"], ok, r["c"], HALF_WINDOW, DEGREE, True)
    R = np.full((n, 2), np.nan)
    Rs = np.full((n, 2), np.nan)
    for i in np.flatnonzero(ok):
        u = use.copy()
        u[i] = True
        R[i] = t.residual(int(i), u)
        got = searched_residual(t, int(i), u, r["searched"][i])
        if got is not None:
            Rs[i] = got
    med = np.nanmedian(R[use], axis=0)

    def arr(k):
        return np.array([np.nan if v is None else float(v) for v in sg[k]])

    def over_median(x):
        return x / np.nanmedian(x[use])

    sc = arr("score")
    local = np.array([np.nanmedian(sc[max(0, i - 4):i + 5]) for i in range(n)])
    move = np.array([np.zeros(6) if v is None else np.abs(v) for v in sg["stage_move"]], float)
    S = r["S"]
    z, zs = (R / med).max(axis=1), (Rs / med).max(axis=1)
    return {"residual": z, "searched_residual": zs, "residual_minus_searched": z - zs,
            "searched_over_residual_inverse": z / np.maximum(zs, 1e-9),
            "score_drop_local": local - sc, "evaluations": over_median(arr("evaluations")),
            "stage_steps": arr("stage_steps"), "stage_move_mm": over_median(arr("stage_move_mm")),
            "stage_move_deg": over_median(arr("stage_move_deg")),
            "stage_move_over_sigma": (move / S).max(axis=1),
            "sigma_over_bone": (S / np.nanmedian(S[use], axis=0)).max(axis=1),
            "sigma_over_recent": (S / np.array([np.nanmedian(S[max(0, i - 5):i + 6], axis=0)
                                                for i in range(n)])).max(axis=1),
            "_pool": use & r["good"]}


def signals(rs, frames=SILENT) -> list:
    """For each of ``frames``: every signal's value and the share of its set's unflagged good frames (the
    check before the rule) that reach as high."""
    tabs = {}
    for r in rs:
        if r["searched"] is not None:
            tabs[(r["set"], r["run"], r["bone"])] = _signal_table(r, _review(r, stage=None))
    out = []
    for key in frames:
        v = tabs[key[:3]]
        row = {"frame": "/".join(str(k) for k in key)}
        for name, x in v.items():
            if name.startswith("_"):
                continue
            pool = np.concatenate([w[name][w["_pool"]] for k, w in tabs.items() if k[0] == key[0]])
            row[name] = [None if not np.isfinite(x[key[3]]) else round(float(x[key[3]]), 3),
                         _share(float(x[key[3]]), pool)]
        out.append(row)
    return out


def main(argv=None) -> int:
    from ._study_cli import stored_parser, write_stamped

    p = stored_parser("stage_silent", __doc__)
    p.add_argument("--no-sweep", action="store_true", help="skip the limits' sweep")
    a = p.parse_args(argv)
    rs = list(runs())
    got = {"signals": signals(rs), **counts(rs)}
    if not a.no_sweep:
        got["sweep"] = sweep(rs)
    got["injected"] = {f"{k:g}": injected(rs, k=k) for k in (4.3, 5.0)}
    for row in got["signals"]:
        print(row["frame"], {k: v for k, v in row.items() if k != "frame"})
    for k, v in got["per_set"].items():
        b, n = v["before"], v["after"]
        print(f"{k}: silent {b['silent']} -> {n['silent']} of {b['over']}, good flagged "
              f"{b['good_flagged']} -> {n['good_flagged']} of {b['good']}, mid flagged {b['mid_flagged']} -> "
              f"{n['mid_flagged']}")
    print("b941103 stored flags reproduced by the check before:", got["b941103_reproduced"])
    for k, v in got["injected"].items():
        print(f"injected {k}x:", v)
    for k, v in got.get("sweep", {}).items():
        print(k, {n: v[n] for n in ("silent", "good_flagged", "mid_flagged")})
    if a.out:
        write_stamped(a.out, "core.studies.tracking.stage_silent", argv, a.machine_name, got)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
