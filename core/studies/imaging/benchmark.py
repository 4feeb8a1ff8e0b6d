"""Speed of the image-correction chain: ``python -m core.studies.imaging.benchmark [--quick] [--out FILE]``.

Prints JSON (machine, device, sizes, times in ms, ratios). Cases:

* ``flatfield_undistort``: dark + flatfield + undistort (poly(8,8), bilinear ``cv2.remap``) of a
  1024² 12-bit frame, per frame (the remap tables are built once, timed separately);
  ``pipeline_workers2`` is the same chain through :meth:`Pipeline.map` on 2 threads.
* ``richardson_lucy``: 10 Richardson–Lucy iterations of a 1024² frame with the thesis-like PSF
  (σ = 1.28 px, 13² kernel), undamped and damped.
* ``poly_fit``: a (15, 15) polynomial (136 terms) fitted to 250 grid points: the forward map
  alone (one QR, plus the SVD for rank/condition) and a whole :func:`fit_distortion` (both
  directions).
* ``grid_calibration``: detection + indexing + poly(8,8) fit on a 1024² grid frame.

Each time is the median of repeated runs (``--quick``: 512² frames and fewer repeats). NumPy's
BLAS may use several threads for the small least-squares problems; on a loaded 2-core machine
that can be slower than one thread — ``OPENBLAS_NUM_THREADS`` is reported.
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import cv2
import numpy as np

from core.imaging.deconvolution import richardson_lucy
from core.imaging.distortion import calibrate_distortion
from core.imaging.distortion_maps import remap_tables
from core.imaging.distortion_models import fit_distortion
from core.imaging.flatfield import build_flatfield
from core.imaging.pipeline import Pipeline
from core.imaging.pointmaps import fit_polynomial_map
from core.imaging.psf import gaussian_psf


def _median_ms(fn, repeat: int) -> float:
    fn()  # warm-up
    t = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        t.append(time.perf_counter() - t0)
    return float(np.median(t) * 1e3)


def _machine() -> dict:
    return {"platform": platform.platform(), "machine": platform.machine(), "cpu_count": os.cpu_count(),
            "python": platform.python_version(), "numpy": np.__version__, "opencv": cv2.__version__,
            "opencv_threads": cv2.getNumThreads(),
            "OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS")}


def run(*, quick: bool = False) -> dict:
    """Run every case and return the JSON-ready result."""
    from core.synthetic import Distortion, ImagingModel, distortion_grid_frame, flatfield_frames, foot_rig

    n = 512 if quick else 1024
    rep = 3 if quick else 10
    cam = foot_rig(seed=0, pixels=n)[0]
    dist = Distortion.for_camera(cam, k1=0.04, k2=0.06, twist_deg=5.0, twist_power=4.0)
    model = ImagingModel.fluoroscope(cam, rng=0, distortion=dist)
    grid = distortion_grid_frame(cam, model, rng=1)
    flats, _ = flatfield_frames(cam, model, 8, rng=2)
    ff = build_flatfield(flats, dark=model.dark_dn)
    frame = flats[0]
    out: dict = {"benchmark": "imaging", "machine": _machine(), "device": "cpu", "quick": quick,
                 "frame": {"shape": [n, n], "dtype": str(frame.dtype), "bits": 12}, "times_ms": {}}
    T = out["times_ms"]

    t0 = time.perf_counter()
    cal = calibrate_distortion(grid.image, pitch_mm=15.0, feature_diameter_px=3.0 / cam.pixel_size,
                               model="poly(8,8)")
    T["grid_calibration"] = (time.perf_counter() - t0) * 1e3
    out["grid_points"] = len(cal.index)

    t0 = time.perf_counter()
    remap_tables(cal.model, (n, n))
    T["remap_tables_once"] = (time.perf_counter() - t0) * 1e3
    pipe = Pipeline.standard(flatfield=ff, distortion=cal.model)
    T["flatfield_undistort"] = _median_ms(lambda: pipe.apply(frame), rep)
    T["flatfield_only"] = _median_ms(lambda: ff.normalise(frame), rep)
    frames = [flats[k % len(flats)] for k in range(4 * rep)]
    t0 = time.perf_counter()
    for _ in pipe.map(frames, workers=2):
        pass
    T["pipeline_workers2_per_frame"] = (time.perf_counter() - t0) * 1e3 / len(frames)

    img = pipe.apply(frame)
    psf = gaussian_psf(model.psf_sigma_px)
    T["richardson_lucy_10"] = _median_ms(lambda: richardson_lucy(img, psf, iterations=10), max(2, rep // 3))
    T["richardson_lucy_10_damped"] = _median_ms(
        lambda: richardson_lucy(img, psf, iterations=10, damping=1.0,
                                photons_per_unit=model.photons_per_pixel), max(2, rep // 3))

    rng = np.random.default_rng(0)
    p = cal.grid.ideal_uv
    if len(p) > 250:
        p = p[rng.choice(len(p), 250, replace=False)]
    k = len(p)
    q = cal.model.forward(p) + rng.normal(0, 0.2, p.shape)
    T["poly_fit_15_15_forward"] = _median_ms(lambda: fit_polynomial_map(p, q, (15, 15)), rep)
    T["poly_fit_15_15_both"] = _median_ms(lambda: fit_distortion(p, q, "poly(15,15)"), rep)
    out["poly_fit"] = {"order": [15, 15], "terms": 136, "points": int(k)}
    out["psf"] = {"sigma_px": model.psf_sigma_px, "size": int(psf.shape[0])}
    out["ratios"] = {
        "frames_per_s_flatfield_undistort": 1e3 / T["flatfield_undistort"],
        "frames_per_s_pipeline_workers2": 1e3 / T["pipeline_workers2_per_frame"],
        "rl10_over_flatfield_undistort": T["richardson_lucy_10"] / T["flatfield_undistort"],
    }
    return out


def main(argv: list[str] | None = None, *, prog: str = "python -m core.studies.imaging.benchmark") -> int:
    ap = argparse.ArgumentParser(prog=prog,
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="512² frames, fewer repeats (a smoke run)")
    ap.add_argument("--out", help="also write the JSON to this file")
    args = ap.parse_args(argv)
    res = run(quick=args.quick)
    from core.io.atomic import print_json

    print_json(res, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
