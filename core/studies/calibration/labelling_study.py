"""Labelling acceptance and the image-based end-to-end calibration (thesis §5.4).

``python -m core.studies.calibration.labelling_study [--out DIR] [--figures DIR] [--quick]``

1. **Rendered frames**: spirals moved through the volume of the 512-pixel foot rig are rendered
   through the image chain (quantum noise, blur, glare, roll-off; distortion off), beads are
   detected and localised with :mod:`core.markers` and 0-3 detections per view are removed at
   random (missed or occluded beads, on top of the beads the views already hide by overlap).
   Both views of every frame are labelled by :func:`~core.calibration.label_sequence` with the
   epipolar geometry estimated from the sequence itself (no rig given).
2. **Projected points**: many more frames (exact projections, 0.05 px noise, 0-3 beads missing per
   view, the spiral axis up to 30° out of the ideal orientation), same labelling.
3. **The cube** (15 beads, labelled by RANSAC): frames of projected points as in 2.
4. **End to end**: the labelled rendered frames of the 33-bead spiral feed the bundle
   adjustment; the calibrated rig is compared with the truth.

``by_missing`` splits the frames by the most beads absent from one view's detections (removed
at random, hidden or merged by overlap; for projected frames exactly the removed ones).
A frame counts as *correct* when it is accepted and every label in both views is right (up to
the object's symmetry, applied to both views alike); *wrong* when accepted with any wrong label;
*rejected* when the labelling reports it cannot decide.
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
from core.calibration.detection import ObjectDetections, detect_object_beads
from core.calibration.errormap import capture_lattice, reconstruction_errors
from core.calibration.matching import label_sequence
from core.calibration.objects import CalibrationTarget, cube_target, spiral_target
from core.synthetic.capture import capture_centre, capture_poses, render
from core.synthetic.imaging import ImagingModel
from core.synthetic.rig import foot_rig

__all__ = ["main", "run_labelling_study", "score_frames"]


def _correct(fr, truth_uv, target: CalibrationTarget, tol_px: float) -> bool:
    """All labels of both views right, up to one symmetry applied to both views."""
    for p in target.symmetries:
        ok = True
        for lab, uv in zip(fr.labellings, truth_uv, strict=True):
            k = lab.labels >= 0
            if np.any(np.linalg.norm(lab.uv[k] - uv[p[lab.labels[k]]], axis=1) > tol_px):
                ok = False
                break
        if ok:
            return True
    return False


def score_frames(frames, truth_uv, target: CalibrationTarget, *, tol_px: float = 2.0, missing=None) -> dict:
    """Counts of correct / wrong / rejected frames and the labelled fraction of detections;
    with ``missing`` (per frame, e.g. the most beads absent from a view) also the counts per
    value of ``missing`` (``by_missing``: value -> [frames, correct])."""
    c = w = r = 0
    frac, reasons, by = [], {}, {}
    miss = [None] * len(frames) if missing is None else list(missing)
    for fr, uv, k in zip(frames, truth_uv, miss, strict=True):
        ok = False
        if not fr.ok:
            r += 1
            key = fr.reason.split(" (")[0][:80]
            reasons[key] = reasons.get(key, 0) + 1
        elif _correct(fr, uv, target, tol_px):
            c += 1
            ok = True
        else:
            w += 1
        if fr.ok:
            frac += [lab.n_labelled / max(len(lab.uv), 1) for lab in fr.labellings]
        if k is not None:
            b = by.setdefault(int(k), [0, 0])
            b[0] += 1
            b[1] += int(ok)
    n = len(frames)
    out = {"frames": n, "correct": c, "wrong": w, "rejected": r, "correct_percent": 100.0 * c / n,
           "labelled_fraction_of_detections": float(np.mean(frac)) if frac else None,
           "rejected_reasons": reasons}
    if missing is not None:
        out["by_missing"] = {str(k): by[k] for k in sorted(by)}
    return out


def _most_missing(target, dets) -> list[int]:
    """Per frame: the most beads absent from one view's detections (removed, hidden or merged)."""
    return [max(len(target) - len(d) for d in pair) for pair in dets]


def _drop(det: ObjectDetections, g, k: int) -> ObjectDetections:
    return det.without(g.choice(len(det), min(k, len(det)), replace=False)) if k else det


def rendered_frames(target, rig, n: int, *, rng, drop_max: int = 3, keep_images: int = 0):
    """Render, detect, drop: per frame the detection pair and the true (ideal) bead positions."""
    ims = [ImagingModel.fluoroscope(c, rng=rng, distortion=None) for c in rig]
    ppm = [c.fx / np.linalg.norm(capture_centre(rig) - c.source) for c in rig]
    poses = capture_poses(rig, target, n, rng=rng, margin_px=0.02 * rig[0].width)
    dets, truth, images, dropped, loc = [], [], [], [], []
    for T in poses:
        fr = render(rig, target, T, rng=rng, imaging=ims)
        pair = []
        for v in range(len(rig)):
            img = ims[v].to_float(fr.image[v])
            d = detect_object_beads(img, target.size_classes[0], px_per_mm=ppm[v])
            dist = np.linalg.norm(d.uv[:, None] - fr.ideal_uv[v][None], axis=2).min(axis=1)
            loc.append(dist)
            k = int(rng.integers(0, drop_max + 1))
            dropped.append(k)
            pair.append(_drop(d, rng, k))
            if len(images) < 2 * keep_images:
                images.append(img)
        dets.append(tuple(pair))
        truth.append(fr.ideal_uv)
    loc = np.concatenate(loc)
    stats = {"median_localisation_error_px": float(np.median(loc)),
             "p95_localisation_error_px": float(np.percentile(loc[loc < 3], 95)),
             "mean_detections_dropped_per_view": float(np.mean(dropped))}
    return dets, truth, poses, images, stats


def projected_frames(target, rig, n: int, *, rng, drop_max: int = 3, noise_px: float = 0.05):
    poses = capture_poses(rig, target, n, rng=rng, axis_tilt_deg=30.0)
    ppm = [c.fx / np.linalg.norm(capture_centre(rig) - c.source) for c in rig]
    sizes, cls = target.size_classes
    dets, truth = [], []
    for T in poses:
        uv = rig.project(target.centers_lab(T))
        pair = []
        for v in range(len(rig)):
            keep = rng.permutation(len(target))[: len(target) - int(rng.integers(0, drop_max + 1))]
            pair.append(ObjectDetections(uv[v, keep] + rng.normal(0, noise_px, (len(keep), 2)),
                                         np.full((len(keep), 2), noise_px), target.diameters[keep] * ppm[v],
                                         cls[keep], ppm[v], sizes, np.full(len(keep), 50.0)))
        dets.append(tuple(pair))
        truth.append(uv)
    return dets, truth


def end_to_end(rig, target, frames, obs, poses, truth) -> dict:
    """Bundle adjustment on the labelled rendered frames; errors against the true rig."""
    ok = [i for i, fr in enumerate(frames) if fr.ok]
    ref = ok[0]
    sym = next(p for p in target.symmetries if _correct(frames[ref], truth[ref], target, 2.0))
    T_ref = poses[ref].copy()
    if not np.array_equal(sym, np.arange(len(target))):  # reference labelled by its mirror image
        from core.markers.pose import rigid_fit

        T_ref = rigid_fit(target.centers, target.centers_lab(poses[ref])[sym]).T
    t0 = time.perf_counter()
    res = bundle_adjust(obs, [(c.width, c.height) for c in rig], reference=0, T_lab_from_reference=T_ref,
                        pixel_size=rig[0].pixel_size, pixel_sigma=0.05)
    secs = time.perf_counter() - t0
    if not res.ok:
        return {"ok": False, "reason": res.reason}
    lattice = capture_lattice(rig, spacing_mm=10.0)
    e = reconstruction_errors(rig, res.rig, lattice)[0]
    return {"ok": True, "frames_used": len(obs), "observations": len(res.frame_index),
            "outliers": int(res.outliers.sum()), "reprojection_rms_px": res.rms_px, "sigma0": res.sigma0,
            "seconds": secs,
            "focal_error_percent": [100 * (c.fx / t.fx - 1) for c, t in zip(res.rig, rig, strict=True)],
            "sid_error_mm": [c.sid - t.sid for c, t in zip(res.rig, rig, strict=True)],
            "source_error_mm": [float(np.linalg.norm(c.source - t.source))
                                for c, t in zip(res.rig, rig, strict=True)],
            "predicted_source_std_mm": [s["source"].tolist() for s in res.camera_std],
            "lattice_rms_mm": float(np.sqrt(np.mean(e**2))), "lattice_max_mm": float(e.max())}


def run_labelling_study(*, quick: bool = False, seed: int = 0, out_dir=None, figures_dir=None,
                        progress=None) -> dict:
    say = progress or (lambda msg: None)
    g = np.random.default_rng(seed)
    rig512, rig1024 = foot_rig(seed=0, pixels=512), foot_rig(seed=0, pixels=1024)
    n_render, n_points, n_cube = (6, 40, 10) if quick else (60, 300, 200)
    res = {"machine": {"platform": platform.platform(), "processor": platform.machine(),
                       "cpus": os.cpu_count(), "python": sys.version.split()[0], "numpy": np.__version__,
                       "load_average_at_start": list(os.getloadavg())},
           "config": {"rendered_frames": n_render, "projected_frames": n_points,
                      "cube_projected_frames": n_cube, "drop_max": 3,
                      "rendered_pixels": 512, "projected_pixels": 1024}}
    for n_beads in (23, 33):
        tg = spiral_target(n_beads)
        say(f"spiral{n_beads}: rendering {n_render} frames")
        t0 = time.perf_counter()
        dets, truth, poses, images, stats = rendered_frames(tg, rig512, n_render, rng=g,
                                                            keep_images=5 if n_beads == 33 else 0)
        t1 = time.perf_counter()
        frames, obs, _ = label_sequence(tg, dets, rng=g)
        t2 = time.perf_counter()
        res[f"spiral{n_beads}_rendered"] = {**score_frames(frames, truth, tg,
                                                           missing=_most_missing(tg, dets)), **stats,
                                            "render_detect_seconds_per_frame": (t1 - t0) / n_render,
                                            "label_seconds_per_frame": (t2 - t1) / n_render}
        if n_beads == 33:
            say("end-to-end bundle adjustment on the rendered frames")
            res["end_to_end_spiral33_rendered"] = end_to_end(rig512, tg, frames, obs, poses, truth)
            shown = [f for f in range(len(images) // 2) if frames[f].ok]
            if figures_dir is not None and shown:
                from core.studies.calibration.plots import labelling_figure

                f = shown[0]
                Path(figures_dir).mkdir(parents=True, exist_ok=True)
                labelling_figure(images[2 * f : 2 * f + 2], frames[f].labellings, tg.bead_ids,
                                 Path(figures_dir) / "calibration_labelling.png",
                                 titles=(f"frame {f}, cam01 (512 px, rendered)", "cam02"))
        say(f"spiral{n_beads}: {n_points} frames of projected points")
        dets, truth = projected_frames(tg, rig1024, n_points, rng=g)
        t0 = time.perf_counter()
        frames, _, _ = label_sequence(tg, dets, rng=g)
        res[f"spiral{n_beads}_projected"] = {**score_frames(frames, truth, tg,
                                                            missing=_most_missing(tg, dets)),
                                             "label_seconds_per_frame": (time.perf_counter() - t0) / n_points}
    cube = cube_target()
    say(f"cube15: {n_cube} frames of projected points")
    dets, truth = projected_frames(cube, rig1024, n_cube, rng=g)
    t0 = time.perf_counter()
    frames, _, _ = label_sequence(cube, dets, rng=g)
    res["cube15_projected"] = {**score_frames(frames, truth, cube, missing=_most_missing(cube, dets)),
                               "label_seconds_per_frame": (time.perf_counter() - t0) / n_cube}
    if out_dir is not None:
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        (Path(out_dir) / "labelling_study.json").write_text(json.dumps(res, indent=1))
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m core.studies.calibration.labelling_study",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=None)
    ap.add_argument("--figures", default=None)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    res = run_labelling_study(quick=a.quick, seed=a.seed, out_dir=a.out, figures_dir=a.figures,
                              progress=lambda m: print(f"[labelling study] {m}", file=sys.stderr, flush=True))
    print(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
