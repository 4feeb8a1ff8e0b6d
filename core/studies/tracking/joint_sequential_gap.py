"""Where joint tracking loses to sequential on a stored acceptance run, from its per-frame errors
(``python -m core.studies.tracking.joint_sequential_gap [--seed 4 --bone calcaneus --commit b941103]``).

The acceptance study keeps, per mode and bone, every frame's error (mm, degrees) and, where the final stage
moved the pose, the search's pose's error before it (``per_frame_signals.search_error``). For one bone this
study gives: the RMS translation error jointly and sequentially, the paired statistics of the difference
(bootstrap intervals of the RMS difference over frames, iid and in 5-frame blocks, as the errors of
neighbouring frames are correlated; Wilcoxon's signed-rank and the t test on the per-frame squared-norm
difference), the frames and axes that carry the difference (each frame's squared-norm difference, each
axis's share of the sum), the same over frame windows and for the search's poses (does the search or the
final stage lose), and the other bones' differences in the frames that carry it (do the bones trade
evidence there).

Measured (seed 4's calcaneus at b941103, ``tracking_acceptance_seed4_final_b941103_h100.json``, tracked on
one NVIDIA H100; the statistics on this 2-core x86_64 machine): ``resources/benchmarks/
tracking_joint_sequential_gap_cpu.json`` and the README's paragraph on it.
"""

from __future__ import annotations

import json

import numpy as np

__all__ = ["gap", "main"]


def _rms(E: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum(E[:, :3] ** 2, axis=1))))


def _searched(t: dict, E: np.ndarray) -> np.ndarray:
    S = E.copy()
    for f, v in enumerate(t["per_frame_signals"]["search_error"]):
        if v is not None:
            S[f] = v
    return S


def gap(d: dict, bone: str, *, draws: int = 100000, block: int = 5, seed: int = 0, top: int = 10) -> dict:
    """The comparison of the module docs for ``bone`` of an acceptance study's JSON ``d`` (both modes kept,
    every frame with a pose in both)."""
    from scipy import stats

    t = {m: d["runs"][m]["tracking"] for m in ("joint", "sequential")}
    E = {m: np.array(t[m][bone]["per_frame_error"], float) for m in t}
    S = {m: _searched(t[m][bone], E[m]) for m in t}
    n = len(E["joint"])
    nj, ns = (np.linalg.norm(E[m][:, :3], axis=1) for m in ("joint", "sequential"))
    dd = nj ** 2 - ns ** 2
    rng = np.random.default_rng(seed)
    iid, blk = [], []
    for _ in range(draws):
        i = rng.integers(0, n, n)
        iid.append(np.sqrt(np.mean(nj[i] ** 2)) - np.sqrt(np.mean(ns[i] ** 2)))
        st = rng.integers(0, n - block + 1, n // block)
        i = (st[:, None] + np.arange(block)).ravel()
        blk.append(np.sqrt(np.mean(nj[i] ** 2)) - np.sqrt(np.mean(ns[i] ** 2)))
    order = np.argsort(-dd)
    cum = np.cumsum(dd[order])
    carry = np.sort(order[: int(np.argmax(cum >= dd.sum())) + 1] if dd.sum() > 0 else order[:0])
    axes = E["joint"] ** 2 - E["sequential"] ** 2
    out = {"bone": bone, "frames": n,
           "rms_mm": {"joint": round(_rms(E["joint"]), 5), "sequential": round(_rms(E["sequential"]), 5)},
           "rms_diff_mm": round(_rms(E["joint"]) - _rms(E["sequential"]), 5),
           "interval95_iid": np.round(np.quantile(iid, [0.025, 0.975]), 6).tolist(),
           f"interval95_blocks_of_{block}": np.round(np.quantile(blk, [0.025, 0.975]), 6).tolist(),
           "wilcoxon_p": round(float(stats.wilcoxon(dd).pvalue), 3),
           "t_test_p": round(float(stats.ttest_1samp(dd, 0.0).pvalue), 3),
           "frames_worse_jointly": int((dd > 0).sum()),
           "per_axis_rms": {m: np.round(np.sqrt(np.mean(E[m] ** 2, axis=0)), 4).tolist() for m in E},
           "axis_share_of_squared_diff": np.round(np.r_[axes[:, :3].sum(0) / axes[:, :3].sum(),
                                                        axes[:, 3:].sum(0) / axes[:, 3:].sum()], 3).tolist(),
           "rms_deg": {m: round(float(np.sqrt(np.mean(np.sum(E[m][:, 3:] ** 2, axis=1)))), 5) for m in E},
           "top_frames": [[int(f), round(float(dd[f]) * 1e3, 2)] for f in order[:top]],
           "top_frames_unit": "squared translation error, joint minus sequential, 1e-3 mm^2",
           "frames_carrying_the_sum": sorted(int(f) for f in carry)}
    lo, hi = (int(min(carry)), int(max(carry)) + 1) if len(carry) else (0, 0)
    win = {}
    for a, b in ((0, n), (0, lo), (lo, hi), (hi, n)):
        if b > a:
            win[f"{a}-{b - 1}"] = {f"{k}_{m}": round(_rms(X[m][a:b]), 4)
                                   for k, X in (("search", S), ("final", E)) for m in ("joint", "sequential")}
    out["windows_rms_mm"] = win
    out["stage_improved_frames"] = {m: int((np.linalg.norm(E[m][:, :3], axis=1)
                                            < np.linalg.norm(S[m][:, :3], axis=1)).sum()) for m in E}
    mv = {m: np.array([v or 0.0 for v in t[m][bone]["per_frame_signals"]["stage_move_mm"]]) for m in t}
    out["stage_move_mm"] = {m: {"median": round(float(np.median(v)), 4),
                                "carrying_frames": np.round(v[carry], 4).tolist()} for m, v in mv.items()}
    others = {}
    for b in t["joint"]:
        if b == bone:
            continue
        Dj, Ds = (np.array(t[m][b]["per_frame_error"], float) for m in ("joint", "sequential"))
        D = Dj - Ds
        others[b] = {"max_abs_diff_mm_in_carrying_frames": round(float(np.abs(D[carry, :3]).max()), 4)
                     if len(carry) else None,
                     "rms_mm": {m: round(_rms(np.array(t[m][b]["per_frame_error"], float)), 5) for m in t}}
    out["other_bones"] = others
    return out


def main(argv=None) -> int:
    from ._study_cli import stored_parser, write_stamped
    from .trajectory_gaps import BENCH

    p = stored_parser("joint_sequential_gap", __doc__)
    p.add_argument("--seed", type=int, default=4)
    p.add_argument("--bone", default="calcaneus")
    p.add_argument("--commit", default="b941103", help="the stored run's commit (its file name)")
    a = p.parse_args(argv)
    file = f"tracking_acceptance_seed{a.seed}_final_{a.commit}_h100.json"
    got = {"run": file, **gap(json.loads((BENCH / file).read_text()), a.bone)}
    print(json.dumps(got, indent=1))
    if a.out:
        write_stamped(a.out, "core.studies.tracking.joint_sequential_gap", argv, a.machine_name, got)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
