"""Acceptance and timing of ``talus calibrate`` on the demo's calibration session.

``python -m core.studies.calibration.session_acceptance [--session DIR] [--pixels 1024]
[--spiral 40] [--grid 5] [--out FILE]`` writes a synthetic session
(:func:`core.synthetic.session.write_calibration_session`) unless one is given, calibrates it
from its images alone (:func:`core.calibration.session.calibrate_session`, timed per step) and
compares the result with the session's ``truth/`` (read here only):

* **distortion on the independent bead lattice**: the lattice beads detected in each lattice
  frame, corrected by the fitted model, against their true pinhole positions after the best
  similarity (the correction is defined up to one: the camera absorbs it), RMS in mm at the
  intensifier; and the user-side check (inter-bead distances and right angles);
* **cameras**: focal length (relative), source position and SID against the truth, with the
  predicted standard deviations (and each axis's error in them);
* **where the source error comes from** (:func:`source_error_analysis`): the bundle adjustment
  re-run with the true image positions, with the fitted correction of the true positions, with
  the detections of one object and the truth of the other, and with the measured detection
  residuals under random signs (an ensemble); the detection residuals by how close a bead's image
  comes to another's; each source error split along and across its principal ray;
* **3-D reconstruction over the capture volume**: lattice points (10 mm) in both cones and
  inside both round intensifier fields (where a bead can be seen), projected by the true
  cameras, distorted by the true intensifiers, corrected by the fitted models and triangulated
  by the calibrated rig; RMS distance to the true points (the error of
  the calibration alone), and with the bundle's own localisation noise added.

It prints the JSON and writes it to ``--out``.
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

__all__ = ["evaluate", "main", "run"]


def _truth(session_dir: Path):
    from core.geometry.camera import Camera, Rig
    from core.synthetic.distortion import Distortion

    doc = json.loads((session_dir / "truth" / "truth.json").read_text())
    arrays = dict(np.load(session_dir / "truth" / "truth.npz"))
    cams = [Camera(np.array(c["K"]), np.array(c["R"]), np.array(c["t"]), c["width"], c["height"],
                   c["pixel_size_mm"], c["session_name"]) for c in doc["cameras"]]
    dist, field = {}, {}
    for name, m in doc["imaging"].items():
        field[name] = m.get("aperture_radius")
        d = m.get("distortion")
        dist[name] = None if d is None else Distortion(tuple(d["center"]), d["scale_px"], d["k1"], d["k2"],
                                                       d["twist_rad"], d["twist_power"])
    return Rig(tuple(cams)), dist, arrays, field


def _similarity_residual(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """|q - S(p)| after the least-squares similarity S (complex ``a p + b``)."""
    zp, zq = p[:, 0] + 1j * p[:, 1], q[:, 0] + 1j * q[:, 1]
    A = np.column_stack([zp, np.ones_like(zp)])
    coef = np.linalg.lstsq(A, zq, rcond=None)[0]
    return np.abs(A @ coef - zq)


def _lattice_truth(session, cal, arrays) -> dict:
    from core.imaging.grid_indexing import index_grid
    from core.markers import detect_beads

    out = {}
    allr = []
    for v, cam in enumerate(session.cameras):
        c = cal.cameras[v]
        res = []
        for k, ref in enumerate(session.frames(cam, "lattice") if session.has("lattice") else []):
            img = c.flatfield.normalise(session.read(ref))
            bead_mm = float(session.manifest.get("lattice", {}).get("bead_diameter_mm", 2.0))
            bead_px = bead_mm / c.grid.mm_per_px
            try:
                det = detect_beads(img, diameter_px=bead_px, polarity="dark", mask=c.flatfield.valid)
                pts = index_grid(det.uv, min_points=9).uv
            except ValueError as exc:
                out.setdefault("failed", []).append(f"{ref}: {exc}")
                continue
            key = f"lattice_{cam}_{k:04d}"
            dist_t, ideal_t = arrays[f"{key}_distorted_uv"], arrays[f"{key}_ideal_uv"]
            d = np.linalg.norm(pts[:, None] - dist_t[None], axis=2)
            j = d.argmin(axis=1)
            ok = d[np.arange(len(pts)), j] < 2.0
            corrected = c.grid.model.inverse(pts[ok])
            r = _similarity_residual(corrected, ideal_t[j[ok]]) * c.grid.mm_per_px
            res.append(r)
        r = np.concatenate(res) if res else np.zeros(0)
        allr.append(r)
        out[cam] = {"beads": len(r), "rms_mm": float(np.sqrt(np.mean(r**2))) if len(r) else None,
                    "max_mm": float(r.max()) if len(r) else None}
    a = np.concatenate(allr)
    out["all"] = {"beads": len(a), "rms_mm": float(np.sqrt(np.mean(a**2))) if len(a) else None}
    return out


def _bundle_sources(cal, uvs, true_rig, man) -> dict:
    """Bundle adjustment (as :func:`core.calibration.session.solve_step` runs it) of the labelled
    frames with the image positions ``uvs`` (one ``(V, n, 2)`` array per observation); source and
    focal-length errors against the truth."""
    from core.calibration.bundle import ObjectFrame, bundle_adjust
    from core.calibration.session import _manifest_T

    frames = [ObjectFrame(o.points, uv) for o, uv in zip(cal.observations, uvs, strict=True)]
    n_static = 1 if cal.static_target is not None else 0
    ref = len(frames) - n_static if n_static else 0
    ba = bundle_adjust(frames, [(c.width, c.height) for c in cal.rig], reference=ref,
                       T_lab_from_reference=_manifest_T(man) if n_static else None,
                       pixel_size=[c.pixel_size for c in cal.rig], pixel_sigma=0.1, max_evaluations=400)
    if not ba.ok:
        return {"ok": False, "reason": ba.reason}
    e = [c.source - t.source for c, t in zip(ba.rig, true_rig, strict=True)]
    return {"ok": True, "source_error_mm": [float(np.linalg.norm(x)) for x in e],
            "source_error_xyz_mm": [np.round(x, 4).tolist() for x in e],
            "f_rel_error_percent": [100 * (c.fx / t.fx - 1) for c, t in zip(ba.rig, true_rig, strict=True)],
            "rms_px": ba.rms_px}


def source_error_analysis(session, cal, true_rig, arrays, *, draws: int = 12, seed: int = 0) -> dict:
    """Where the source-position error comes from, by controlled substitutions (a study of issue 16).

    The calibrated observations (the labelled beads of every frame used) are replaced by
    * ``truth_ideal``: the true pinhole projections of the same beads — checks that the bundle
      adjustment, the pixel-centre convention and the lab frame from the static object agree with
      the generator (the error should be ~0);
    * ``fitted_correction_of_truth``: the true distorted positions corrected by the fitted
      distortion models — the error the distortion correction alone leaves;
    * the detections of the moving object with the static object's from the truth and the
      reverse — which frames' localisation error moves the sources;
    * the detections without the beads whose image comes within 3 px of another bead's;
    * ``noise_ensemble``: ``fitted_correction_of_truth`` plus the measured detection residuals with
      random signs (``draws`` draws) — the spread of the source error that localisation errors of
      the measured size give.

    Also: the detection residuals (detected minus fitted correction of the true position; mean,
    RMS, and by how close a bead's image comes to another bead's), and each camera's source error
    split into its part along the principal ray (what a focal-length error moves) and across it.
    """
    man = session.manifest
    rows = [r for r in cal.frames if r["ok"]]
    V = len(cal.rig)
    truth_ideal, truth_corr, det = [], [], []
    for r, o in zip(rows, cal.observations, strict=True):
        if r["group"] == "spiral":
            ideal, dist = arrays["spiral_ideal_uv"][r["index"]], arrays["spiral_distorted_uv"][r["index"]]
        else:
            ideal, dist = arrays["cube_ideal_uv"], arrays["cube_distorted_uv"]
        corr = np.stack([cal.cameras[v].grid.model.inverse(dist[v]) for v in range(V)])
        uv = o.uv
        # a helix labelled end to end is the same object turned over: compare like with like
        if r["group"] == "spiral" and np.nanmean(np.abs(uv - corr[:, ::-1])) < np.nanmean(np.abs(uv - corr)):
            ideal, corr = ideal[:, ::-1], corr[:, ::-1]
        seen = np.isfinite(uv[..., :1])
        truth_ideal.append(np.where(seen, ideal, np.nan))
        truth_corr.append(np.where(seen, corr, np.nan))
        det.append(uv)
    n_static = 1 if cal.static_target is not None else 0
    n_obj = len(det) - n_static
    out: dict = {"experiments": {
        "detections": _bundle_sources(cal, det, true_rig, man),
        "truth_ideal": _bundle_sources(cal, truth_ideal, true_rig, man),
        "fitted_correction_of_truth": _bundle_sources(cal, truth_corr, true_rig, man)}}
    if n_static:
        out["experiments"]["detected_object_true_static"] = _bundle_sources(
            cal, det[:n_obj] + truth_corr[n_obj:], true_rig, man)
        out["experiments"]["true_object_detected_static"] = _bundle_sources(
            cal, truth_corr[:n_obj] + det[n_obj:], true_rig, man)
    res = [d - t for d, t in zip(det, truth_corr, strict=True)]
    r_all = np.concatenate([x.reshape(-1, 2) for x in res])
    r_all = r_all[np.isfinite(r_all[:, 0])]
    e2 = np.linalg.norm(r_all, axis=1)
    # how close each bead's image comes to another bead's (edge to edge, px), from the calibration
    gaps = []
    for f, o in enumerate(cal.observations):
        T = cal.bundle.object_poses[f]
        X = o.points @ T[:3, :3].T + T[:3, 3]
        diam = (cal.target if f < n_obj else cal.static_target).diameters
        g = []
        for cam in cal.rig:
            uv, z = cam.project(X, return_depth=True)
            rad = diam / 2 * cam.fx / z
            d = np.linalg.norm(uv[:, None] - uv[None], axis=2) - rad[:, None] - rad[None]
            np.fill_diagonal(d, np.inf)
            g.append(d.min(axis=1))
        gaps.append(np.where(np.isfinite(res[f][..., 0]), np.stack(g), np.nan))
    gap = np.concatenate([x.ravel() for x in gaps])
    gap = gap[np.isfinite(gap)]
    by_gap = {}
    for lo, hi, key in ((-np.inf, 3.0, "under_3px"), (3.0, 8.0, "3_to_8px"), (8.0, np.inf, "over_8px")):
        m = (gap >= lo) & (gap < hi)
        by_gap[key] = {"n": int(m.sum()), "median_px": float(np.median(e2[m])) if m.any() else None,
                       "rms_px": float(np.sqrt(np.mean(e2[m] ** 2))) if m.any() else None}
    # the detections whose bead image comes within 3 px of another's left out (they carry the
    # largest localisation errors: a neighbour's shadow pulls the centroid)
    crowded = [np.where((gp < 3.0)[..., None], np.nan, d) for gp, d in zip(gaps, det, strict=True)]
    out["experiments"]["detections_without_crowded_beads"] = _bundle_sources(cal, crowded, true_rig, man)
    out["detection_residuals"] = {
        "n": len(e2), "mean_px": r_all.mean(axis=0).tolist(),
        "rms_per_axis_px": np.sqrt((r_all**2).mean(axis=0)).tolist(),
        "median_px": float(np.median(e2)), "p99_px": float(np.percentile(e2, 99)),
        "by_gap_to_the_nearest_bead_image": by_gap}
    g = np.random.default_rng(seed)
    ens = []
    for _ in range(int(draws)):
        uvs = [t + g.choice([-1.0, 1.0], size=r.shape[:2])[..., None] * r
               for t, r in zip(truth_corr, res, strict=True)]
        ens.append(_bundle_sources(cal, uvs, true_rig, man))
    ok = [e for e in ens if e["ok"]]
    errs = np.array([e["source_error_mm"] for e in ok])
    out["noise_ensemble"] = {
        "draws": int(draws), "converged": len(ok),
        "mean_source_error_mm": float(errs.mean()) if len(ok) else None,
        "max_source_error_mm": float(errs.max()) if len(ok) else None,
        "share_of_draws_over_0.5mm": float(np.mean(errs.max(axis=1) > 0.5)) if len(ok) else None,
        "f_rel_error_percent_sd": np.std([e["f_rel_error_percent"] for e in ok], axis=0).tolist()}
    split = []
    for c, t in zip(cal.rig, true_rig, strict=True):
        e = c.source - t.source
        along = float(e @ t.principal_ray)
        depth = float(np.linalg.norm(t.source))  # source to the lab origin (the static object)
        split.append({"camera": t.name, "along_principal_ray_mm": along,
                      "across_mm": float(np.sqrt(max(e @ e - along**2, 0.0))),
                      "f_error_times_source_to_origin_mm": float(-(c.fx / t.fx - 1) * depth)})
    out["source_error_split"] = split
    return out


def evaluate(session, cal, session_dir: Path) -> dict:
    """Everything against the truth (module docs)."""
    from core.calibration.errormap import capture_lattice
    from core.geometry.triangulate import triangulate

    true_rig, dist, arrays, field = _truth(session_dir)
    cams = []
    for c, t, s in zip(cal.rig, true_rig, cal.bundle.camera_std, strict=True):
        cams.append({"camera": t.name, "f_rel_error_percent": 100 * (c.fx / t.fx - 1),
                     "f_sd_percent": 100 * float(s["f"]) / c.fx,
                     "source_error_mm": float(np.linalg.norm(c.source - t.source)),
                     "source_error_xyz_mm": (c.source - t.source).tolist(),
                     "source_sd_mm": [float(x) for x in s["source"]],
                     "source_error_in_sd": [float(a / b) for a, b in zip(c.source - t.source, s["source"],
                                                                          strict=True)],
                     "sid_error_mm": c.sid - t.sid if c.pixel_size else None,
                     "principal_point_shift_px": [c.cu - t.cu, c.cv - t.cv]})
    X = capture_lattice(true_rig, spacing_mm=10.0, margin_px=10.0)
    uv = true_rig.project(X)
    seen = np.ones(len(X), bool)  # inside the round field of both views (10 px clear of its rim)
    raw = []
    for v, t in enumerate(true_rig):
        d = dist[t.name]
        q = d.forward(uv[v]) if d else uv[v]
        raw.append(q)
        if field.get(t.name):
            c = np.asarray(d.center) if d else np.array([(t.width - 1) / 2, (t.height - 1) / 2])
            seen &= np.linalg.norm(q - c, axis=1) <= field[t.name] * min(t.width, t.height) / 2 - 10
    X, uv = X[seen], uv[:, seen]
    obs = np.stack([cal.cameras[v].grid.model.inverse(raw[v][seen]) for v in range(len(true_rig))])
    rec = triangulate(cal.rig, obs, method="linear").points
    e = np.linalg.norm(rec - X, axis=1)
    g = np.random.default_rng(0)
    noise = cal.bundle.rms_px / np.sqrt(2)
    e2 = np.linalg.norm(triangulate(cal.rig, obs + g.normal(0, noise, obs.shape), method="linear").points - X,
                        axis=1)
    return {"cameras": cams,
            "max_f_error_percent": max(abs(c["f_rel_error_percent"]) for c in cams),
            "max_source_error_mm": max(c["source_error_mm"] for c in cams),
            "lattice_vs_truth": _lattice_truth(session, cal, arrays),
            "source_error_analysis": source_error_analysis(session, cal, true_rig, arrays),
            "lattice_check": {c["name"]: c.get("lattice_check") for c in cal.report["cameras"]},
            "reconstruction": {"points": len(X), "points_outside_a_field": int((~seen).sum()),
                               "spacing_mm": 10.0, "rms_mm": float(np.sqrt(np.mean(e**2))),
                               "p95_mm": float(np.percentile(e, 95)), "max_mm": float(e.max()),
                               "with_localisation_noise_px": float(noise),
                               "with_noise_rms_mm": float(np.sqrt(np.mean(e2**2)))}}


def run(*, session_dir=None, pixels: int = 1024, n_spiral: int = 40, n_grid: int = 5, seed: int = 0,
        progress=None) -> dict:
    from core.calibration.session import calibrate_session
    from core.io.calibration_session import read_session

    say = progress or (lambda m: None)
    res = {"machine": {"platform": platform.platform(), "processor": platform.machine(),
                       "cpus": os.cpu_count(), "python": sys.version.split()[0],
                       "load_average_at_start": list(os.getloadavg())}}
    if session_dir is None or not (Path(session_dir) / "session.json").is_file():
        from core.synthetic.session import write_calibration_session

        session_dir = Path(session_dir or f"calibration_session_{pixels}")
        say(f"writing the session ({pixels}², {n_spiral} spiral, {n_grid} grid frames) to {session_dir}")
        t = time.perf_counter()
        write_calibration_session(session_dir, pixels=pixels, seed=seed, n_spiral=n_spiral, n_grid=n_grid)
        res["session_write_seconds"] = time.perf_counter() - t
    session_dir = Path(session_dir)
    session = read_session(session_dir)
    res["session"] = {"folder": str(session_dir), "frame_size": list(session.frame_size),
                      "n_frames": session.manifest.get("n_frames")}
    say("calibrating")
    t = time.perf_counter()
    cal = calibrate_session(session, progress=lambda s, d, n: say(f"{s} {d}/{n}") if d == n else None)
    res["calibrate_seconds"] = time.perf_counter() - t
    res["seconds_by_step"] = cal.report["seconds"]
    res["load_average_at_end"] = list(os.getloadavg())
    res["report"] = {k: cal.report[k] for k in ("bundle", "n_frames_labelled", "error_volume", "notes")}
    res["distortion"] = {c["name"]: {k: c["distortion"][k] for k in ("model", "residuals", "table", "points")}
                         for c in cal.report["cameras"]}
    say("comparing with the truth")
    res["truth"] = evaluate(session, cal, session_dir)
    tr = res["truth"]
    res["acceptance"] = {
        "lattice_rms_mm<=0.05": tr["lattice_vs_truth"]["all"]["rms_mm"] is not None
        and tr["lattice_vs_truth"]["all"]["rms_mm"] <= 0.05,
        "f_within_0.1%": tr["max_f_error_percent"] <= 0.1,
        "sources_within_0.5mm": tr["max_source_error_mm"] <= 0.5,
        "reconstruction_rms<=0.1mm": tr["reconstruction"]["rms_mm"] <= 0.1}
    return res


def main(argv=None) -> int:
    from core.io.atomic import print_json

    ap = argparse.ArgumentParser(prog="python -m core.studies.calibration.session_acceptance",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("--session", default=None, help="session folder (written when it holds none)")
    ap.add_argument("--pixels", type=int, default=1024)
    ap.add_argument("--spiral", type=int, default=40)
    ap.add_argument("--grid", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=None, help="also write the JSON here")
    a = ap.parse_args(argv)
    res = run(session_dir=a.session, pixels=a.pixels, n_spiral=a.spiral, n_grid=a.grid, seed=a.seed,
              progress=lambda m: print(f"[calibration session] {m}", file=sys.stderr, flush=True))
    print_json(res, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
