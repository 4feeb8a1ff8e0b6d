"""Grid calibration at scale: ``python -m core.studies.imaging.grid_benchmark [--sizes ...] [--out FILE]``.

Times detection, lattice indexing and the automatic model choice on synthetic distortion-grid
frames of about 250, 2,500 and 20,000 holes, and checks them against the generator's truth.
Prints JSON (machine, sizes, times in seconds, residuals in pixels).

Cases (all with the thesis-like distortion of the imaging tests, scaled to the image: 5th-order
radial term and a 5° S-twist growing as r⁴, 5.7 mm RMS uncorrected at 1024²):

* ``250``: the thesis grid, 3 mm holes at 15 mm pitch, through the 1024² fluoroscope model
  (:meth:`ImagingModel.fluoroscope` defaults: MTF50 0.5 cycles/mm, 5×10³ quanta/mm²).
* ``2500``: 1.5 mm holes at 5 mm pitch, 2048², the same fluoroscope model.
* ``20000``: 0.8 mm holes at 1.85 mm pitch (~25 px), 4096², a flat-panel-like detector (MTF50
  2 cycles/mm, 5×10⁴ quanta/mm²), as the large dot grids of real X-ray calibration sets.

For each size and each of ``--repeats`` runs: :func:`detect_grid_points`, :func:`index_grid`,
:func:`ideal_grid`, :func:`select_model` over :data:`AUTO_MODELS` (5-fold cross-validation; its
table gives each model's held-out RMS and time), and a fit of each candidate to all points
(:func:`fit_distortion`; the thin-plate spline to its :data:`TPS_MAX_POINTS` subsample). Times
are the median of the runs: ``*_s`` wall-clock seconds and ``*_cpu_s`` the process's CPU
seconds (all threads; on a shared, loaded machine — the load average is reported — the wall
time is the larger, the CPU time is about what an idle machine needs). The accuracy figures
come from the first run, which the others repeat exactly.

Truth checks: ``detection`` — distance of each detected centre to the true distorted hole;
``indexing.exact`` — every indexed point's ``(i, j)`` is its true lattice cell up to one
translation (the residual of the best similarity ``(i, j) → true ideal position`` is below
1e-6 px; a wrong index leaves a whole pitch); ``model.truth_rms_px`` — the chosen model's
correction of the true distorted positions against the true ideal ones (after the similarity
that relates the estimated ideal grid to the true one).
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import cv2
import numpy as np
from scipy.spatial import cKDTree

from core.imaging.distortion import ideal_grid
from core.imaging.distortion_eval import AUTO_MODELS, select_model
from core.imaging.distortion_models import TPS_MAX_POINTS, fit_distortion
from core.imaging.grid_detection import detect_grid_points
from core.imaging.grid_indexing import index_grid

#: size → (pixels, pitch mm, hole diameter mm, detector); "fluoroscope" = the preset's defaults
CASES = {
    250: (1024, 15.0, 3.0, "fluoroscope"),
    2500: (2048, 5.0, 1.5, "fluoroscope"),
    20000: (4096, 1.85, 0.8, "flat_panel"),
}
_FLAT_PANEL = {"mtf50_cycles_per_mm": 2.0, "fluence_per_mm2": 5e4}


def _machine() -> dict:
    return {"platform": platform.platform(), "machine": platform.machine(), "processor": platform.processor(),
            "cpu_count": os.cpu_count(), "python": platform.python_version(), "numpy": np.__version__,
            "opencv": cv2.__version__, "opencv_threads": cv2.getNumThreads(),
            "OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS")}


def make_frame(size: int, *, cache: str | None = None) -> dict:
    """The grid frame of one case and its truth (``cache``: a folder to keep it in as .npz)."""
    from core.synthetic import Distortion, ImagingModel, distortion_grid, distortion_grid_frame, foot_rig

    px, pitch, hole, detector = CASES[size]
    path = None if cache is None else os.path.join(cache, f"grid_{size}.npz")
    cam = foot_rig(seed=0, pixels=px)[0]
    out = {"pixels": px, "pitch_mm": pitch, "hole_mm": hole, "detector": detector,
           "pixel_size_mm": float(cam.pixel_size), "feature_px": hole / cam.pixel_size}
    if path is not None and os.path.exists(path):
        z = np.load(path)
        out.update(image=z["image"], ideal=z["ideal"], distorted=z["distorted"], render_s=None)
        return out
    t0 = time.perf_counter()
    s = px / 1024
    dist = Distortion.for_camera(cam, k1=0.04, k2=0.06, twist_deg=5.0, twist_power=4.0,
                                 center_offset_px=(8.0 * s, -6.0 * s))
    model = ImagingModel.fluoroscope(cam, rng=0, distortion=dist,
                                     **(_FLAT_PANEL if detector == "flat_panel" else {}))
    grid = distortion_grid(pitch_mm=pitch, hole_diameter_mm=hole, field_diameter_mm=px * cam.pixel_size)
    fr = distortion_grid_frame(cam, model, rng=1, grid=grid)
    out.update(image=fr.image, ideal=fr.ideal_uv, distorted=fr.distorted_uv,
               render_s=time.perf_counter() - t0)
    if path is not None:
        os.makedirs(cache, exist_ok=True)
        tmp = path + ".tmp.npz"
        np.savez(tmp, image=fr.image, ideal=fr.ideal_uv, distorted=fr.distorted_uv)
        os.replace(tmp, path)
    return out


def _similarity(ij: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, complex, complex]:
    """Residuals (px) of the best similarity ``(i, j) → uv`` and its ``(a, b)``: ``uv ≈ a w + b``."""
    w = ij[:, 0] + 1j * ij[:, 1]
    z = uv[:, 0] + 1j * uv[:, 1]
    A = np.column_stack([w, np.ones_like(w)])
    a, b = np.linalg.lstsq(A, z, rcond=None)[0]
    return np.abs(A @ [a, b] - z), complex(a), complex(b)


def _one_run(fr: dict, folds: int) -> dict:
    img = fr["image"]
    H, W = img.shape
    centre = ((W - 1) / 2, (H - 1) / 2)
    t = {}
    t0, c0 = time.perf_counter(), time.process_time()
    pts = detect_grid_points(img, feature_diameter_px=fr["feature_px"])
    t["detect_s"], t["detect_cpu_s"] = time.perf_counter() - t0, time.process_time() - c0
    t0, c0 = time.perf_counter(), time.process_time()
    gi = index_grid(pts.uv, origin_uv=centre)
    t["index_s"], t["index_cpu_s"] = time.perf_counter() - t0, time.process_time() - c0
    t["detect_index_s"] = t["detect_s"] + t["index_s"]
    t["detect_index_cpu_s"] = t["detect_cpu_s"] + t["index_cpu_s"]
    g = ideal_grid(gi, pitch_mm=fr["pitch_mm"], center_uv=centre)
    t0, c0 = time.perf_counter(), time.process_time()
    spec, table = select_model(g.ideal_uv, g.distorted_uv, AUTO_MODELS, folds=folds, mm_per_px=g.mm_per_px)
    t["select_model_s"], t["select_model_cpu_s"] = time.perf_counter() - t0, time.process_time() - c0
    fits, models = {}, {}
    for m in AUTO_MODELS:
        t0 = time.perf_counter()
        models[m] = fit_distortion(g.ideal_uv, g.distorted_uv, m, mm_per_px=g.mm_per_px)
        fits[m] = time.perf_counter() - t0
    t["fit_s"] = fits
    t["cross_validation_s"] = {r["model"]: r.get("seconds") for r in table}
    return {"times": t, "pts": pts, "index": gi, "grid": g, "spec": spec, "table": table,
            "model": models[spec.label] if spec.label in models else fit_distortion(
                g.ideal_uv, g.distorted_uv, spec, mm_per_px=g.mm_per_px)}


def _accuracy(fr: dict, r: dict) -> dict:
    truth_d, truth_i = fr["distorted"], fr["ideal"]
    pts, gi, g, model = r["pts"], r["index"], r["grid"], r["model"]
    d, j = cKDTree(truth_d).query(pts.uv)
    det = {"holes_in_image": len(truth_d), "detected": len(pts), "matched_unique": len(np.unique(j[d < 2])),
           "median_error_px": float(np.median(d)), "max_error_px": float(d.max())}
    dj, jj = cKDTree(truth_d).query(gi.uv)
    res, _, _ = _similarity(gi.ij, truth_i[jj])
    idx = {"indexed": len(gi), "unassigned": len(gi.unassigned), "pitch_px": gi.pitch_px,
           "distinct_true_holes": len(np.unique(jj)), "similarity_residual_max_px": float(res.max()),
           "exact": bool(res.max() < 1e-6 and len(np.unique(jj)) == len(gi) and dj.max() < 2)}
    # the estimated ideal grid is a similarity of the true one: relate them, then compare the
    # chosen model's correction of the true distorted positions with the true ideal positions
    zt = truth_i[jj, 0] + 1j * truth_i[jj, 1]
    ze = g.ideal_uv[:, 0] + 1j * g.ideal_uv[:, 1]
    A = np.column_stack([zt, np.ones_like(zt)])
    a, b = np.linalg.lstsq(A, ze, rcond=None)[0]
    zi = a * (truth_i[:, 0] + 1j * truth_i[:, 1]) + b
    err = np.abs(model.inverse(truth_d) @ [1, 1j] - zi)
    mod = {"chosen": r["spec"].label, "n_points": model.n_points, "n_fit": model.n_fit,
           "mm_per_px": g.mm_per_px, "truth_rms_px": float(np.sqrt(np.mean(err**2))),
           "truth_max_px": float(err.max()), "cross_validation": [
               {k: v for k, v in row.items() if k != "seconds"} for row in r["table"]]}
    return {"detection": det, "indexing": idx, "model": mod}


def _median_times(runs: list[dict]) -> dict:
    first = runs[0]["times"]
    out: dict = {}
    for k, v in first.items():
        if isinstance(v, dict):
            out[k] = {m: float(np.median([r["times"][k][m] for r in runs])) for m in v}
        else:
            out[k] = float(np.median([r["times"][k] for r in runs]))
    return out


def run(*, sizes=(250, 2500, 20000), repeats: int = 3, folds: int = 5, cache: str | None = None,
        progress=None) -> dict:
    """Run the cases and return the JSON-ready result (``progress(msg)`` is called per step)."""
    say = progress or (lambda msg: None)
    out: dict = {"benchmark": "grid_scaling", "machine": _machine(), "device": "cpu", "repeats": int(repeats),
                 "folds": int(folds), "candidates": list(AUTO_MODELS), "tps_max_points": TPS_MAX_POINTS,
                 "cases": []}
    for size in sizes:
        say(f"grid {size}: rendering")
        fr = make_frame(int(size), cache=cache)
        runs, load = [], []
        for k in range(int(repeats)):
            load.append(os.getloadavg()[0])
            say(f"grid {size}: run {k + 1}/{repeats}")
            runs.append(_one_run(fr, folds))
        case = {"size": int(size), "image": [fr["pixels"], fr["pixels"]], "pitch_mm": fr["pitch_mm"],
                "hole_mm": fr["hole_mm"], "detector": fr["detector"], "pixel_size_mm": fr["pixel_size_mm"],
                "feature_px": fr["feature_px"], "render_s": fr["render_s"], "load_average_1min": load,
                "times_median_s": _median_times(runs), "times_each_run_s": [r["times"] for r in runs],
                **_accuracy(fr, runs[0])}
        out["cases"].append(case)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m core.studies.imaging.grid_benchmark",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="250,2500,20000", help="comma-separated cases (250, 2500, 20000)")
    ap.add_argument("--repeats", type=int, default=3, help="runs per size; times are their median")
    ap.add_argument("--folds", type=int, default=5, help="cross-validation folds")
    ap.add_argument("--cache", help="folder to keep the rendered frames in (the 4096² one takes minutes)")
    ap.add_argument("--out", help="also write the JSON to this file")
    args = ap.parse_args(argv)
    try:
        sizes = [int(s) for s in args.sizes.split(",") if s.strip()]
    except ValueError:
        ap.error(f"--sizes: expected comma-separated integers, got {args.sizes!r}")
    bad = [s for s in sizes if s not in CASES]
    if bad:
        ap.error(f"--sizes: unknown case(s) {bad}; expected some of {sorted(CASES)}")
    if args.repeats < 1:
        ap.error("--repeats: expected at least 1")
    import sys

    res = run(sizes=sizes, repeats=args.repeats, folds=args.folds, cache=args.cache,
              progress=lambda m: print(m, file=sys.stderr, flush=True))
    from core.io.atomic import print_json

    print_json(res, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
