"""Speed of bead localisation: ``python -m core.studies.markers.benchmark [--quick] [--out FILE]``.

Times :func:`core.markers.batch.localize` on ``n_beads`` beads (2 and 3 mm steel, 6–9 px) in a
grid, over ``n_frames`` noisy frames (Poisson noise at the thesis-like dose), with guesses 1 px
off the true centres, as when tracking. The recommended localizer runs at its defaults (search
disc of 3.5 bead radii) on all frames — serially and with the default thread pool — and every
other localizer on a tenth of the frames. Prints JSON: machine, sizes, seconds, localisations
per second and the ratio to the 10,000 / s target. Timing is the best of ``--repeats`` runs of
wall-clock time (with the process CPU time of that run: ``per_cpu_second`` is what an idle core
delivers when other programs share the machine — the JSON records the load average); the
frames are rendered before timing starts.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

import numpy as np

from core.geometry.camera import Camera, make_K
from core.markers.batch import METHODS, RECOMMENDED, localize
from core.synthetic.analytic import attenuation_per_mm, bead_line_integrals

__all__ = ["bead_grid_frames", "run_benchmark"]

TARGET_PER_S = 10_000.0


def bead_grid_frames(n_beads: int = 100, n_frames: int = 1000, *, pitch_px: int = 32,
                     photons_per_pixel: float = 535.0, seed: int = 0):
    """``(frames float32 (F, H, W), true uv (N, 2), diameter_px (N,))`` of a bead grid.

    Beads alternate 2 / 3 mm on a square grid ``pitch_px`` apart, seen by a 0.327 mm-pixel
    camera 1400 mm from its source (thesis §4.3); frames are transmissions with Poisson noise of
    ``photons_per_pixel`` quanta at full fluence (5000 / mm², the study's dose).
    """
    side = int(np.ceil(np.sqrt(n_beads)))
    size = side * pitch_px + pitch_px
    f = 1400.0 / 0.327
    cam = Camera(make_K(f, f, (size - 1) / 2, (size - 1) / 2), np.eye(3), np.zeros(3), size, size,
                 pixel_size=0.327)
    g = np.random.default_rng(seed)
    ij = np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2)[:n_beads]
    uv = (ij + 1) * pitch_px + g.uniform(-0.5, 0.5, (n_beads, 2))
    z = 1390.0
    pts = np.column_stack([(uv - (size - 1) / 2) * z / f, np.full(n_beads, z)])
    dia = np.where(np.arange(n_beads) % 2 == 0, 2.0, 3.0)
    L = bead_line_integrals(cam, pts, dia, attenuation_per_mm("steel"), average="fluence")
    expected = np.exp(-L.astype(np.float64)) * photons_per_pixel
    frames = np.empty((n_frames, size, size), np.float32)
    for k in range(0, n_frames, 64):
        n = min(64, n_frames - k)
        frames[k : k + n] = g.poisson(expected, size=(n, size, size)) / photons_per_pixel
    return frames, cam.project(pts), dia * f / z


def _time(fn, repeats: int) -> tuple[float, float]:
    """Best wall-clock seconds and the process CPU seconds of that run."""
    best, cpu = np.inf, np.inf
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall = time.perf_counter() - t0
        if wall < best:
            best, cpu = wall, time.process_time() - c0
    return best, cpu


def run_benchmark(*, n_beads: int = 100, n_frames: int = 1000, repeats: int = 1) -> dict:
    """Time the localizers (module docs) and return the JSON-ready result."""
    load_before = os.getloadavg()
    frames, uv, dia = bead_grid_frames(n_beads, n_frames)
    g = np.random.default_rng(1)
    ang = g.uniform(0, 2 * np.pi, (n_frames, n_beads))
    guesses = uv + np.stack([np.cos(ang), np.sin(ang)], -1)  # 1 px off, as a tracking prediction
    n = n_frames * n_beads
    res = {}
    for workers in (1, None):
        last = {}

        def run(w=workers, out=last):
            out["loc"] = localize(frames, guesses, diameter_px=dia, workers=w)

        t, cpu = _time(run, repeats)
        loc = last["loc"]
        err = np.linalg.norm(loc.uv - uv, axis=-1)
        res["serial" if workers == 1 else "threads"] = {
            "workers": workers or min(os.cpu_count() or 1, 8), "seconds": t, "cpu_seconds": cpu,
            "localisations": n, "per_second": n / t, "per_cpu_second": n / cpu,
            "ratio_to_target": n / t / TARGET_PER_S,
            "ok_fraction": float(loc.ok.mean()), "rms_error_px": float(np.sqrt(np.nanmean(err**2))),
        }
    sub = max(1, n_frames // 10)
    others = {}
    for m in METHODS:
        if m == RECOMMENDED:
            continue
        t, cpu = _time(lambda m=m: localize(frames[:sub], guesses[:sub], diameter_px=dia, method=m), repeats)
        others[m] = {"frames": sub, "seconds": t, "per_second": sub * n_beads / t,
                     "per_cpu_second": sub * n_beads / cpu}
    return {
        "benchmark": "core.markers localize",
        "machine": {"platform": platform.platform(), "processor": platform.machine(),
                    "cpu_count": os.cpu_count(), "python": sys.version.split()[0],
                    "numpy": np.__version__, "load_average_before": list(load_before),
                    "load_average_after": list(os.getloadavg())},
        "device": "cpu (numpy, vectorised over beads and frames; threads over chunks)",
        "sizes": {"n_beads": n_beads, "n_frames": n_frames, "image_px": list(frames.shape[1:]),
                  "bead_diameter_px": sorted({round(float(d), 2) for d in dia}),
                  "guess_error_px": 1.0},
        "recommended": RECOMMENDED, "target_per_second": TARGET_PER_S,
        "robust": res, "other_methods": others,
    }


def main(argv=None, *, prog: str = "python -m core.studies.markers.benchmark") -> int:
    ap = argparse.ArgumentParser(prog=prog,
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="100 beads x 50 frames (a smoke run)")
    ap.add_argument("--repeats", type=int, default=None, help="timed runs per case (best is kept)")
    ap.add_argument("--out", default=None, help="also write the JSON to this file")
    args = ap.parse_args(argv)
    frames = 50 if args.quick else 1000
    reps = args.repeats or (3 if args.quick else 2)
    res = run_benchmark(n_frames=frames, repeats=reps)
    text = json.dumps(res, indent=1)
    print(text)
    if args.out:
        with open(args.out, "w") as fh:
            fh.write(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
