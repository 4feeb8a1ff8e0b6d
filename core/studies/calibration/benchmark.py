"""Speed of the calibration steps: ``python -m core.studies.calibration.benchmark [--quick] [--out FILE]``.

Prints JSON (machine, sizes, seconds). Cases:

* ``bundle_adjustment``: 50 frames x 33 beads x 2 views (0.05 px noise, DLT initial guess,
  covariance and derived standard deviations included), and 20 frames;
* ``sensitivity``: 5,000 Latin-hypercube samples (15-bead cube, one camera) and a Sobol analysis
  (1,024 base samples x 32 = 32,768 DLTs);
* ``dlt``: one :func:`~core.calibration.calibrate_dlt` call and 5,000 batched DLTs;
* ``labelling``: one view of the 33-bead spiral (projected points, 0-3 beads missing) and a
  20-frame :func:`~core.calibration.label_sequence` with the epipolar geometry estimated;
* ``detection``: :func:`~core.calibration.detect_object_beads` on one rendered frame.

Times are the median of ``repeats`` runs (wall clock, ``time.perf_counter``). This code runs on
the CPU only (numpy / scipy / OpenCV).
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

__all__ = ["main", "run_benchmark"]


def _time(fn, repeats: int) -> float:
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return float(np.median(ts))


def run_benchmark(*, quick: bool = False, repeats: int = 3) -> dict:
    import scipy

    from core.calibration.bundle import bundle_adjust
    from core.calibration.detection import detect_object_beads
    from core.calibration.dlt import calibrate_dlt, dlt_batch
    from core.calibration.labelling import label_view
    from core.calibration.matching import label_sequence
    from core.calibration.objects import cube_target, spiral_target
    from core.calibration.sensitivity import perturbation_study, sobol_analysis
    from core.geometry.transforms import make_rigid
    from core.studies.calibration.labelling_study import projected_frames
    from core.synthetic.capture import capture_centre, capture_poses, observe, render
    from core.synthetic.imaging import ImagingModel
    from core.synthetic.rig import foot_rig

    r = 1 if quick else repeats
    rig = foot_rig(seed=0, pixels=1024)
    sizes = [(c.width, c.height) for c in rig]
    sp = spiral_target(33)
    out = {"machine": {"platform": platform.platform(), "processor": platform.machine(),
                       "cpus": os.cpu_count(), "python": sys.version.split()[0], "numpy": np.__version__,
                       "load_average_at_start": list(os.getloadavg()),
                       "scipy": scipy.__version__},
           "device": "cpu", "repeats": r, "quick": quick}
    ba = {}
    for n in (20, 50):
        poses = capture_poses(rig, sp, n, rng=n)
        frames = observe(rig, sp, poses, noise_px=0.05, rng=1)
        res = bundle_adjust(frames, sizes, T_lab_from_reference=poses[0], pixel_size=rig[0].pixel_size,
                            pixel_sigma=0.05)
        t = _time(lambda f=frames, p=poses: bundle_adjust(f, sizes, T_lab_from_reference=p[0],
                                                          pixel_size=rig[0].pixel_size, pixel_sigma=0.05), r)
        ba[f"{n}_frames"] = {"frames": n, "beads": len(sp), "views": 2, "observations": len(res.frame_index),
                             "parameters": len(res.parameters), "evaluations": res.n_evaluations,
                             "seconds": t, "ok": res.ok}
    out["bundle_adjustment"] = ba
    cube = cube_target().centers_lab(make_rigid(np.eye(3), capture_centre(rig)))
    n_s = 5000
    out["sensitivity"] = {
        "latin_hypercube": {"samples": n_s, "beads": 15,
                            "seconds": _time(lambda: perturbation_study(rig[0], cube, n_samples=n_s), r)},
        "sobol": {"base_samples": 1024, "inputs": 30, "dlt_evaluations": 1024 * 32,
                  "seconds": _time(lambda: sobol_analysis(rig[0], cube, n=1024), r)}}
    uv = rig[0].project(cube)
    single = _time(lambda: [calibrate_dlt(cube, uv, width=1024, height=1024) for _ in range(100)], r) / 100
    noisy = uv[None] + np.random.default_rng(0).normal(0, 0.05, (5000, 15, 2))
    out["dlt"] = {"single_seconds": single, "batched_5000_seconds": _time(lambda: dlt_batch(cube, noisy), r)}
    g = np.random.default_rng(2)
    dets, _ = projected_frames(sp, rig, 20, rng=g)
    views = [d for pair in dets for d in pair]
    out["labelling"] = {
        "view_seconds": _time(lambda: [label_view(sp, d) for d in views], 1) / len(views),
        "sequence_20_frames_seconds": _time(lambda: label_sequence(sp, dets, rng=0), 1)}
    px = 512 if quick else 1024
    rig_d = foot_rig(seed=0, pixels=px)
    im = ImagingModel.fluoroscope(rig_d[0], distortion=None)
    fr = render(rig_d, sp, capture_poses(rig_d, sp, 1, rng=3)[0], rng=0, imaging=[im, im])
    img = im.to_float(fr.image[0])
    ppm = rig_d[0].fx / np.linalg.norm(capture_centre(rig_d) - rig_d[0].source)
    det = detect_object_beads(img, sp.size_classes[0], px_per_mm=ppm)
    t = _time(lambda: detect_object_beads(img, sp.size_classes[0], px_per_mm=ppm), r)
    out["detection"] = {"pixels": px, "beads_found": len(det), "seconds": t}
    return out


def main(argv=None, *, prog: str = "python -m core.studies.calibration.benchmark") -> int:
    ap = argparse.ArgumentParser(prog=prog,
                                 description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="one repeat, 512-pixel detection frame")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default=None, help="also write the JSON to this file")
    a = ap.parse_args(argv)
    if a.repeats < 1:
        ap.error("--repeats: expected a positive integer")
    res = run_benchmark(quick=a.quick, repeats=a.repeats)
    text = json.dumps(res, indent=1)
    if a.out:
        Path(a.out).write_text(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
