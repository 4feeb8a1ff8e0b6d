"""Where a stored acceptance run's excess over the Cramér–Rao bound comes from, from its per-frame errors
(``python -m core.studies.tracking.excess_decomposition [FILES …] [--out JSON]``).

The acceptance study (:mod:`core.studies.tracking.acceptance`) keeps, per mode and bone, every frame's error
``e_t`` (mm ×3, degrees ×3 about lab axes through the centroid) and the bone's known-tissue bound ``C`` (mean
covariance over every tenth frame: ``sigma`` per axis, ``rms_mm = sqrt(tr C_tt)``, ``rms_deg``). Its goal's
ratio is ``ρ = sqrt(mean_t |e_t|²) / sqrt(tr C)`` per unit. With ``B² = tr C`` of a unit, this study splits
``ρ² = Σ_axes (m_i² + s_i²) / B²`` (``m_i`` the mean error over the frames, ``s_i²`` its variance) into

* ``bias`` — ``Σ m_i² / B²``: an error the same in every frame (a bias of the cost or its model);
* ``white`` — ``Σ w_i² / B²`` with ``w_i² = mean((e_{t-1} − 2 e_t + e_{t+1})²) / 6`` (second differences:
  what changes from one frame to the next, a slow drift's part taken out to first order): the frame-to-frame
  spread, the part independent noise draws give; ``sqrt(white)`` is the ratio an estimator with only this part
  would have — 1 for an efficient one;
* ``slow`` — ``Σ (s_i² − w_i²) / B²``: the spread that changes slowly over the trial (runs of frames biased
  together, a bias that moves with the pose);

so that ``ρ² − 1 = bias + slow + (white − 1)``: the excess in units of the bound's variance. Whether a few
frames carry it: ``ρ`` without the 1, 3, 5 and 10 largest frames (by ``|e_t|``) and without the flagged
frames, the share of ``Σ |e_t|²`` in the 5 largest frames, and the quantiles of the per-frame ratio
``|e_t| / B`` (median, 90 %, largest) against those of a bound-efficient estimator (errors drawn from
``N(0, diag σ²)``, the same number of frames): a few frames carry the excess when the median is near
its expected value and the tail is not; a bias of the cost or its model spreads it over every frame (the
median ratio as high as ``ρ``). Per axis: ``m_i / σ_i``, ``s_i / σ_i``, ``w_i / σ_i``, the lag-1
autocorrelation of the errors about their mean, and the mean's t statistic from 10 batch means of 10 frames
(their spread, not the frames', so slow drifts widen it).

The same for the search's poses before the likelihood final stage moved them (``searched``: the stored
``per_frame_signals.search_error``): what the stage takes off and what it adds.

Limits: the bound's ``σ`` is the mean over every tenth frame, not each frame's; ``w`` of a frame next to a
jump (a flagged frame) takes the jump in; the stored errors are rounded to 1e-5.

Measured (the f4f4b08 runs, ``resources/benchmarks/tracking_acceptance_seed{0,3,4}_final_f4f4b08_h100.json``,
tracked on one NVIDIA H100; the statistics on this 2-core x86_64 machine):
``resources/benchmarks/tracking_excess_f4f4b08.json`` and the README's paragraph "Where the excess over the
bound comes from".
"""

from __future__ import annotations

import argparse
import json

import numpy as np

__all__ = ["decompose", "main", "searched", "study"]

FILES = "resources/benchmarks/tracking_acceptance_seed{seed}_final_f4f4b08_h100.json"
SEEDS = (0, 3, 4)
DROP = (1, 3, 5, 10)
QUANTILES = (0.5, 0.9, 1.0)
UNITS = {"mm": slice(0, 3), "deg": slice(3, 6)}


def _expected_quantiles(sigma: np.ndarray, n: int, *, draws: int | None = None, seed: int = 0) -> dict:
    """Median over ``draws`` trials (default about 400,000 frames in all, at least 100 trials) of ``n``
    frames from ``N(0, diag sigma²)`` of each quantile of ``|e| / sqrt(Σ sigma²)`` (the largest: quantile
    1), and of the 5 largest frames' share of ``Σ |e|²``."""
    g = np.random.default_rng(seed)
    draws = max(100, 400_000 // max(n, 1)) if draws is None else int(draws)
    e = g.standard_normal((draws, n, len(sigma))) * sigma
    r = np.linalg.norm(e, axis=2) / np.sqrt(np.sum(sigma ** 2))
    q = {f"q{round(100 * p)}": float(np.median(np.quantile(r, p, axis=1))) for p in QUANTILES}
    s = np.sort(r ** 2, axis=1)[:, ::-1]
    q["top5_share"] = float(np.median(s[:, :5].sum(1) / s.sum(1)))
    return q


def _axis(e: np.ndarray, sigma: float) -> dict:
    n = len(e)
    m, s = float(e.mean()), float(e.std())
    w = float(np.sqrt(np.mean(np.diff(e, 2) ** 2) / 6)) if n >= 3 else float("nan")
    c = e - m
    lag1 = float(np.sum(c[1:] * c[:-1]) / np.sum(c * c)) if np.any(c) else 0.0
    nb = n // 10
    bm = e[:nb * 10].reshape(10, nb).mean(1) if nb else np.full(10, m)
    se = float(bm.std(ddof=1) / np.sqrt(10))
    return {"mean_over_sigma": round(m / sigma, 3), "sd_over_sigma": round(s / sigma, 3),
            "white_over_sigma": round(w / sigma, 3), "lag1": round(lag1, 3),
            "mean_t": round(m / se, 2) if se > 0 else None}


def _unit(E: np.ndarray, sigma: np.ndarray, bound_rms: float, flagged: np.ndarray, names) -> dict:
    n = len(E)
    B2 = bound_rms ** 2
    r2 = np.sum(E ** 2, axis=1)
    rho = float(np.sqrt(r2.mean() / B2))
    m, v = E.mean(0), E.var(0)
    w = np.mean(np.diff(E, 2, axis=0) ** 2, axis=0) / 6
    bias, white = float(np.sum(m ** 2) / B2), float(np.sum(w) / B2)
    slow = float(np.sum(v - w) / B2)
    order = np.argsort(-r2)
    drop = {str(k): float(np.sqrt(r2[order[k:]].mean() / B2)) for k in DROP if k < n}
    ratio = np.sqrt(r2 / B2)
    got = {f"q{round(100 * p)}": float(np.quantile(ratio, p)) for p in QUANTILES}
    got["top5_share"] = float(np.sort(r2)[::-1][:5].sum() / r2.sum())
    keep = ~flagged
    return {
        "ratio": round(rho, 4),
        "parts": {"bias": round(bias, 4), "slow": round(slow, 4), "white": round(white, 4),
                  "excess": round(rho ** 2 - 1, 4)},
        "ratio_white_only": round(float(np.sqrt(white)), 4),
        "ratio_without_bias": round(float(np.sqrt(max(rho ** 2 - bias, 0.0))), 4),
        "ratio_without_largest": {k: round(x, 4) for k, x in drop.items()},
        "ratio_unflagged": round(float(np.sqrt(r2[keep].mean() / B2)), 4) if keep.any() else None,
        "per_frame_ratio": {k: round(x, 3) for k, x in got.items()},
        "per_frame_ratio_if_efficient": {k: round(x, 3) for k, x in _expected_quantiles(sigma, n).items()},
        "largest_frames": [int(f) for f in order[:5]],
        "axes": {a: _axis(E[:, i], float(sigma[i])) for i, a in enumerate(names)},
    }


def decompose(t: dict) -> dict:
    """The decomposition of the module docs for one bone's record ``t`` of an acceptance study's
    ``tracking`` (``per_frame_error``, ``frames_with_pose``, ``cramer_rao``, ``flagged_frames``)."""
    E = np.asarray(t["per_frame_error"], float).reshape(-1, 6)
    frames = list(t.get("frames_with_pose") or range(len(E)))
    cb = t["cramer_rao"]
    sigma = np.asarray(cb["sigma"], float)
    flagged = np.isin(frames, t.get("flagged_frames") or [])
    out = {"frames": len(E), "flagged": int(flagged.sum())}
    for u, sl in UNITS.items():
        names = ("tx", "ty", "tz") if u == "mm" else ("rx", "ry", "rz")
        out[u] = _unit(E[:, sl], sigma[sl], float(cb[f"rms_{u}"]), flagged, names)
    return out


def searched(t: dict) -> dict | None:
    """``t`` with each frame's error the search's, before the final stage moved it
    (``per_frame_signals.search_error``; a frame the stage did not move keeps its own), or None where the
    record has no such signals."""
    se = (t.get("per_frame_signals") or {}).get("search_error")
    if se is None:
        return None
    E = [e if v is None else v for e, v in zip(t["per_frame_error"], se, strict=True)]
    return {**t, "per_frame_error": E}


def study(paths) -> dict:
    """Per file (an acceptance study's JSON with ``runs``), per mode and bone: :func:`decompose`, with
    the same of the search's poses before the final stage (``searched``, :func:`searched`) where kept."""
    out = {}
    for p in paths:
        with open(p) as fh:
            d = json.load(fh)
        runs = d["runs"] if "runs" in d else {d["config"]["mode"]: d}
        seed = str(d.get("seed", next(iter(runs.values()))["config"].get("seed", 0)))
        out[seed] = {"file": p, "runs": {m: {n: _both(t) for n, t in r["tracking"].items()
                                               if "cramer_rao" in t} for m, r in runs.items()}}
    return out


def _both(t: dict) -> dict:
    d = decompose(t)
    if (s := searched(t)) is not None:
        d["searched"] = {k: v for k, v in decompose(s).items() if k in UNITS}
    return d


def _table(res: dict) -> str:
    rows = ["seed mode bone unit: ratio | bias slow white-1 | white-only | w/o 5 largest | "
            "median q90 (efficient)"]
    for s, r in res.items():
        for m, bones in r["runs"].items():
            for n, b in bones.items():
                for u in UNITS:
                    x = b[u]
                    pr, pe = x["per_frame_ratio"], x["per_frame_ratio_if_efficient"]
                    rows.append(f"{s} {m[:3]} {n:9s} {u:3s}: {x['ratio']:.2f} | {x['parts']['bias']:.2f} "
                                f"{x['parts']['slow']:.2f} {x['parts']['white'] - 1:.2f} | "
                                f"{x['ratio_white_only']:.2f} | {x['ratio_without_largest']['5']:.2f} | "
                                f"{pr['q50']:.2f} {pr['q90']:.2f} ({pe['q50']:.2f} {pe['q90']:.2f})")
    return "\n".join(rows)


def main(argv=None) -> int:
    import sys

    from core.io.atomic import print_json

    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.excess_decomposition",
                                description=(__doc__ or "").split("\n")[0])
    p.add_argument("files", nargs="*", help="acceptance JSONs (default the f4f4b08 runs of seeds 0, 3, 4)")
    p.add_argument("--machine-name", default="this 2-core x86_64 machine, shared")
    p.add_argument("--out", default=None, help="write the JSON here too")
    a = p.parse_args(argv)
    files = a.files or [FILES.format(seed=s) for s in SEEDS]
    res = {"study": "core.studies.tracking.excess_decomposition", "machine_name": a.machine_name,
           "tracked_on": "one NVIDIA H100 (the acceptance runs); the statistics on the machine named",
           "seeds": study(files)}
    print(_table(res["seeds"]), file=sys.stderr)
    print_json(res, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
