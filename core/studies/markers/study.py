"""Thesis §4.3 reproduced on synthetic lattices: robustness, stability and accuracy of localizers.

Run ``python -m core.studies.markers.study [--quick] [--out DIR]``: it renders the 21-bead lattice of
:mod:`core.synthetic.lattice` in ``n_frames`` static frames with independent quantum noise,
runs all seven localizers (:data:`core.markers.batch.METHODS`) and writes ``markers_study.json``
plus the figures ``markers_convergence.png``, ``markers_drift.png``,
``markers_intermarker.png`` and ``markers_dose.png`` (via :mod:`core.studies.markers.plots`). The
moving-bone pose study (:func:`core.studies.markers.motion_study.moving_bone_study`) and a dose sweep
(drift and inter-marker σ of three localizers at ¼–4 × the dose, :func:`dose_sweep`) run too
and land in the same JSON.

Experiments (thesis numbering):

1. **Robustness to the initial guess** (Fig. 4.4): for perturbations of 0–300 % of each bead's
   radius (nine levels), ``n_mc`` guesses per bead at that distance from the true centre in a
   uniformly random direction, each in a different noisy frame; error = distance between the
   estimate and the true centre (px). Failures are counted separately.
2. **Frame-to-frame stability** (Table 4.1): initial guesses from the intensity-weighted
   centroid of detections on the temporal mean of the frames (as the thesis did); each
   localizer runs on every frame; drift = distance between consecutive frames' estimates of a
   bead (px): mean, SD and RMS. Also the per-axis scatter about each bead's mean, the bias of
   that mean, and the ratio of the scatter to the localizer's own predicted σ.
3. **Inter-marker distances** (Table 4.2): for every frame and every pair of grid neighbours,
   the estimated distance (px, scaled to mm in the beads' plane) minus the 20 mm pitch: μ, σ.

The "thesis-like" noise level is :meth:`ImagingModel.fluoroscope`'s default dose (5000 detected
quanta/mm² at full fluence, the lab's raw frames); at that dose the iterative Gaussian of the
thesis shows ~0.04 px mean drift, as in Table 4.1.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from core.markers.batch import METHODS, RECOMMENDED, localize
from core.markers.detect import detect_beads
from core.synthetic.lattice import LatticeScene, make_lattice_scene

__all__ = ["StudyConfig", "convergence", "dose_sweep", "drift_and_distances", "run_study"]


@dataclass(frozen=True)
class StudyConfig:
    """Sizes of the study (defaults: the thesis's; :meth:`quick` for tests)."""

    n_frames: int = 1000
    n_mc: int = 1000
    levels_percent: tuple[float, ...] = (0.0, 37.5, 75.0, 112.5, 150.0, 187.5, 225.0, 262.5, 300.0)
    fluence_per_mm2: float = 5000.0
    seed: int = 0
    motion_frames: int = 50
    dose_factors: tuple[float, ...] = (0.25, 0.5, 1.0, 2.0, 4.0)
    dose_frames: int = 200

    @classmethod
    def quick(cls) -> StudyConfig:
        return cls(n_frames=40, n_mc=40, levels_percent=(0.0, 150.0, 300.0), motion_frames=10,
                   dose_factors=(0.5, 2.0), dose_frames=20)


def convergence(scene: LatticeScene, frames: np.ndarray, cfg: StudyConfig, methods=tuple(METHODS),
                rng=None) -> dict:
    """Experiment 1: final error vs initial-guess perturbation (JSON-ready dict per method)."""
    g = np.random.default_rng(cfg.seed + 1) if rng is None else rng
    F, N = len(frames), len(scene.uv)
    radius = scene.diameter_px / 2.0
    out = {m: [] for m in methods}
    for level in cfg.levels_percent:
        n_pass = int(np.ceil(cfg.n_mc / F))
        ang = g.uniform(0.0, 2.0 * np.pi, size=(n_pass, F, N))
        dirs = np.stack([np.cos(ang), np.sin(ang)], axis=-1)
        guesses = scene.uv + (level / 100.0) * radius[:, None] * dirs  # (n_pass, F, N, 2)
        for m in methods:
            errs, fails = [], 0
            for p in range(n_pass):
                loc = localize(frames, guesses[p], diameter_px=scene.diameter_px, method=m)
                e = np.linalg.norm(loc.uv - scene.uv, axis=-1)
                errs.append(e[np.isfinite(e)])
                fails += int((~loc.ok).sum())
            e = np.concatenate(errs)[: cfg.n_mc * N]
            n = n_pass * F * N
            out[m].append({
                "level_percent": level, "n": n, "failed_fraction": fails / n,
                "mean": _f(e.mean()), "sd": _f(e.std()), "median": _f(np.median(e)),
                "p95": _f(np.percentile(e, 95)), "max": _f(e.max()),
                "below_0.1px": _f(np.mean(e < 0.1)),
            })
    return out


def _f(x) -> float | None:
    x = float(x)
    return x if np.isfinite(x) else None


def initial_guesses(scene: LatticeScene, frames: np.ndarray) -> np.ndarray:
    """Thesis §4.3.1 start: detections on the temporal mean, refined by the intensity centroid,
    labelled by the nearest true bead (21 × 2; NaN for a bead not detected)."""
    mean = frames.mean(axis=0)
    det = detect_beads(mean, diameter_px=float(np.median(scene.diameter_px)), refine=False)
    guesses = np.full_like(scene.uv, np.nan)
    if len(det):
        d = np.linalg.norm(det.uv[:, None] - scene.uv[None], axis=2)
        j = np.argmin(d, axis=0)
        ok = d[j, np.arange(len(scene.uv))] < scene.diameter_px / 2
        guesses[ok] = det.uv[j[ok]]
    loc = localize(mean, guesses, diameter_px=scene.diameter_px, method="intensity_centroid")
    return np.where(loc.ok[:, None], loc.uv, guesses)


def drift_and_distances(scene: LatticeScene, frames: np.ndarray, methods=tuple(METHODS)) -> tuple[dict, dict]:
    """Experiments 2 and 3: per-method drift statistics and inter-marker distance errors."""
    start = initial_guesses(scene, frames)
    drift, dist = {}, {}
    i, j = scene.pairs.T
    for m in methods:
        t0 = time.perf_counter()
        loc = localize(frames, start, diameter_px=scene.diameter_px, method=m)
        dt = time.perf_counter() - t0
        uv = loc.uv  # (F, N, 2)
        step = np.linalg.norm(np.diff(uv, axis=0), axis=-1).ravel()
        step = step[np.isfinite(step)]
        scatter = np.nanstd(uv, axis=0)  # (N, 2) per-axis SD about each bead's mean
        bias = np.nanmean(uv, axis=0) - scene.uv
        pred = np.nanmean(loc.sigma, axis=0)
        drift[m] = {
            "mean": _f(step.mean()), "sd": _f(step.std()), "rms": _f(np.sqrt(np.mean(step**2))),
            "scatter_px": _f(np.sqrt(np.nanmean(scatter**2))),
            "bias_rms_px": _f(np.sqrt(np.nanmean(bias**2))),
            "predicted_sigma_px": _f(np.sqrt(np.nanmean(pred**2))),
            "scatter_over_predicted": _f(np.sqrt(np.nanmean(scatter**2)) / np.sqrt(np.nanmean(pred**2))),
            "failed_fraction": _f(np.mean(~loc.ok)), "seconds": dt,
            "localisations_per_s": loc.status.size / dt,
        }
        d = np.linalg.norm(uv[:, i] - uv[:, j], axis=-1) * scene.mm_per_px - scene.pitch_mm
        d = d[np.isfinite(d)]
        hist, edges = np.histogram(d, bins=600, range=(-0.6, 0.6))  # 2 µm bins
        dist[m] = {"mu": _f(d.mean()), "sigma": _f(d.std()), "n": int(d.size),
                   "hist": hist.tolist(), "edges": edges.tolist()}
    return drift, dist


def dose_sweep(cfg: StudyConfig, methods=("intensity_centroid", "iterative_gaussian", RECOMMENDED)) -> list:
    """Drift RMS and inter-marker σ of a few localizers at multiples of the thesis-like dose."""
    out = []
    for k in cfg.dose_factors:
        dose = cfg.fluence_per_mm2 * k
        scene = make_lattice_scene(fluence_per_mm2=dose, seed=cfg.seed)
        frames = scene.frames(cfg.dose_frames, np.random.default_rng(cfg.seed + 7))
        drift, dist = drift_and_distances(scene, frames, methods)
        out.append({"dose_factor": k, "fluence_per_mm2": dose,
                    "photons_per_pixel": scene.imaging.photons_per_pixel,
                    "drift_rms_px": {m: drift[m]["rms"] for m in methods},
                    "intermarker_sigma_mm": {m: dist[m]["sigma"] for m in methods}})
    return out


def run_study(cfg: StudyConfig = StudyConfig(), *, progress=None) -> dict:
    """All three experiments and the moving-bone pose study; returns the JSON-ready result."""
    from core.studies.markers.motion_study import moving_bone_study

    say = progress or (lambda msg: None)
    t0 = time.perf_counter()
    scene = make_lattice_scene(fluence_per_mm2=cfg.fluence_per_mm2, seed=cfg.seed)
    frames = scene.frames(cfg.n_frames, np.random.default_rng(cfg.seed))
    say(f"rendered {cfg.n_frames} lattice frames")
    drift, dist = drift_and_distances(scene, frames)
    say("drift and inter-marker distances done")
    conv = convergence(scene, frames, cfg)
    say("convergence done")
    motion = moving_bone_study(n_frames=cfg.motion_frames, seed=cfg.seed)
    say("moving bone done")
    doses = dose_sweep(cfg)
    say("dose sweep done")
    rec = RECOMMENDED
    worst = max(c["mean"] for c in conv[rec])
    acceptance = {
        "convergence_mean_error_px_max_over_levels": worst,
        "convergence_ok (< 0.1 px)": bool(worst < 0.1),
        "drift_rms_px": drift[rec]["rms"], "drift_ok (<= 0.05 px)": bool(drift[rec]["rms"] <= 0.05),
        "intermarker_sigma_mm": dist[rec]["sigma"],
        "intermarker_ok (<= 0.035 mm)": bool(dist[rec]["sigma"] <= 0.035),
        "pose_rotation_rms_deg": motion["rotation_error_deg"]["rms"],
        "pose_position_rms_mm": motion["position_error_mm"]["rms"],
        "pose_ok (<= 0.05 mm / 0.05 deg)": bool(motion["rotation_error_deg"]["rms"] <= 0.05
                                                 and motion["position_error_mm"]["rms"] <= 0.05
                                                 and motion["frames_without_pose"] == 0),
    }
    return {
        "machine": {"platform": platform.platform(), "processor": platform.machine(),
                    "python": sys.version.split()[0]},
        "config": asdict(cfg),
        "scene": {"pixel_mm": scene.camera.pixel_size, "sid_mm": scene.camera.sid,
                  "mm_per_px_in_bead_plane": scene.mm_per_px,
                  "bead_diameters_px": sorted({round(float(d), 3) for d in scene.diameter_px}),
                  "photons_per_pixel": scene.imaging.photons_per_pixel,
                  "psf_sigma_px": scene.imaging.psf_sigma_px, "n_beads": len(scene.uv),
                  "n_pairs": len(scene.pairs)},
        "methods": METHODS, "recommended": rec,
        "convergence": conv, "drift": drift, "intermarker": dist, "moving_bone": motion,
        "dose_sweep": doses,
        "acceptance": acceptance, "seconds": time.perf_counter() - t0,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m core.studies.markers.study",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small sizes (a smoke run)")
    ap.add_argument("--out", default="resources/figures", help="folder for the JSON and figures")
    args = ap.parse_args(argv)
    cfg = StudyConfig.quick() if args.quick else StudyConfig()
    res = run_study(cfg, progress=lambda m: print(m, file=sys.stderr, flush=True))
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "markers_study.json").write_text(json.dumps(res, indent=1))
    from core.studies.markers.plots import study_figures

    study_figures(res, out)
    summary = {"acceptance": res["acceptance"],
               "drift_rms_px": {m: d["rms"] for m, d in res["drift"].items()},
               "intermarker_sigma_mm": {m: d["sigma"] for m, d in res["intermarker"].items()}}
    print(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
