"""Statistics of the harder trial's runs (:mod:`core.studies.tracking.hard_trial`): the issue's
goals, the confidence σ's coverage with what a correct σ gives, bias against spread, joint against
sequential as a paired comparison, and several seeds' runs joined frame by frame. What each measure
means and which one the goals are checked on: :mod:`core.studies.tracking.hard_trial`'s docs."""

from __future__ import annotations

import numpy as np

__all__ = ["AXES", "CHI2_6_2SIGMA", "CHI2_6_90", "COVERAGE_CHECKED_ON", "GOALS", "JOINT_MARGIN", "TWO_SIGMA",
           "coverage", "error_structure", "goals", "has_sigma", "merge_runs", "paired_comparison"]

#: the 95.45 % quantile of χ² with 6 degrees of freedom: what "within 2σ" is for six errors
#: together (``within_2_sigma_chi2``: Σ (e_k / σ_k)² below it). With a calibrated σ, 95.45 % of
#: frames are; of the stricter ``within_2_sigma`` (all six |e_k| <= 2σ_k) only 0.9545⁶ = 75.6 %.
CHI2_6_2SIGMA = 12.8489

#: the issue's goals for the harder trial: per-frame RMS (mm, degrees) of every bone, and the
#: fraction within 2σ of the confidence — checked per axis (:data:`COVERAGE_CHECKED_ON`,
#: :func:`coverage`), for the translation and the rotation axes each
GOALS = {"rms_mm": 0.10, "rms_deg": 0.15, "within_2_sigma": 0.90}
#: what "within 2σ" is checked on: ``"per_axis"`` — every frame's six errors counted separately,
#: the translation axes and the rotation axes each (:func:`coverage`)
COVERAGE_CHECKED_ON = "per_axis"
#: P(|z| <= 2) of a standard normal: the per-axis coverage of a correct σ
TWO_SIGMA = 0.9544997361
#: the 90 % quantile of χ² with 6 degrees of freedom
CHI2_6_90 = 10.6446
#: "joint at least as good as sequential" (:func:`paired_comparison`): the upper end of the 95 %
#: interval of joint's RMS minus sequential's within this much (mm, degrees): a tenth of the goal
JOINT_MARGIN = {"mm": 0.1 * GOALS["rms_mm"], "deg": 0.1 * GOALS["rms_deg"]}
AXES = ("tx", "ty", "tz", "rx", "ry", "rz")


def _wilson(k: float, n: int, z: float = 1.959964) -> list:
    """95 % Wilson interval of a fraction ``k / n`` (independent trials)."""
    if n == 0:
        return [float("nan"), float("nan")]
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return [round(float(c - h), 4), round(float(c + h), 4)]


def has_sigma(sig) -> np.ndarray:
    """Per frame of ``sig`` (frames × 6), whether it has a σ: a finite σ on at least one axis. A
    frame without one (every axis NaN or ``inf``: no confidence computed) is left out of the
    coverage and counted apart (``frames_without_sigma``), not counted within an infinite σ, which
    would let a run without confidence meet the goal (as
    :func:`core.studies.tracking.acceptance_goals.sigma_coverage` does); an axis without σ (``inf``)
    beside others that have one stays unbounded: covered on that axis."""
    return np.any(np.isfinite(np.asarray(sig, dtype=float)), axis=1)


def coverage(E, sig, cov=None) -> dict:
    """How well the confidence covers the errors ``E`` (frames × 6: mm, degrees) — σ ``sig``
    (frames × 6; NaN or ``inf`` on every axis where a frame has none, ``inf`` on an axis without
    one) and, where every frame has one, its 6 × 6 covariance ``cov`` (a sequence with None where a
    frame has none) — each measure with what a correct σ gives (``expected``, errors normal with
    that σ), over the frames with an error and a σ (:func:`has_sigma`; ``frames_without_sigma``
    counts the frames with an error and none):

    * ``per_axis`` — of the single errors, ``|e_k| <= 2 σ_k``: all, the translation axes, the
      rotation axes and each axis; expected :data:`TWO_SIGMA` (95.4 %) for every one of them
      whatever the correlations between axes. ``interval95`` (Wilson) treats the errors as
      independent, which frames of one trial are not (a shared bias), so it is too narrow.
    * ``all_six`` — frames whose six errors all lie within 2σ: 0.954⁶ = 75.6 % for independent
      axes, up to 95.4 % for fully correlated ones: no fixed target fits it.
    * ``chi2`` — frames whose squared Mahalanobis distance ``d² = eᵀ Σ⁻¹ e`` is within
      :data:`CHI2_6_2SIGMA` (the χ²(6) quantile of 2σ's 95.4 %, expected 95.4 %) and within
      :data:`CHI2_6_90` (expected 90 %). ``Σ`` is the reported covariance where there is one;
      otherwise ``diag(σ²)`` (``"covariance": "diagonal"``), and then ``d²`` follows χ²(6) only
      when the axes' errors are uncorrelated — with correlated errors (rotation and translation
      are, in a projection) a correct σ puts fewer frames inside.
    * ``z_rms`` — per axis the RMS of ``e_k / σ_k`` (1 for a correct σ; below 1: σ too large,
      above: too small) and ``mean_d2`` (6 for a correct σ).

    ``met``: the goal (:data:`GOALS` ``within_2_sigma``) on the measure it is checked on
    (:data:`COVERAGE_CHECKED_ON`): the translation axes' and the rotation axes' per-axis
    fractions both at least 90 %."""
    E, sig = np.asarray(E, dtype=float), np.asarray(sig, dtype=float)
    err, has = np.all(np.isfinite(E), axis=1), has_sigma(sig)
    ok = err & has & ~np.any(np.isnan(sig), axis=1)
    E, sig = E[ok], sig[ok]
    n = int(ok.sum())
    inside = np.abs(E) <= 2 * sig
    full = cov is not None and len(cov) == len(ok) and all(c is not None
                                                           for c, o in zip(cov, ok, strict=True) if o)
    if full:
        C = [np.asarray(c, dtype=float) for c, o in zip(cov, ok, strict=True) if o]
        d2 = np.array([e @ np.linalg.solve(c, e) if np.all(np.isfinite(c)) else 0.0
                       for e, c in zip(E, C, strict=True)])
    else:
        d2 = np.sum((E / sig) ** 2, axis=1)
    z = E / sig

    def frac(a) -> dict:
        k, m = int(np.sum(a)), int(np.size(a))
        return {"observed": round(k / m, 4) if m else float("nan"), "n": m, "interval95": _wilson(k, m)}

    pa = {"all": frac(inside), "translation": frac(inside[:, :3]), "rotation": frac(inside[:, 3:]),
          "axes": {a: round(float(np.mean(inside[:, k])), 4) if n else float("nan")
                   for k, a in enumerate(AXES)},
          "expected": round(TWO_SIGMA, 4)}
    cover = {"n_frames": n, "frames_without_sigma": int(np.sum(err & ~has)),
             "per_axis": pa,
             "all_six": {**frac(np.all(inside, axis=1)), "expected_independent": round(TWO_SIGMA ** 6, 4),
                         "expected_fully_correlated": round(TWO_SIGMA, 4)},
             "chi2": {"covariance": "full" if full else "diagonal",
                      "within_2_sigma": {**frac(d2 <= CHI2_6_2SIGMA), "quantile": CHI2_6_2SIGMA,
                                         "expected": round(TWO_SIGMA, 4)},
                      "within_90": {**frac(d2 <= CHI2_6_90), "quantile": CHI2_6_90, "expected": 0.90}},
             "z_rms": {a: round(float(np.sqrt(np.mean(z[:, k] ** 2))), 3) if n else float("nan")
                       for k, a in enumerate(AXES)},
             "mean_d2": round(float(np.mean(d2)), 3) if n else float("nan"),
             "checked_on": COVERAGE_CHECKED_ON, "goal": GOALS["within_2_sigma"]}
    cover["met"] = bool(n and min(pa["translation"]["observed"], pa["rotation"]["observed"])
                        >= GOALS["within_2_sigma"])
    return cover


def error_structure(E, sig, frames=()) -> dict:
    """Bias or spread: per axis (mm, degrees) the mean error over the frames, its standard
    deviation and the bias's share of the mean square (``mean² / (mean² + sd²)``); and for each
    of ``frames`` (e.g. those over 4× their bound) the errors, the axis of the largest |error|
    among translations and among rotations, the errors less the bone's mean (what spread alone
    leaves), ``e / σ`` and whether all six are within 2σ."""
    E, sig = np.asarray(E, dtype=float), np.asarray(sig, dtype=float)
    ok = np.all(np.isfinite(E), axis=1)
    mu = E[ok].mean(0) if ok.any() else np.full(6, np.nan)
    sd = E[ok].std(0) if ok.any() else np.full(6, np.nan)
    ms = mu ** 2 + sd ** 2
    out = {"mean": dict(zip(AXES, mu.round(4).tolist(), strict=True)),
           "sd": dict(zip(AXES, sd.round(4).tolist(), strict=True)),
           "bias_share": dict(zip(AXES, np.where(ms > 0, mu ** 2 / np.where(ms > 0, ms, 1), np.nan).round(3)
                                  .tolist(), strict=True)),
           "bias_norm": {"mm": round(float(np.linalg.norm(mu[:3])), 4),
                         "deg": round(float(np.linalg.norm(mu[3:])), 4)},
           "frames": {}}
    for f in frames:
        e, s = E[int(f)], sig[int(f)]
        out["frames"][str(int(f))] = {
            "error": dict(zip(AXES, e.round(4).tolist(), strict=True)),
            "largest": [AXES[int(np.argmax(np.abs(e[:3])))], AXES[3 + int(np.argmax(np.abs(e[3:])))]],
            "less_mean": dict(zip(AXES, (e - mu).round(4).tolist(), strict=True)),
            "norm_less_mean_mm": round(float(np.linalg.norm((e - mu)[:3])), 4),
            "z": dict(zip(AXES, np.where(np.isfinite(s), e / s, 0.0).round(2).tolist(), strict=True)),
            "within_2_sigma": bool(np.all(np.abs(e) <= 2 * s))}
    return out


def _block_indices(g: np.random.Generator, n: int, block: int, n_boot: int) -> np.ndarray:
    """``(n_boot, n)`` circular block bootstrap indices over ``n`` frames, blocks of ``block``."""
    k = -(-n // block)
    starts = g.integers(0, n, size=(n_boot, k))
    return ((starts[:, :, None] + np.arange(block)) % n).reshape(n_boot, -1)[:, :n]


def paired_comparison(seq, joint, *, margin: float, n_boot: int = 4000, block: int | None = None,
                      seed: int = 0) -> dict:
    """Joint against sequential tracking of one bone on the same frames: ``seq``, ``joint`` the
    per-frame error lengths (mm, or degrees), paired by frame (frames where either is missing
    are left out). The difference of the RMS errors (joint − sequential) with a 95 % interval
    from a circular block bootstrap over frames (blocks of ``block`` frames, default
    ``ceil(n^(1/3))``: a frame's error is correlated with its neighbours'), resampling the pairs
    together so that what the frames share cancels; also the mean of the per-frame squared
    error differences with its interval, and the bootstrap share of resamples where joint is
    worse. ``verdict``: ``"worse"`` (the interval above 0), ``"better"`` (below 0) or ``"not
    resolved"``; ``at_least_as_good``: the interval's upper end within ``margin``
    (non-inferiority: joint no worse than ``margin``, with 95 % confidence)."""
    a, b = np.asarray(seq, dtype=float), np.asarray(joint, dtype=float)
    ok = np.isfinite(a) & np.isfinite(b)
    a, b = a[ok], b[ok]
    n = int(ok.sum())
    if n == 0:
        return {"n_frames": 0, "at_least_as_good": False, "verdict": "no frames"}
    block = int(block or np.ceil(n ** (1 / 3)))
    idx = _block_indices(np.random.default_rng(seed), n, block, n_boot)
    ms_a, ms_b = np.mean(a[idx] ** 2, axis=1), np.mean(b[idx] ** 2, axis=1)
    drms = np.sqrt(ms_b) - np.sqrt(ms_a)
    lo, hi = np.quantile(drms, [0.025, 0.975])
    d2lo, d2hi = np.quantile(ms_b - ms_a, [0.025, 0.975])
    rms_a, rms_b = float(np.sqrt(np.mean(a ** 2))), float(np.sqrt(np.mean(b ** 2)))
    return {"n_frames": n, "block": block, "n_boot": n_boot,
            "rms_sequential": round(rms_a, 5), "rms_joint": round(rms_b, 5),
            "rms_difference": round(rms_b - rms_a, 5),
            "interval95": [round(float(lo), 5), round(float(hi), 5)],
            "mean_sq_difference": round(float(np.mean(b ** 2 - a ** 2)), 7),
            "mean_sq_interval95": [round(float(d2lo), 7), round(float(d2hi), 7)],
            "share_joint_worse": round(float(np.mean(drms > 0)), 3),
            "frames_joint_worse": round(float(np.mean(b > a)), 3),
            "verdict": "worse" if lo > 0 else "better" if hi < 0 else "not resolved",
            "margin": margin, "at_least_as_good": bool(hi <= margin)}


def goals(runs: dict) -> dict:
    """The issue's goals (:data:`GOALS`) of each run (``label -> evaluate()``'s result, labels
    ``"<metric>/<final>/<mode>"``): per bone the RMS errors, whether each is within its goal, the
    2σ coverage — ``sigma_ok`` on the per-axis measure (:data:`COVERAGE_CHECKED_ON`: the
    translation and the rotation axes each at least 90 % within 2σ; ``within_2_sigma``, all six
    of a frame, and ``within_2_sigma_chi2`` beside it with what a correct σ gives them) — and,
    where the same metric and final stage ran both ``sequential`` and ``joint``, whether joint
    mode is at least as good: :func:`paired_comparison` of the per-frame translation and
    rotation errors (``paired``), ``joint_ok`` where both are within :data:`JOINT_MARGIN` with
    95 % confidence (runs without per-frame errors: joint's RMS not above sequential's);
    ``met``: every goal of the run."""
    out = {}
    for label, ev in runs.items():
        per = {}
        for n, b in ev["bones"].items():
            cov = b.get("coverage")
            if cov:
                pt, pr = cov["per_axis"]["translation"]["observed"], cov["per_axis"]["rotation"]["observed"]
            else:  # an older result: the per-axis fraction of all six
                pt = pr = b["per_axis_within_2_sigma"]
            per[n] = {"rms_mm": round(b["rms_error_mm"], 4), "rms_deg": round(b["rms_error_deg"], 4),
                      "coverage_checked_on": COVERAGE_CHECKED_ON,
                      "per_axis_within_2_sigma": round(b["per_axis_within_2_sigma"], 3),
                      "per_axis_translation": round(pt, 3), "per_axis_rotation": round(pr, 3),
                      "per_axis_expected": round(TWO_SIGMA, 3),
                      "within_2_sigma": round(b["within_2_sigma"], 3),
                      "within_2_sigma_expected": round(TWO_SIGMA ** 6, 3),
                      "within_2_sigma_chi2": round(b.get("within_2_sigma_chi2", float("nan")), 3),
                      "within_2_sigma_chi2_expected": round(TWO_SIGMA, 3),
                      "mm_ok": bool(b["rms_error_mm"] <= GOALS["rms_mm"]),
                      "deg_ok": bool(b["rms_error_deg"] <= GOALS["rms_deg"]),
                      "sigma_ok": bool(min(pt, pr) >= GOALS["within_2_sigma"]),
                      "silent_failures": len(b["silent_failures"])}
        out[label] = {"bones": per}
    for label, g in out.items():
        head, _, mode = label.rpartition("/")
        seq = out.get(f"{head}/sequential")
        if mode.startswith("joint") and seq is not None:
            for n, b in g["bones"].items():
                s = seq["bones"][n]
                b["joint_vs_sequential"] = {"mm": round(b["rms_mm"] - s["rms_mm"], 4),
                                            "deg": round(b["rms_deg"] - s["rms_deg"], 4)}
                ej = runs[label]["bones"][n].get("per_frame_error")
                es = runs[f"{head}/sequential"]["bones"][n].get("per_frame_error")
                if ej is not None and es is not None and len(ej) == len(es):
                    ej, es = np.asarray(ej, dtype=float), np.asarray(es, dtype=float)
                    b["paired"] = {u: paired_comparison(np.linalg.norm(es[:, k], axis=1),
                                                        np.linalg.norm(ej[:, k], axis=1),
                                                        margin=JOINT_MARGIN[u])
                                   for u, k in (("mm", slice(0, 3)), ("deg", slice(3, 6)))}
                    b["joint_ok"] = bool(b["paired"]["mm"]["at_least_as_good"]
                                         and b["paired"]["deg"]["at_least_as_good"])
                else:
                    b["joint_ok"] = bool(b["rms_mm"] <= s["rms_mm"] and b["rms_deg"] <= s["rms_deg"])
        g["met"] = bool(all(b["mm_ok"] and b["deg_ok"] and b["sigma_ok"] and b.get("joint_ok", True)
                            for b in g["bones"].values()))
    return out


def merge_runs(results) -> dict:
    """The runs of several :func:`run` results (e.g. seeds) joined frame by frame: per label and
    bone the per-frame errors, σ and bounds concatenated, the RMS errors, :func:`coverage` and
    :func:`error_structure` (over 4× bound frames numbered in the joined order) recomputed —
    what :func:`goals` takes. Labels present in every result only."""
    results = list(results)
    labels = [k for k in results[0]["runs"] if all(k in r["runs"] for r in results)]
    out = {}
    for label in labels:
        bones = {}
        for n in results[0]["runs"][label]["bones"]:
            parts = [r["runs"][label]["bones"][n] for r in results]
            E = np.concatenate([np.asarray(p["per_frame_error"], dtype=float) for p in parts])
            S = np.concatenate([np.asarray(p["per_frame_sigma"], dtype=float) for p in parts])
            S = np.where(S < 0, np.inf, S)  # evaluate() writes a missing σ as -1 (a frame's: all six)
            B = np.concatenate([np.asarray(p["per_frame_bound"], dtype=float) for p in parts])
            et, er = np.linalg.norm(E[:, :3], axis=1), np.linalg.norm(E[:, 3:], axis=1)
            ok = np.isfinite(et)
            over = np.where(ok & (np.nanmax(np.column_stack([et / B[:, 0], er / B[:, 1]]), axis=1) > 4))[0]
            ok &= has_sigma(S)  # the σ measures: over the frames that have one (coverage's)
            off, silent = 0, []
            for p in parts:
                silent += [off + f for f in p["silent_failures"]]
                off += len(p["per_frame_error"])
            inside = np.abs(E[ok]) <= 2 * S[ok]
            chi2 = np.sum((E[ok] / S[ok]) ** 2, axis=1)
            bones[n] = {"rms_error_mm": float(np.sqrt(np.nanmean(et ** 2))),
                        "rms_error_deg": float(np.sqrt(np.nanmean(er ** 2))),
                        "bound_rms_mm": float(np.sqrt(np.nanmean(B[:, 0] ** 2))),
                        "bound_rms_deg": float(np.sqrt(np.nanmean(B[:, 1] ** 2))),
                        "within_2_sigma": float(np.mean(np.all(inside, axis=1))),
                        "per_axis_within_2_sigma": float(np.mean(inside)),
                        "within_2_sigma_chi2": float(np.mean(chi2 <= CHI2_6_2SIGMA)),
                        "coverage": coverage(E, S), "error_structure": error_structure(E, S, over),
                        "over_4x_bound": over.tolist(), "silent_failures": silent,
                        "per_frame_error": E.tolist()}
            b = bones[n]
            b["rms_over_bound"] = {"mm": b["rms_error_mm"] / b["bound_rms_mm"],
                                   "deg": b["rms_error_deg"] / b["bound_rms_deg"]}
        out[label] = {"bones": bones, "seeds": [r["config"]["seed"] for r in results]}
    return out
