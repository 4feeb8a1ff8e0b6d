"""Is a bone's estimated-vs-true calibration tracking difference geometry or image noise? Controls.

:mod:`core.studies.calibration.tracking_comparison` tracks the demo trial twice: corrected and
calibrated as ``talus calibrate`` estimated from the session (trial ``walk``), and with the
generator's true correction and rig (``walk_truth``). The two corrections sample the raw noisy
frames at slightly different positions, so besides the calibration's geometry they also see a
different noise realisation (linear-interpolation weights change by the position difference, in
pixels). These controls separate the two:

* ``difference``: where the estimated and the true correction sample each raw frame (RMS and
  largest distance over the field, in raw pixels; the part an affine map does not explain) and
  how their flatfields differ (relative RMS): CPU only.
* ``clean``: the same trial (same poses, image chain and rig) rendered without quantum and read
  noise (still rounded to whole DN), tracked with the estimated and the true calibration
  (``walk_clean`` / ``walk_clean_truth``): the calibration's geometry alone.
* ``noise2``: the trial rendered with another noise draw, tracked with both calibrations
  (``walk_noise2`` / ``walk_noise2_truth``): the comparison repeated on other noise.
* ``shift``: the true correction with its output grid moved by a constant sub-pixel ``δ`` of the
  size of the measured difference, tracked with the true rig whose principal points move by
  ``-δ`` (``walk_shift``): exact geometry, the raw frames resampled at positions ``δ`` away.
* ``field``: the true correction with a smooth sinusoidal displacement of the sample positions of
  the same RMS, tracked with the true rig (``walk_field``): the control as a displacement field.

``python -m core.studies.calibration.noise_controls difference DEMO [--out F]``;
``... prepare DEMO [--device cuda] [--out F]`` (writes the frames, the shifted rig and the trials;
once); ``... track DEMO TRIAL [--device cuda] [--out F]`` (one trial; copies of ``DEMO`` can
track different trials at the same time); ``... combine F1 F2 ... [--out F]`` (the differences).
``DEMO`` is a folder written by :func:`core.synthetic.make_demo_study` and calibrated from its
session. Study code: reads the generator's truth.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

from core.studies.calibration.truth import true_correction

__all__ = ["TRIALS", "combine", "correction_difference", "prepare", "track_one"]

#: Control trials: name -> (frame folder, calibration: "estimated" | "rig" | "rig_shift",
#: correction: None = the saved one | "truth" | "shift" | "field")
TRIALS = {
    "walk": ("frames", "estimated", None),
    "walk_truth": ("frames", "rig", "truth"),
    "walk_clean": ("frames_clean", "estimated", None),
    "walk_clean_truth": ("frames_clean", "rig", "truth"),
    "walk_noise2": ("frames_noise2", "estimated", None),
    "walk_noise2_truth": ("frames_noise2", "rig", "truth"),
    "walk_shift": ("frames", "rig_shift", "shift"),
    "walk_field": ("frames", "rig", "field"),
}
#: (a, b): the tracking differences ``a - b`` the controls report
PAIRS = {
    "baseline (estimated - true calibration, noisy frames)": ("walk", "walk_truth"),
    "clean (estimated - true calibration, noise-free frames)": ("walk_clean", "walk_clean_truth"),
    "noise2 (estimated - true calibration, another noise draw)": ("walk_noise2", "walk_noise2_truth"),
    "shift (true geometry, frames resampled delta away - true)": ("walk_shift", "walk_truth"),
    "field (true rig, sample positions moved by a smooth field - true)": ("walk_field", "walk_truth"),
    "noise draw (true calibration, another noise draw - first draw)": ("walk_noise2_truth", "walk_truth"),
}


def _true_tables(folder: Path, name: str, shape):
    """(gain, dark, Distortion, forward tables (H, W, 2)) of the generator's correction of view ``name``."""
    import tifffile

    from core.synthetic.distortion import Distortion

    meta = json.loads((folder / "imaging" / f"{name}.json").read_text())
    dark = float(meta.get("dark_dn", 0.0))
    gain = tifffile.imread(folder / "imaging" / f"flatfield_{name}.tif").astype(np.float64) - dark
    d = meta["distortion"]
    dist = Distortion(tuple(d["center"]), d["scale_px"], d["k1"], d["k2"], d["twist_rad"], d["twist_power"])
    v, u = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)
    return gain, dark, dist, dist.forward(np.stack([u, v], axis=-1))


def correction_difference(folder) -> dict:
    """Where the saved (estimated) correction of trial ``walk`` samples each raw frame against
    the generator's true correction, per view: raw-pixel distance RMS / 95th percentile / largest
    over the field (pixels whose true source lies where the true flatfield has signal), the RMS
    left after the best affine map of the ideal pixel (what a change of intrinsics absorbs), the
    mean distance vector, and the flatfields' relative RMS difference."""
    from core.imaging.distortion_maps import remap_tables
    from core.imaging.pipeline import FlatfieldStep, UndistortStep
    from core.study import Study
    from core.study.calibrations import trial_correction

    folder = Path(folder)
    out = {}
    with Study.open(folder) as st:
        pipes = trial_correction(st, "walk")
        cams = list(st.trial("walk").rig())
    if pipes is None:
        raise ValueError(f"{folder}: trial 'walk' has no saved correction (calibrate the demo first)")
    for cam, name, pipe in zip(cams, _true_names(folder), pipes, strict=True):
        shape = (cam.height, cam.width)
        gain, _, _, fw = _true_tables(folder, name, shape)
        und = [s for s in pipe.steps if isinstance(s, UndistortStep)]
        ff = [s for s in pipe.steps if isinstance(s, FlatfieldStep)]
        if und:
            mx, my = remap_tables(und[0].model, shape, step=und[0].step)
            est = np.stack([mx, my], axis=-1).astype(np.float64)
        else:
            v, u = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)
            est = np.stack([u, v], axis=-1)
        iu = np.clip(np.rint(fw[..., 0]).astype(int), 0, shape[1] - 1)
        iv = np.clip(np.rint(fw[..., 1]).astype(int), 0, shape[0] - 1)
        inside = ((fw[..., 0] >= 0) & (fw[..., 0] <= shape[1] - 1)
                  & (fw[..., 1] >= 0) & (fw[..., 1] <= shape[0] - 1))
        mask = inside & (gain[iv, iu] > 0.05 * float(np.max(gain)))
        d = (est - fw)[mask]
        r = np.linalg.norm(d, axis=1)
        v, u = np.nonzero(mask)
        A = np.column_stack([u, v, np.ones_like(u)]).astype(float)
        coef, *_ = np.linalg.lstsq(A, d, rcond=None)
        res = np.linalg.norm(d - A @ coef, axis=1)
        entry = {"pixels": int(mask.sum()), "rms_px": float(np.sqrt(np.mean(r**2))),
                 "p95_px": float(np.percentile(r, 95)), "max_px": float(r.max()),
                 "mean_vector_px": [float(x) for x in d.mean(axis=0)],
                 "rms_after_affine_px": float(np.sqrt(np.mean(res**2))),
                 "max_after_affine_px": float(res.max())}
        if ff:
            from scipy.ndimage import binary_erosion

            g_est = np.asarray(ff[0].flatfield.gain, np.float64)
            ok = (gain > 0.05 * gain.max()) & (g_est > 0)
            inner = binary_erosion(ok, iterations=max(2, shape[0] // 40))
            for key, m in (("", ok), ("_inner", inner)):
                rel = g_est[m] / gain[m] - 1.0
                entry[f"flatfield_relative_rms{key}"] = float(np.sqrt(np.mean(rel**2)))
                entry[f"flatfield_relative_mean{key}"] = float(np.mean(rel))
            entry["flatfield_inner"] = f"the field eroded by {max(2, shape[0] // 40)} px (its edge apart)"
        out[name] = entry
    rms = float(np.sqrt(np.mean([e["rms_px"] ** 2 for e in out.values()])))
    return {"views": out, "rms_px": rms}


def _true_names(folder: Path) -> list[str]:
    """The generator's camera names (``rig/rig.json``), in the rig's order."""
    return [c["name"] for c in json.loads((Path(folder) / "rig" / "rig.json").read_text())["cameras"]]


def _field(shape, rms_px: float, wavelength_px: float, mask=None) -> np.ndarray:
    """A smooth (H, W, 2) displacement (sinusoids of ``wavelength_px``) scaled to ``rms_px``."""
    v, u = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)
    k = 2 * np.pi / float(wavelength_px)
    f = np.stack([np.sin(k * u + 0.3) * np.cos(k * v + 1.1),
                  np.cos(k * u + 2.0) * np.sin(k * v + 0.7)], axis=-1)
    sel = f if mask is None else f[mask]
    return f * (rms_px / float(np.sqrt(np.mean(np.sum(sel**2, axis=-1)))))


def resampled_true_correction(folder, names, *, grid_shift=None, offsets=None) -> list:
    """The generator's flatfield and distortion of each view, with its output pixel ``p`` sampled
    at ``forward(p + grid_shift)`` (the ideal image moved by ``-grid_shift``) and/or at
    ``forward(p) + offsets[view][p]`` (a displacement field, (H, W, 2) pixels)."""
    import cv2
    import tifffile

    folder = Path(folder)
    out = []
    for k, name in enumerate(names):
        ff = tifffile.imread(folder / "imaging" / f"flatfield_{name}.tif")
        gain, dark, dist, _ = _true_tables(folder, name, ff.shape)
        v, u = np.mgrid[0:ff.shape[0], 0:ff.shape[1]].astype(np.float64)
        s = np.zeros(2) if grid_shift is None else np.asarray(grid_shift, float)
        src = dist.forward(np.stack([u + s[0], v + s[1]], axis=-1))
        if offsets is not None:
            src = src + offsets[k]
        mx, my = src[..., 0].astype(np.float32), src[..., 1].astype(np.float32)

        def correct(raw, gain=gain, dark=dark, mx=mx, my=my):
            ok = gain > 1e-6
            img = np.where(ok, (np.asarray(raw, np.float64) - dark) / np.where(ok, gain, 1.0), 0.0)
            img = np.clip(img, 0.0, 1.0).astype(np.float32)
            return cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

        out.append(correct)
    return out


def _settings(folder: Path) -> dict:
    p = folder / "noise_controls.json"
    return json.loads(p.read_text()) if p.is_file() else {}


def _write_frames(folder: Path, summary: dict, device, noise_seed: int | None) -> dict:
    """Frames of the same trial through the same image chain: without quantum and read noise
    (``noise_seed`` None; still rounded to whole DN) or with the noise drawn from ``noise_seed``."""
    import tifffile

    from core.synthetic.scene import make_foot_scene

    scene = make_foot_scene(n_frames=summary["n_frames"], pixels=summary["pixels"], seed=summary["seed"],
                            spacing=summary["voxel_spacing_mm"], tissue_spacing=summary["tissue_spacing_mm"])
    sub = "frames_clean" if noise_seed is None else "frames_noise2"
    models = [dataclasses.replace(m, photons_per_pixel=None, read_noise_dn=0.0) if noise_seed is None else m
              for m in scene.imaging]
    renderer = scene.renderer(device=device)
    for i in range(scene.n_frames):
        L = scene.line_integrals(i, renderer=renderer)
        for v, (cam, m) in enumerate(zip(scene.rig, models, strict=True)):
            rng = None if noise_seed is None else np.random.default_rng([int(noise_seed), 0x5CE4E, i, v])
            img = m.apply(L[v], rng=rng)
            p = folder / sub / cam.name / f"frame_{i:04d}.tif"
            p.parent.mkdir(parents=True, exist_ok=True)
            tifffile.imwrite(p, img, photometric="minisblack")
    noise = ("none (no quantum or read noise; rounded to whole DN)" if noise_seed is None
             else f"quantum and read noise drawn from seed {noise_seed}")
    return {"folder": sub, "noise": noise}


def prepare(demo, *, device=None, shift_px: float | None = None, field_wavelength_px: float = 24.0,
            noise_seed: int = 1001) -> dict:
    """Write the noise-free and re-drawn frames, the rig with moved principal points and the
    control trials (each starting from the true frame-0 poses) into ``demo``; returns the
    settings (also saved as ``noise_controls.json``)."""
    from core.geometry.mayacam import read_mayacam, write_mayacam
    from core.study import Study

    folder = Path(demo)
    summary = json.loads((folder / "summary.json").read_text())
    diff = correction_difference(folder)
    size = float(diff["rms_px"] if shift_px is None else shift_px)
    delta = [size / np.sqrt(2.0), size / np.sqrt(2.0)]
    settings = {"correction_difference": diff, "shift_px": delta, "field_rms_px": size,
                "field_wavelength_px": field_wavelength_px, "noise_seed": noise_seed,
                "frames": {}}
    t0 = time.perf_counter()
    for seed in (None, noise_seed):
        info = _write_frames(folder, summary, device, seed)
        settings["frames"][info["folder"]] = info["noise"]
    settings["render_seconds"] = time.perf_counter() - t0
    with Study.open(folder, mode="w") as st:
        walk = st.trial("walk")
        est = walk.calibration
        if est == "rig":
            raise ValueError(f"{folder}: trial 'walk' uses the true rig; calibrate the demo first")
        ps = json.loads((folder / "rig" / "rig.json").read_text())["cameras"][0]["pixel_size_mm"]
        files = []
        for path in sorted((folder / "rig").glob("cam*.txt")):
            cam = read_mayacam(path, pixel_size=ps, name=path.stem)
            K = np.array(cam.K, float)
            K[0, 2] -= delta[0]
            K[1, 2] -= delta[1]
            q = folder / "rig_shift" / path.name
            q.parent.mkdir(parents=True, exist_ok=True)
            write_mayacam(dataclasses.replace(cam, K=K), q, version=2)
            files.append(q)
        if "rig_shift" not in st.manifest["calibrations"]:
            st.add_calibration("rig_shift", files, pixel_size_mm=ps)
        bit_depth = st.manifest["trials"]["walk"]["views"][0].get("bit_depth")
        truths = {b: np.load(folder / "poses" / f"{b}.npy") for b in walk.bones}
        for name, (sub, cal, _) in TRIALS.items():
            if name not in st.trials:
                views = [folder / sub / p.name for p in walk.view_paths]
                st.add_trial(name, views, calibration=est if cal == "estimated" else cal,
                             bones=list(walk.bones), bit_depth=bit_depth)
            for b in walk.bones:
                st.trial(name).record_pose(b, 0, truths[b][0])
    (folder / "noise_controls.json").write_text(json.dumps(settings, indent=1))
    return settings


def _correction(folder: Path, trial: str, names) -> list | None:
    kind = TRIALS[trial][2]
    if kind is None:
        return None
    if kind == "truth":
        return true_correction(folder, names)
    s = _settings(folder)
    if kind == "shift":
        return resampled_true_correction(folder, names, grid_shift=s["shift_px"])
    offsets = []
    for name in names:
        gain, _, _, fw = _true_tables(folder, name, _flat_shape(folder, name))
        iu = np.clip(np.rint(fw[..., 0]).astype(int), 0, gain.shape[1] - 1)
        iv = np.clip(np.rint(fw[..., 1]).astype(int), 0, gain.shape[0] - 1)
        offsets.append(_field(gain.shape, s["field_rms_px"], s["field_wavelength_px"],
                              gain[iv, iu] > 0.05 * gain.max()))
    return resampled_true_correction(folder, names, offsets=offsets)


def _flat_shape(folder: Path, name: str):
    import tifffile

    return tifffile.imread(folder / "imaging" / f"flatfield_{name}.tif").shape


def track_one(demo, trial: str, *, device=None, frames=None, bones=None) -> dict:
    """Track one control trial from the true frame-0 poses (:func:`track_study` defaults); its
    per-bone RMS errors against the true poses, the tracked poses, the flagged bone-frames with
    their reasons, every frame's score, and the JCS check."""
    from core.studies.calibration.tracking_comparison import _errors
    from core.study import Study
    from core.tracking.from_study import track_study

    folder = Path(demo)
    with Study.open(folder, mode="w") as st:
        tr = st.trial(trial)
        names = list(bones or tr.bones)
        order = list(range(tr.n_frames) if frames is None else frames)
        truths = {b: np.load(folder / "poses" / f"{b}.npy") for b in names}
        cams = _true_names(folder)
        t0 = time.perf_counter()
        corr = _correction(folder, trial, cams)
        _, rep = track_study(st, trial, names, order, device=device, correction=corr)
        res = {"trial": trial, "frames_folder": TRIALS[trial][0], "calibration": tr.calibration,
               "correction": TRIALS[trial][2] or "saved with the calibration",
               "normalisation": rep.get("normalisation"), "seconds": time.perf_counter() - t0,
               "summary": rep.get("summary"),
               "bones": {b: _errors(st, trial, b, order, truths[b]) for b in names},
               "poses": {b: tr.poses(b)[order].tolist() for b in names},
               "frames": order, "flagged": [], "scores": {}}
        for b in names:
            J = tr.results(b)
            sc = J.scores(tr.n_frames)[order]
            res["scores"][b] = [None if not np.isfinite(s) else float(s) for s in sc]
            for f in order:
                rec = J.records.get(f)
                fl = list((rec.tracking or {}).get("flags") or []) if rec is not None else []
                if fl:
                    res["flagged"].append({"bone": b, "frame": int(f), "flags": fl})
        foot = [b for b in ("tibia", "talus", "calcaneus") if b in names]
        if len(foot) >= 2 and order[0] == 0:
            from core.studies.tracking.jcs_check import joint_check

            res["jcs"] = joint_check({b: tr.poses(b)[order] for b in foot},
                                     {b: truths[b][order] for b in foot},
                                     {b: st.bone_volume(b) for b in foot})
    return res


def _rot_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0))))


def combine(runs: dict) -> dict:
    """The controls' differences from per-trial results of :func:`track_one` (``{trial: result}``):
    per pair and bone the RMS differences (acceptance: <= 0.02 mm and <= 0.05 deg) and the RMS of
    the frame-by-frame pose differences between the two runs (rotation angle, centroid mm)."""
    out = {}
    for label, (a, b) in PAIRS.items():
        if a not in runs or b not in runs:
            continue
        ra, rb = runs[a], runs[b]
        d = {}
        for bone in ra["bones"]:
            ea, eb = ra["bones"][bone], rb["bones"].get(bone, {})
            Pa, Pb = np.asarray(ra["poses"][bone], float), np.asarray(rb["poses"][bone], float)
            ok = np.all(np.isfinite(Pa), axis=(1, 2)) & np.all(np.isfinite(Pb), axis=(1, 2))
            rot = [_rot_deg(Pa[i][:3, :3] @ Pb[i][:3, :3].T) for i in np.nonzero(ok)[0]]
            dmm = ea.get("rms_mm", np.nan) - eb.get("rms_mm", np.nan)
            ddeg = ea.get("rms_deg", np.nan) - eb.get("rms_deg", np.nan)
            d[bone] = {"rms_mm": dmm, "rms_deg": ddeg,
                       "per_frame_rotation_apart_rms_deg": float(np.sqrt(np.mean(np.square(rot)))) if rot
                       else None,
                       "within_0.02mm_0.05deg": bool(abs(dmm) <= 0.02 and abs(ddeg) <= 0.05)}
        out[label] = {"trials": [a, b], "per_bone": d}
    return out


def main(argv=None) -> int:
    from core.io.atomic import print_json

    ap = argparse.ArgumentParser(prog="python -m core.studies.calibration.noise_controls",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("step", choices=("difference", "prepare", "track", "combine"))
    ap.add_argument("args", nargs="+")
    ap.add_argument("--device", default=None)
    ap.add_argument("--frames", default=None, help="START:STOP[:STEP]")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    if a.step == "difference":
        res = correction_difference(a.args[0])
    elif a.step == "prepare":
        res = prepare(a.args[0], device=a.device)
    elif a.step == "track":
        frames = list(range(*(int(v) for v in a.frames.split(":")))) if a.frames else None
        res = track_one(a.args[0], a.args[1], device=a.device, frames=frames)
    else:
        runs = {}
        for f in a.args:
            r = json.loads(Path(f).read_text())
            runs[r["trial"]] = r
        keep = ("calibration", "correction", "frames_folder", "seconds", "summary", "bones", "flagged", "jcs")
        res = {"runs": {t: {k: r[k] for k in keep if k in r} for t, r in runs.items()},
               "differences": combine(runs)}
    print(f"[noise controls] {a.step} done", file=sys.stderr)
    print_json(res, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
