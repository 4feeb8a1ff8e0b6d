"""The tracker's noise correction with and without (``python -m core.studies.tracking.noise_correction``).

:class:`core.tracking.register.RegistrationOptions` ``noise_correction`` takes the quantum noise's
expected squared gradient ``E₁ / F`` out of the fluoroscope's squared gradient magnitudes
(:mod:`core.studies.tracking.gc_noise_bias` found that pedestal to bias the gradient correlation of
magnitudes), ``E₁`` estimated from each frame (:func:`core.similarity.gradient.frame_noise_energy`).
This study tracks, in one process, with the correction off and on (newton search, the tracker's
other defaults):

* ``hard`` — the harder acceptance trial (:mod:`core.studies.tracking.hard_trial`: its scene, its
  2 mm / 3° starts, :func:`~core.studies.tracking.hard_trial.evaluate`), sequential and joint, and
  each frame's ``E₁`` against the calibration's (two plate frames per view,
  :func:`core.studies.tracking.gc_noise_bias.calibration_energy`'s frames and
  :func:`core.similarity.gradient.noise_gradient_energy`);
* ``acceptance`` — the walking trial of :mod:`core.studies.tracking.benchmark` (talus alone, three
  bones joint: speed, errors over the Cramér–Rao bound, silent failures), and the time of the
  estimate per view.

Results: ``resources/benchmarks/tracking_noise_energy_h200.json`` (one NVIDIA H200, 1024², 0.5 mm
voxels; 12 hard frames, 20 acceptance frames); the speed with the noise samples drawn by the frame
look-ahead (``--parts acceptance --no-bound --inline``): ``tracking_noise_speed_h100.json`` (one
NVIDIA H100). JSON on stdout (and ``--out``).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace

import numpy as np

__all__ = ["acceptance", "hard", "main"]


def _log(t0: float, *a) -> None:
    print(f"[{time.perf_counter() - t0:6.1f}s]", *a, file=sys.stderr, flush=True)


def hard(*, n_frames: int = 12, pixels: int = 1024, spacing: float = 0.5, seed: int = 0) -> dict:
    """The harder trial tracked with the correction off and on (``plain/…``, ``corrected/…``)."""
    import core.studies.tracking.gc_noise_bias as G
    from core.geometry.transforms import pose_from_params
    from core.similarity.gradient import frame_noise_energy, noise_gradient_energy
    from core.studies.tracking.acceptance import _random_offset
    from core.studies.tracking.hard_trial import HardRun, _contacts, evaluate
    from core.tracking.trial import TrackingOptions, track

    t0 = time.perf_counter()
    hr = HardRun(n_frames=n_frames, pixels=pixels, spacing=spacing, seed=seed)
    for f in range(n_frames):
        hr.frames(f)
    bounds = hr.bounds(range(n_frames))
    contacts = _contacts(hr)
    g = np.random.default_rng(seed + 7)  # the starts of hard_trial.run
    kf = {n: {0: pose_from_params(_random_offset(g, 2.0, 3.0), center=m.centroid, base=hr.truth(0)[b])}
          for b, (n, m) in enumerate(zip(hr.names, hr.models, strict=True))}
    base = TrackingOptions()
    out: dict = {"runs": {}}
    for nc in (False, True):
        reg = replace(base.registration, search="newton", noise_correction=nc)
        for mode in ("sequential", "joint"):
            t1 = time.perf_counter()
            res = track(hr.renderer, hr.models, hr.frames, range(n_frames), keyframes=kf,
                        options=replace(base, registration=reg, mode=mode))
            ev = evaluate(hr, res, bounds, contacts)
            ev["wall_s"] = time.perf_counter() - t1
            out["runs"][f"{'corrected' if nc else 'plain'}/{mode}"] = ev
            _log(t0, "corrected" if nc else "plain", mode,
                 {n: (round(b["rms_error_mm"], 4), round(b["rms_error_deg"], 3), b["silent_failures"])
                  for n, b in ev["bones"].items()})
    sig = 0.3 / float(hr.scene.rig[0].pixel_size)
    views = []
    for v in range(len(hr.corrections)):
        a, b = G._calibration_flats(hr, v, seed=seed)
        cal = noise_gradient_energy(a, b, fluoro_sigma=sig)
        est = [frame_noise_energy(hr.frames(f)[v], fluoro_sigma=sig) for f in range(n_frames)]
        views.append({"view": v, "calibration_E1": cal,
                      "frame_E1_over_calibration": (np.array(est) / cal).round(3).tolist()})
    out["energy_check"] = {"sigma_px": sig, "views": views}
    return out


def acceptance(*, n_frames: int = 20, pixels: int = 1024, spacing: float = 0.5, repeats: int = 3,
               bound: bool = True, inline: bool = False) -> dict:
    """The walking trial's benchmark cases (:func:`core.studies.tracking.benchmark._case`) with
    the correction off and on, and the estimate's time per view (``bound=False``: without the
    Cramér–Rao bound, the speed alone; ``inline``: also ``corrected_inline``, the correction with
    the noise samples drawn in the registering thread, as before the frame look-ahead drew them)."""
    from core.similarity.gradient import frame_noise_energy
    from core.studies.tracking.acceptance import TrackingScene, cramer_rao
    from core.studies.tracking.benchmark import _case
    from core.tracking.trial import TrackingOptions

    t0 = time.perf_counter()
    n = int(n_frames)
    ts = TrackingScene(n_frames=n, pixels=pixels, spacing=spacing, phase=(0.0, 0.6 * n / 100.0), device=None)
    for i in range(n):
        ts.frames(i)
    bound = cramer_rao(ts, range(0, n, 4)) if bound else None
    sig = 0.3 / float(ts.scene.rig[0].pixel_size)
    times, energies = [], []
    for i in range(n):
        for v in range(2):
            fl = np.asarray(ts.frames(i)[v], np.float32)
            t = time.perf_counter()
            energies.append(frame_noise_energy(fl, fluoro_sigma=sig))
            times.append(time.perf_counter() - t)
    out: dict = {"bound": bound, "estimate": {"sigma_px": sig, "E1": energies,
                                              "ms_per_view_median": 1e3 * float(np.median(times)),
                                              "ms_per_view_max": 1e3 * float(np.max(times))}, "runs": {}}
    from core.tracking.feed import FrameFeed

    base = TrackingOptions(mode="joint")
    keys = FrameFeed._noise_keys
    for label in ("plain", "corrected") + (("corrected_inline",) if inline else ()):
        nc = label != "plain"
        o = replace(base, registration=replace(base.registration, search="newton", noise_correction=nc))
        if label == "corrected_inline":  # nothing drawn ahead
            FrameFeed._noise_keys = lambda self: ()
        try:
            for case, bones in (("one_bone", [1]), ("three_bones", [0, 1, 2])):
                r = _case(ts, bones, o, n, int(repeats), bound)
                out["runs"][f"{label}/{case}"] = r
                ms = r["end_to_end"]["ms_per_frame_after_first"]
                _log(t0, label, case, round(ms, 2), "ms per frame")
        finally:
            FrameFeed._noise_keys = keys
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.noise_correction",
                                description=__doc__.split("\n")[0])
    p.add_argument("--parts", default="hard,acceptance", help="hard, acceptance or both (comma-separated)")
    p.add_argument("--pixels", type=int, default=1024)
    p.add_argument("--voxel", type=float, default=0.5, help="voxel size, mm")
    p.add_argument("--hard-frames", type=int, default=12)
    p.add_argument("--acceptance-frames", type=int, default=20)
    p.add_argument("--no-bound", action="store_true", help="acceptance: speed alone (no Cramér–Rao bound)")
    p.add_argument("--inline", action="store_true",
                   help="acceptance: also the correction with the noise drawn in the registering thread")
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    from core.io.atomic import print_json

    parts = a.parts.split(",")
    res: dict = {"study": "core.studies.tracking.noise_correction"}
    if "hard" in parts:
        res["hard"] = hard(n_frames=a.hard_frames, pixels=a.pixels, spacing=a.voxel)
    if "acceptance" in parts:
        res["acceptance"] = acceptance(n_frames=a.acceptance_frames, pixels=a.pixels, spacing=a.voxel,
                                       bound=not a.no_bound, inline=a.inline)
    print_json(res, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
