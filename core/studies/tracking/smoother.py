"""The covariance-weighted smoother of the tracked poses against the truth, on stored acceptance runs
(``python -m core.studies.tracking.smoother``).

Runs: the acceptance study's seeds 0, 3 and 4 at d262386, both modes (one NVIDIA H100, 1024², 0.5
mm, 100 frames, the final stage; ``tracking_acceptance_seed{0,3,4}_final_d262386_h100.json``).
Each keeps every frame's error against the truth, σ and flags; the tracked poses are rebuilt as
those errors applied to the seed's true poses (:func:`core.studies.tracking.trajectory_gaps.truth`,
the motion made again from the seed; rotation centre the seed's bone model's centroid at 0.5 mm,
:func:`centroids`, the one the errors are about). Per bone, mode and seed three estimates are
compared with the truth:

* ``raw``: the tracked poses (each frame alone);
* ``lowpass``: the acceptance study's fixed low-pass (second-order zero-phase Butterworth, cut-off
  by Winter's residual analysis, flagged frames left out and not scored,
  :meth:`~core.tracking.results.TrackingResult.filtered_poses`);
* the smoother :func:`core.tracking.smoothing.smooth_poses` in the variants of :data:`VARIANTS`
  (the model, the flagged frames' weight, the robust down-weighting, weighing by each frame's σ or
  not), every frame scored.

Measures (:func:`measures`): RMS error over the bone's single-frame Cramér–Rao bound (mm, °; the
bound does not bound an estimate that pools frames: a separate figure from the per-frame goal),
the largest error, the frames over 4× the bound and those of them not flagged (silent), and for
the smoother its covariance's coverage (the fraction of translation and of rotation axes within
2σ; a correct σ gives 95.4 %), the scale ``k`` it found on the tracker's σ.

Transient (:func:`transient`): the truth given a heel-strike-like jerk at frame :data:`T0` — each
coordinate stepped by ``amplitude`` (mm; the same number in degrees) as a damped second-order
system's step response (:data:`TRANSIENT_HZ`, damping :data:`TRANSIENT_ZETA`: it settles within a
few frames at the trial's 278 Hz, overshooting) — plus the run's own errors; the smoother's added
error there is its error with the transient minus without, RMS over frames ``T0 - 3`` to
``T0 + 12``, beside the raw frames' error in that window.

Outliers (:func:`_outliers`): frame :data:`OUTLIER_FRAME` of each run moved 1, 2 and 5 mm along the
lab's x and flagged; the smoothed pose's error there. Error structure (:func:`error_structure`): per
axis the share of the per-frame errors' mean square that is the run's mean error, and their lag-1
correlation; coverage is also given about the run's mean error (``within_2_sigma_about_mean``).

Measured (``resources/benchmarks/tracking_smoother_cpu.json``, this 2-core x86_64 machine, shared; 18
bone-runs), × the single-frame bound mm / °: raw 1.18–1.92 / 1.27–1.81 with 21 frames over 4× (5
silent); the low-pass 0.69–4.26 / 0.60–1.41 (the tibia's translation 1.7–4.3×: 22–26 Hz lags its
0.4 mm a frame) with 53 over 4× among the unflagged frames it scores; the smoother's defaults
0.54–1.13 / 0.42–1.14 (mean 0.81 / 0.65), none over 4×; within 2σ 77–98 % of the translation and
73–98 % of the rotation axes (means 90.6 / 87.2 %; about the run's mean error 93.6 / 94.3 %; a
correct σ: 95.4 %). The runs' mean error is 0–31 % of their per-frame mean square per axis (5 % on
average), their lag-1 correlation −0.16 to 0.50: the smoother models the second (AR(1), ``correlated``;
with independent errors, ``acceleration_independent``: 77–97 / 71–98 %, means 88.5 / 86.0 %), not the
first, which no trial's data can tell from the pose. Before the outlier search and the AR(1) errors
(f0325fc's defaults, this study at 17a41b8): 0.55–1.13 / 0.42–1.21 (mean 0.80 / 0.66), within 2σ
80–97 / 72–98 % (means 89.2 / 86.4 %). A flagged frame moved 1, 2 or 5 mm: 0.012–0.043 mm off in
every run (taken for an outlier), without the outlier search up to 1.06 / 2.06 / 5.06 mm; the defaults
take 11 of the runs' own flagged frames (in 8 runs) for outliers, without the flag's prior none
(``acceleration_no_flagged_prior``: 0.54–1.13 / 0.42–1.21, means 0.80 / 0.66, within 2σ 91.5 / 87.7
%). Weighing by each frame's σ: 0.55–1.16 / 0.44–1.53; flagged frames skipped: up to 2.7× (a flagged
trial end extrapolated); constant velocity 0.77–1.39 / 0.48–1.26. The transient: no burst let in on
any plain run; the 1 mm / 1° jerk found in every run, its added error 0.024 mm / 0.143° RMS in the
window (without bursts 0.163 / 0.321; independent errors 0.023 / 0.140; the raw frames' own error
there 0.048 / 0.164): with it the smoothed poses' error there is 0.038 mm / 0.156°, worse than the raw
frames' in rotation in 6 of 18 runs.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from core.studies.tracking.acceptance_records import pose_errors
from core.studies.tracking.trajectory_gaps import BENCH, BONES, _rebuilt, truth

__all__ = ["OUTLIER_FRAME", "OUTLIER_MM", "RUNS", "T0", "VARIANTS", "centroids", "error_structure",
           "lowpass_errors", "main", "measures", "run", "table", "transient"]

#: seed -> the stored acceptance run (both modes)
RUNS = {s: f"tracking_acceptance_seed{s}_final_d262386_h100.json" for s in (0, 3, 4)}
#: the smoother's variants: name -> smooth_poses keywords
VARIANTS = {
    # smooth_poses' defaults: constant acceleration, every frame alike (the median sigma), flagged frames
    # measured, robust 2.5, bursts let in, outliers taken (a flagged frame credited FLAGGED_PRIOR), the
    # errors' AR(1) correlation fitted
    "acceleration": {},
    "acceleration_independent": {"correlated": False},
    "acceleration_no_outliers": {"outliers": None},
    "acceleration_no_flagged_prior": {"flagged_prior": 0.0},
    "acceleration_sigma": {"weigh": "sigma"},
    "acceleration_no_bursts": {"transients": None},
    "acceleration_skip_flagged": {"flagged_weight": 0.0},
    "acceleration_flagged_quarter": {"flagged_weight": 0.25},
    "acceleration_not_robust": {"robust": None},
    "velocity": {"model": "velocity"},
    "velocity_no_bursts": {"model": "velocity", "transients": None},
    "velocity_skip_flagged": {"model": "velocity", "flagged_weight": 0.0},
}
#: the transient's frame, natural frequency (Hz) and damping
T0, TRANSIENT_HZ, TRANSIENT_ZETA = 50, 40.0, 0.4
#: the frame moved off (and flagged) in the outlier test, and by how much (mm, along the lab's x)
OUTLIER_FRAME, OUTLIER_MM = 40, (1.0, 2.0, 5.0)
FRAME_RATE_HZ = 100 / 0.36  # the acceptance trial's (core.studies.tracking.acceptance.FRAME_RATE_HZ)


def centroids(seed: int) -> list[np.ndarray]:
    """The seed's bone models' centroids (0.5 mm phantoms, as the acceptance study's scene)."""
    from core.synthetic.phantoms import foot_phantoms
    from core.tracking.bones import bone_model

    return [bone_model(p.volume, mesh=False).centroid for p in foot_phantoms(BONES, spacing=0.5, seed=seed)]


def _errors(P, T, c) -> np.ndarray:
    """``(n, 6)`` errors (mm, degrees) of poses ``P`` against ``T``; NaN rows where ``P`` has none."""
    out = np.full((len(P), 6), np.nan)
    for f, (p, t) in enumerate(zip(P, T, strict=True)):
        if np.all(np.isfinite(p)):
            out[f] = pose_errors(p, t, c)
    return out


def measures(E, bound: dict, flagged, sigma=None) -> dict:
    """RMS over the bound, largest errors, frames over 4× (silent: not ``flagged``) of errors ``E``
    (frames without a row of NaN left out); with ``sigma`` the 2σ coverage per group of axes."""
    ok = np.isfinite(E).all(axis=1)
    frames = np.flatnonzero(ok)
    et, er = np.linalg.norm(E[ok, :3], axis=1), np.linalg.norm(E[ok, 3:], axis=1)
    over = (et > 4 * bound["rms_mm"]) | (er > 4 * bound["rms_deg"])
    out = {"frames": int(ok.sum()),
           "rms_over_bound": [round(float(np.sqrt(np.mean(et ** 2)) / bound["rms_mm"]), 3),
                              round(float(np.sqrt(np.mean(er ** 2)) / bound["rms_deg"]), 3)],
           "rms": [round(float(np.sqrt(np.mean(et ** 2))), 5), round(float(np.sqrt(np.mean(er ** 2))), 5)],
           "max": [round(float(et.max()), 5), round(float(er.max()), 5)],
           "over_4x": frames[over].tolist(), "silent_over_4x": frames[over & ~flagged[ok]].tolist()}
    if sigma is not None:
        inside = np.abs(E[ok]) <= 2 * sigma[ok]
        out["within_2_sigma"] = [round(float(inside[:, :3].mean()), 3), round(float(inside[:, 3:].mean()), 3)]
        about = np.abs(E[ok] - E[ok].mean(axis=0)) <= 2 * sigma[ok]  # about the run's mean error
        out["within_2_sigma_about_mean"] = [round(float(about[:, :3].mean()), 3),
                                            round(float(about[:, 3:].mean()), 3)]
    return out


def error_structure(E) -> dict:
    """Per axis of the per-frame errors ``E``: the share of their mean square that is the run's mean
    error (common to every frame: no pooling of frames removes it) and their lag-1 correlation."""
    ok = np.isfinite(E).all(axis=1)
    X = E[ok]
    mu = X.mean(axis=0)
    c = X - mu
    lag1 = (c[1:] * c[:-1]).sum(axis=0) / np.maximum((c * c).sum(axis=0), 1e-300)
    return {"mean_share": np.round(mu ** 2 / np.maximum((X ** 2).mean(axis=0), 1e-300), 3).tolist(),
            "lag1": np.round(lag1, 3).tolist()}


def _outliers(E, S, fl, T, c, kw) -> dict:
    """Per offset of :data:`OUTLIER_MM`: frame :data:`OUTLIER_FRAME` moved that far along the lab's x
    and flagged; the smoothed pose's translation error there (mm) and whether it was taken for an
    outlier."""
    from core.tracking.smoothing import smooth_poses

    out = {}
    for mm in OUTLIER_MM:
        P = _rebuilt(E, T, c)
        P[OUTLIER_FRAME, 0, 3] += mm
        f = fl.copy()
        f[OUTLIER_FRAME] = True
        sm = smooth_poses(P, S, center=c, flagged=f, **kw)
        e = _errors(sm.poses[OUTLIER_FRAME:OUTLIER_FRAME + 1], T[OUTLIER_FRAME:OUTLIER_FRAME + 1], c)[0]
        w = round(float(sm.weights[OUTLIER_FRAME]), 5)
        out[str(mm)] = {"error_mm": round(float(np.linalg.norm(e[:3])), 4),
                        "outlier": OUTLIER_FRAME in sm.outliers, "weight": w}
    return out


def lowpass_errors(P, T, c, flagged) -> tuple[np.ndarray, float]:
    """The acceptance study's low-pass of ``P`` (flagged frames out, NaN) and its errors; the cut-off."""
    from core.tracking.kinematics import filter_poses, residual_cutoff

    Q = P.copy()
    Q[flagged] = np.nan
    ok = np.all(np.isfinite(Q), axis=(1, 2))
    path = np.full((len(Q), 3), np.nan)
    path[ok] = Q[ok, :3, :3] @ c + Q[ok, :3, 3]
    fc, _ = residual_cutoff(path, FRAME_RATE_HZ)
    return _errors(filter_poses(Q, FRAME_RATE_HZ, fc, center=c), T, c), fc


def _step(n: int, t0: int) -> np.ndarray:
    """The damped second-order step response at frames ``0..n-1`` (0 before ``t0``, → 1)."""
    s = (np.arange(n) - t0) / FRAME_RATE_HZ
    w, z = 2 * math.pi * TRANSIENT_HZ, TRANSIENT_ZETA
    wd = w * math.sqrt(1 - z * z)
    y = 1 - np.exp(-z * w * s) * (np.cos(wd * s) + z * w / wd * np.sin(wd * s))
    return np.where(s > 0, y, 0.0)


def transient(T, c, amplitude: float, t0: int = T0) -> np.ndarray:
    """``T`` with the jerk (module docs): every coordinate stepped by ``amplitude`` mm / degrees."""
    from core.geometry.transforms import pose_from_params

    u = _step(len(T), t0)[:, None] * amplitude * np.r_[np.ones(3), np.radians(np.ones(3))]
    return np.array([pose_from_params(d, center=c, base=t) for d, t in zip(u, T, strict=True)])


def _window_rms(E, lo, hi) -> list[float]:
    W = E[lo:hi]
    return [round(float(np.sqrt(np.nanmean(np.sum(W[:, :3] ** 2, 1)))), 5),
            round(float(np.sqrt(np.nanmean(np.sum(W[:, 3:] ** 2, 1)))), 5)]


def _window_max(E, lo, hi) -> list[float]:
    W = E[lo:hi]
    return [round(float(np.nanmax(np.linalg.norm(W[:, :3], axis=1))), 5),
            round(float(np.nanmax(np.linalg.norm(W[:, 3:], axis=1))), 5)]


def _jerks(E, Es, S, fl, T, c, kw, amplitudes) -> dict:
    """Per amplitude, the transient's errors in its window (module docs): the raw frames', the
    smoother's without and with it, the difference (``added``, RMS and largest)."""
    from core.tracking.smoothing import smooth_poses

    lo, hi = T0 - 3, T0 + 13
    out = {}
    for a in amplitudes:
        Tj = transient(T, c, a)
        sm = smooth_poses(_rebuilt(E, Tj, c), S, center=c, flagged=fl, **kw)
        Ej = _errors(sm.poses, Tj, c)
        out[str(a)] = {"bursts": sm.bursts, "raw": _window_rms(E, lo, hi),
                       "smoothed_plain": _window_rms(Es, lo, hi), "smoothed_jerk": _window_rms(Ej, lo, hi),
                       "added": _window_rms(Ej - Es, lo, hi), "max_added": _window_max(Ej - Es, lo, hi)}
    return out


def _stored(t: dict, n: int):
    """A stored bone record's errors, σ (``(n, 6)``, NaN where none) and flags."""
    E = np.full((n, 6), np.nan)
    E[t["frames_with_pose"]] = t["per_frame_error"]
    S = np.full((n, 6), np.nan)
    S[t["frames_with_pose"]] = [[np.inf if v is None else v for v in q] if q else [np.nan] * 6
                                for q in t["per_frame_sigma"]]
    return E, S, np.isin(np.arange(n), t["flagged_frames"])


def run(seeds=(0, 3, 4), variants=None, amplitudes=(0.25, 1.0), bench: Path = BENCH) -> dict:
    """Every stored run's bones, the estimates and their measures (module docs)."""
    from core.tracking.smoothing import smooth_poses

    variants = VARIANTS if variants is None else {k: VARIANTS[k] for k in variants}
    out: dict = {}
    for seed in seeds:
        d = json.loads((bench / RUNS[seed]).read_text())
        T, cs = truth(int(seed)), centroids(int(seed))
        for mode, r in d["runs"].items():
            for b, t in r["tracking"].items():
                k, c, cb = BONES.index(b), cs[BONES.index(b)], t["cramer_rao"]
                E, S, fl = _stored(t, T.shape[1])
                P = _rebuilt(E, T[k], c)
                El, fc = lowpass_errors(P, T[k], c, fl)
                rec = {"raw": {**measures(E, cb, fl), **error_structure(E)},
                       "lowpass": {"cutoff_hz": round(fc, 2), **measures(El, cb, fl)}}
                for name, kw in variants.items():
                    sm = smooth_poses(P, S, center=c, flagged=fl, **kw)
                    Es = _errors(sm.poses, T[k], c)
                    low = np.flatnonzero((sm.weights > 0) & (sm.weights < 0.999)).tolist()
                    rec[name] = {**measures(Es, cb, fl, sm.sigma), "scale": np.round(sm.scale, 3).tolist(),
                                 "down_weighted": low, "bursts": sm.bursts, "outliers": sm.outliers,
                                 "transient": _jerks(E, Es, S, fl, T[k], c, kw, amplitudes),
                                 "flagged_outlier": _outliers(E, S, fl, T[k], c, kw)}
                out.setdefault(str(seed), {}).setdefault(mode, {})[b] = rec
    return out


def table(res: dict, variant: str = "acceleration") -> list[str]:
    """One line per seed, mode and bone: × the bound (mm/°) raw, low-pass, ``variant``; over 4×
    (silent); the variant's coverage and the 1 mm transient's added error."""
    lines = [f"seed mode bone: x bound mm/deg raw | lowpass | {variant}; over4x raw/lp/sm (silent raw); "
             "2sigma t/r (about the mean error); jerk 1.0 added mm/deg (raw window); "
             "flagged 1/2/5 mm off: mm"]
    for seed, modes in res.items():
        for mode, bones in modes.items():
            for b, r in bones.items():
                s, j = r[variant], r[variant]["transient"].get("1.0", {})
                lines.append(f"{seed} {mode[:3]} {b:9s} {r['raw']['rms_over_bound']} | "
                             f"{r['lowpass']['rms_over_bound']} | {s['rms_over_bound']}; "
                             f"{len(r['raw']['over_4x'])}/{len(r['lowpass']['over_4x'])}/{len(s['over_4x'])} "
                             f"({len(r['raw']['silent_over_4x'])}); {s['within_2_sigma']} "
                             f"({s['within_2_sigma_about_mean']}); {j.get('added')} ({j.get('raw')}); "
                             f"{[o['error_mm'] for o in s['flagged_outlier'].values()]}")
    return lines


def main(argv=None) -> int:
    """Run the study; the JSON (stamped) to ``--out``, the table to stderr."""
    import sys

    from core.studies.tracking import _study_cli as cli

    module = "core.studies.tracking.smoother"  # (__name__ is __main__ under python -m)
    p = cli.parser(module, __doc__)
    p.add_argument("--seeds", default="0,3,4")
    p.add_argument("--variants", default=",".join(VARIANTS))
    p.add_argument("--machine", default="this 2-core x86_64 machine, shared")
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    res = {"runs": run(cli.ints(a.seeds), cli.names(a.variants)),
           "variants": {k: VARIANTS[k] for k in cli.names(a.variants)},
           "transient": {"frame": T0, "natural_hz": TRANSIENT_HZ, "damping": TRANSIENT_ZETA,
                         "window": [T0 - 3, T0 + 12]}}
    print("\n".join(table(res["runs"], cli.names(a.variants)[0])), file=sys.stderr)
    if a.out:
        cli.write_stamped(a.out, module, argv, a.machine, res)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
