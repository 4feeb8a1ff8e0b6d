"""Acceptance study of the calibration (thesis Ch. 5) on the synthetic foot rig.

``python -m core.studies.calibration.study [--out DIR] [--quick] [--figures DIR]`` prints a JSON
summary and writes ``study.json`` and the figures. Parts:

1. **DLT instability** (§5.2.1): the 15-bead cube at the centre of the capture volume, one frame,
   bead positions with Gaussian noise of 0.05 px per axis, calibrated by the DLT ``n_dlt`` times:
   spread of the focal length / SID and of the source positions.
2. **Bundle adjustment**: a 33-bead spiral moved through the volume (``n_frames`` poses from
   :func:`~core.synthetic.capture.capture_poses`), 0.05 px noise, lab frame from frame 0,
   ``n_ba`` noise draws: focal length, SID and source errors against the truth, and the
   standard deviations the adjustment predicts.
3. **Error maps** (§5.2.2): reconstruction error over the 10 mm lattice filling the intersection
   of both cones for the DLT rigs and the BA rigs (calibration error alone, and with 0.05 px
   noise on the lattice points' images), and per-point mean/max histograms at 0.05/0.1/0.25 px.
4. **Independent object**: the cube at another place, triangulated with each BA rig.
5. **Sensitivity** (§5.2.1, Table 5.1): 5000 Latin-hypercube samples per camera (one bead at a
   time, 0.01-0.25 px) and Sobol indices (``n_sobol`` base samples, ±0.25 px).
6. **Real data** (when ``../shared/data`` or ``$TALUS_SAMPLE_DATA`` holds the Autoscoper wrist
   sample): the beads of the three wrist radiograph pairs against the epipolar lines of the real
   calibration (:mod:`core.calibration.epipolar_check`).

Labelling and the image-based end-to-end run are in :mod:`core.studies.calibration.labelling_study`.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

from core.calibration.bundle import bundle_adjust
from core.calibration.dlt import calibrate_dlt
from core.calibration.errormap import capture_lattice, object_reconstruction, reconstruction_errors
from core.calibration.objects import cube_target, spiral_target
from core.calibration.sensitivity import perturbation_study, sobol_analysis
from core.geometry.camera import Rig
from core.geometry.transforms import make_rigid
from core.synthetic.capture import capture_centre, capture_poses, observe
from core.synthetic.rig import foot_rig

__all__ = ["main", "run_study"]


def _stats(x) -> dict:
    x = np.asarray(x, dtype=float)
    return {"mean": float(x.mean()), "std": float(x.std()), "rms": float(np.sqrt(np.mean(x**2))),
            "max_abs": float(np.abs(x).max()), "range": float(np.ptp(x))}


def dlt_instability(rig: Rig, *, n_draws: int, noise_px: float, rng) -> tuple[dict, list[Rig], dict]:
    """Single-frame cube DLTs at ``noise_px``: parameter spread and the rigs."""
    cube = cube_target()
    X = cube.centers_lab(make_rigid(np.eye(3), capture_centre(rig)))
    uv0 = rig.project(X)
    rigs, sid, src, f = [], [], [], []
    for _ in range(n_draws):
        uv = uv0 + rng.normal(0, noise_px, uv0.shape)
        cams = [calibrate_dlt(X, uv[v], width=c.width, height=c.height, pixel_size=c.pixel_size,
                              max_skew_px=50) for v, c in enumerate(rig)]
        if not all(c.ok for c in cams):
            continue
        r = Rig(tuple(c.camera for c in cams))
        rigs.append(r)
        sid.append([c.sid - t.sid for c, t in zip(r, rig, strict=True)])
        f.append([c.fx / t.fx - 1 for c, t in zip(r, rig, strict=True)])
        src.append([c.source - t.source for c, t in zip(r, rig, strict=True)])
    sid, src, f = np.array(sid), np.array(src), np.array(f)
    out = {"n_draws": len(rigs), "noise_px": noise_px,
           "sid_mm": [_stats(sid[:, v]) for v in range(len(rig))],
           "focal_rel_percent": [_stats(100 * f[:, v]) for v in range(len(rig))],
           "source_error_mm": [_stats(np.linalg.norm(src[:, v], axis=1)) for v in range(len(rig))],
           "source_std_xyz_mm": [src[:, v].std(axis=0).tolist() for v in range(len(rig))]}
    return out, rigs, {"sid": sid, "source": src}


def bundle_study(rig: Rig, *, n_frames: int, n_draws: int, noise_px: float,
                 rng) -> tuple[dict, list[Rig], dict]:
    """Spiral BA over ``n_frames`` poses, ``n_draws`` noise draws (new poses each draw)."""
    tg = spiral_target(33)
    sizes = [(c.width, c.height) for c in rig]
    rigs, sid, src, f, pred, times, rms = [], [], [], [], [], [], []
    for _ in range(n_draws):
        poses = capture_poses(rig, tg, n_frames, rng=rng, spread_mm=60)
        frames = observe(rig, tg, poses, noise_px=noise_px, rng=rng)
        t0 = time.perf_counter()
        res = bundle_adjust(frames, sizes, T_lab_from_reference=poses[0], pixel_size=rig[0].pixel_size,
                            pixel_sigma=noise_px)
        times.append(time.perf_counter() - t0)
        if not res.ok:
            continue
        rigs.append(res.rig)
        rms.append(res.rms_px)
        sid.append([c.sid - t.sid for c, t in zip(res.rig, rig, strict=True)])
        f.append([c.fx / t.fx - 1 for c, t in zip(res.rig, rig, strict=True)])
        src.append([c.source - t.source for c, t in zip(res.rig, rig, strict=True)])
        pred.append([[s["sid"], *s["source"]] for s in res.camera_std])
    sid, src, f, pred = np.array(sid), np.array(src), np.array(f), np.array(pred)
    src_err = np.linalg.norm(src, axis=2)
    out = {"n_frames": n_frames, "n_draws": n_draws, "n_ok": len(rigs), "noise_px": noise_px,
           "beads_per_frame": len(tg), "seconds_per_adjustment": _stats(times),
           "reprojection_rms_px": _stats(rms),
           "focal_error_percent": {"max_abs": float(100 * np.abs(f).max()),
                                   "rms": float(100 * np.sqrt(np.mean(f**2)))},
           "sid_error_mm": _stats(sid.ravel()), "source_error_mm": _stats(src_err.ravel()),
           "source_error_max_mm": float(src_err.max()),
           "predicted_std": {"sid_mm": pred[:, :, 0].mean(axis=0).tolist(),
                             "source_xyz_mm": pred[:, :, 1:].mean(axis=0).tolist()},
           "empirical_std": {"sid_mm": sid.std(axis=0).tolist(),
                             "source_xyz_mm": src.std(axis=0).tolist()}}
    return out, rigs, {"sid": sid, "source": src}


def error_maps(rig: Rig, dlt_rigs, ba_rigs, *, noise_px: float, rng) -> tuple[dict, np.ndarray, dict]:
    lattice = capture_lattice(rig, spacing_mm=10.0)
    out, maps = {"n_points": len(lattice), "spacing_mm": 10.0,
                 "bounds_mm": [lattice.min(axis=0).tolist(), lattice.max(axis=0).tolist()]}, {}
    for name, rigs in (("cube_dlt", dlt_rigs), ("spiral_ba", ba_rigs)):
        e0 = reconstruction_errors(rig, rigs, lattice)
        e1 = reconstruction_errors(rig, rigs, lattice, image_noise_px=noise_px, rng=rng)
        out[name] = {"calibration_only": _err_summary(e0), f"with_{noise_px}px_image_noise": _err_summary(e1),
                     "n_rigs": len(rigs)}
        maps[name] = e0
    return out, lattice, maps


def _err_summary(e: np.ndarray) -> dict:
    return {"rms_mm": float(np.sqrt(np.mean(e**2))), "mean_mm": float(e.mean()),
            "p95_mm": float(np.percentile(e, 95)), "max_mm": float(e.max()),
            "worst_point_mean_mm": float(e.mean(axis=0).max()),
            "worst_point_rms_mm": float(np.sqrt(np.mean(e**2, axis=0)).max())}


def independent_object(rig: Rig, rigs, *, noise_px: float, rng) -> dict:
    cube = cube_target()
    T = make_rigid(np.eye(3), capture_centre(rig) + np.array([35.0, -25.0, 30.0]))
    rms, dist = [], []
    for r in rigs:
        uv = rig.project(cube.centers_lab(T)) + rng.normal(0, noise_px, (len(rig), len(cube), 2))
        rec = object_reconstruction(r, cube.centers, uv)
        rms.append(rec.rms_mm)
        dist.append(rec.distance_errors)
    return {"object": "cube15 at +(35, -25, 30) mm", "noise_px": noise_px, "fit_rms_mm": _stats(rms),
            "inter_bead_distance_error_mm": _stats(np.concatenate(dist))}


def sensitivity(rig: Rig, *, n_samples: int, n_sobol: int, rng) -> tuple[dict, object, dict]:
    X = cube_target().centers_lab(make_rigid(np.eye(3), capture_centre(rig)))
    out, first = {}, None
    t0 = time.perf_counter()
    for cam in rig:
        st = perturbation_study(cam, X, n_samples=n_samples, rng=rng)
        sp = st.spread()
        out[cam.name] = {k: {kk: vv for kk, vv in d.items() if kk != "by_amplitude"} for k, d in sp.items()}
        out[cam.name]["by_amplitude"] = {k: sp[k]["by_amplitude"] for k in ("sid", "X", "Y", "Z")}
        first = first or st
    out["seconds"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    sob = sobol_analysis(rig[0], X, amplitude=0.25, n=n_sobol, rng=rng)
    out["sobol"] = {"camera": rig[0].name, "n_evaluations": sob.n_evaluations, "table": sob.table(),
                    "seconds": time.perf_counter() - t0}
    return out, first, sob


def wrist_epipolar(figures_dir=None) -> dict:
    """Part 6: distances of the wrist beads from the real rig's epipolar lines, per frame pair."""

    from core.calibration.epipolar_check import epipolar_check
    from core.samples import load_wrist_sample
    from core.studies import sample_data_dir

    folder = sample_data_dir() / "autoscoper_wrist"
    if not folder.is_dir():
        return {"skipped": f"wrist sample not found at {folder}"}
    sample = load_wrist_sample(folder)
    out = {}
    for k, path in enumerate(sample.frame_paths[0]):
        imgs = [sample.frame(0, k), sample.frame(1, k)]
        chk = epipolar_check(sample.rig, imgs)
        out[path.stem.split(".")[-1]] = {**chk.summary(), "distances_px": np.round(
            np.concatenate([chk.d_view1, chk.d_view2]), 3).tolist()}
        if figures_dir is not None and k == 1:
            from core.studies.calibration.plots import epipolar_figure

            epipolar_figure(imgs, chk, Path(figures_dir) / "calibration_wrist_epipolar.png",
                            names=(sample.rig[0].name, sample.rig[1].name))
    return out


def run_study(*, quick: bool = False, seed: int = 0, out_dir=None, figures_dir=None, progress=None) -> dict:
    """Run every part (module docstring); ``quick`` shrinks the draws ~10x."""
    say = progress or (lambda msg: None)
    rng = np.random.default_rng(seed)
    rig = foot_rig(seed=0, pixels=1024)
    cfg = {"n_dlt": 60 if quick else 500, "n_ba": 3 if quick else 20, "n_frames": 25 if quick else 40,
           "noise_px": 0.05, "n_samples": 1000 if quick else 5000, "n_sobol": 128 if quick else 1024}
    res = {"machine": {"platform": platform.platform(), "processor": platform.machine(),
                       "cpus": os.cpu_count(), "python": sys.version.split()[0], "numpy": np.__version__,
                       "load_average_at_start": list(os.getloadavg())},
           "config": cfg, "rig": [{"name": c.name, "sid_mm": c.sid, "fx_px": c.fx, "pixel_mm": c.pixel_size,
                                   "source_mm": c.source.tolist()} for c in rig],
           "view_angle_deg": float(np.degrees(rig.angle_between_views()))}
    say("DLT instability")
    noise = cfg["noise_px"]
    res["dlt"], dlt_rigs, dlt_dev = dlt_instability(rig, n_draws=cfg["n_dlt"], noise_px=noise, rng=rng)
    say("bundle adjustment")
    res["bundle"], ba_rigs, ba_dev = bundle_study(rig, n_frames=cfg["n_frames"], n_draws=cfg["n_ba"],
                                                  noise_px=cfg["noise_px"], rng=rng)
    res["bundle_20_frames"] = bundle_study(rig, n_frames=20, n_draws=max(3, cfg["n_ba"] // 2),
                                           noise_px=cfg["noise_px"], rng=rng)[0]
    say("error maps")
    res["error_map"], lattice, maps = error_maps(rig, dlt_rigs, ba_rigs, noise_px=cfg["noise_px"], rng=rng)
    levels = {}
    for lvl in (0.05, 0.1, 0.25):
        _, rr, _ = dlt_instability(rig, n_draws=max(20, cfg["n_dlt"] // 5), noise_px=lvl, rng=rng)
        e = reconstruction_errors(rig, rr, lattice)
        levels[f"cube DLT {lvl} px"] = (e.mean(axis=0), e.max(axis=0))
        res["error_map"].setdefault("dlt_by_noise", {})[str(lvl)] = _err_summary(e)
    levels["spiral BA 0.05 px"] = (maps["spiral_ba"].mean(axis=0), maps["spiral_ba"].max(axis=0))
    say("independent object")
    res["independent_object"] = {"spiral_ba": independent_object(rig, ba_rigs, noise_px=noise, rng=rng),
                                 "cube_dlt": independent_object(rig, dlt_rigs[:50], noise_px=noise, rng=rng)}
    say("sensitivity")
    res["sensitivity"], first, sob = sensitivity(rig, n_samples=cfg["n_samples"], n_sobol=cfg["n_sobol"],
                                                   rng=rng)
    say("real data: wrist epipolar lines")
    if figures_dir is not None:
        Path(figures_dir).mkdir(parents=True, exist_ok=True)
    res["wrist_epipolar"] = wrist_epipolar(figures_dir)
    if figures_dir is not None:
        from core.studies.calibration import plots

        d = Path(figures_dir)
        d.mkdir(parents=True, exist_ok=True)
        srcs = np.array([c.source for c in rig])
        res["figures"] = [str(p) for p in (
            plots.instability_figure(dlt_dev, ba_dev, d / "calibration_dlt_vs_ba.png"),
            plots.error_map_figure(lattice, {"cube DLT (1 frame)": maps["cube_dlt"].mean(axis=0),
                                             "spiral BA": maps["spiral_ba"].mean(axis=0)}, srcs,
                                   d / "calibration_error_map.png"),
            plots.error_histogram_figure(levels, d / "calibration_error_histograms.png"),
            plots.sensitivity_figure(first, d / "calibration_sensitivity.png", camera=rig[0].name),
            plots.sobol_figure(sob, d / "calibration_sobol.png", camera=rig[0].name))]
    if out_dir is not None:
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        (Path(out_dir) / "study.json").write_text(json.dumps(res, indent=1))
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m core.studies.calibration.study",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=None, help="folder for study.json")
    ap.add_argument("--figures", default=None, help="folder for the PNG figures")
    ap.add_argument("--quick", action="store_true", help="~10x fewer draws (a smoke run)")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    res = run_study(quick=a.quick, seed=a.seed, out_dir=a.out, figures_dir=a.figures,
                    progress=lambda m: print(f"[calibration study] {m}", file=sys.stderr, flush=True))
    print(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
