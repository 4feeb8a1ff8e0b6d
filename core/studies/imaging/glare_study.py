"""What measuring and undoing veiling glare does to a log-domain cost's optimum
(``python -m core.studies.imaging.glare_study``).

The check of :mod:`core.studies.tracking.bound_gap`'s ceiling, with the glare measured the way
a lab would: on the standard synthetic walking trial (:class:`core.studies.tracking.acceptance.
TrackingScene`) at reduced size on the CPU, each bone's weighted least-squares cost
(:class:`core.tracking.likelihood_cost.LikelihoodCost`: line integrals, no high-pass, gain and a
quadratic background fitted, the other bones at their true poses subtracted) is minimised from
the true pose (:meth:`LikelihoodCost.refine`) on *noise-free* frames, so what remains is the
cost's bias. The soft tissue's true line integral is taken out of every frame (study-only: the
tissue is what else biases such a cost, and it would hide the glare's share). Frames:

* ``no_glare`` — the fluence ``exp(-∫μ)`` alone;
* ``glare`` — through the view's veiling glare only (5 %, σ 20 mm: the trial's chain without
  PSF, roll-off, distortion and noise), flatfield-normalised;
* ``glare_removed`` — that frame through :func:`core.imaging.glare.remove_glare` with the glare
  *measured* from synthetic lead-disc calibration frames of the view (the trial's whole chain,
  noise included: ``--disc-frames`` disc frames over ``--flat-frames`` empty-field frames,
  flatfield-normalised, undistorted with the trial's slightly wrong inverse,
  :func:`core.imaging.glare.estimate_glare`); the generator's glare values are read only to
  report the estimate's error;
* ``glare_removed_true`` — the same with the generator's values (the removal's own ceiling);
* ``full`` / ``full_glare_removed`` — the trial's whole noise-free chain (PSF, glare, roll-off,
  distortion undone by the 3 %-wrong inverse), without and with the measured glare removed
  after the flatfield division (the pipeline's order);
* ``full_noisy`` / ``full_glare_removed_noisy`` (``--seeds N``) — the same with the trial's quanta
  and read noise, N draws per frame, corrected as the pipeline does (flatfield clipped to [0, 1],
  then the glare step): the whole error against the Cramér–Rao bound of the frames
  (:func:`core.tracking.bound.pose_bound`).

Results (``resources/benchmarks/glare_cpu.json``, this 2-core CPU machine, 256², 1 mm voxels,
frames 10/40/70; RMS over the frames, mm / degrees):

* the glare measured from 4 disc frames per view: fraction 0.0497 and 0.0499 (true 0.05, fit SD
  0.0003), σ 17.04 and 17.10 px (true 17.07 px, fit SD 0.07-0.08 px);
* glare alone moves the optimum 0.21 / 0.45 (talus), 0.20 / 0.18 (calcaneus), 0.036 / 0.17
  (tibia); with the measured glare removed 0.0022 / 0.0032, 0.0018 / 0.0013, 0.0005 / 0.0016
  (99 % of the bias gone; the same as with the generator's values, ≤ 0.0024 / 0.0042); without
  glare ≤ 0.0013 / 0.0011;
* through the whole chain 0.21 / 0.45, 0.26 / 0.22, 0.049 / 0.21 become 0.017 / 0.060, 0.035 /
  0.039, 0.054 / 0.042: what is left is the unmodelled PSF and the residual distortion of the
  3 %-wrong inverse (~0.06 mm on the tibia in :mod:`core.studies.tracking.bound_gap`);
* with the trial's noise (``--seeds 4``: 12 samples per bone, ratios uncertain by ~20 %) the RMS
  error over the Cramér–Rao bound (mm, °) goes from 3.93 / 2.05 to 1.29 / 1.01 (talus), 7.49 /
  2.48 to 2.12 / 1.50 (calcaneus), 2.80 / 1.97 to 3.42 / 1.50 (tibia, whose translation is held by
  the residual distortion).

JSON on stdout (``--out``: also to a file).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

from core.studies.imaging.glare_frames import disc_line_integrals, measure_glare

__all__ = ["disc_line_integrals", "main", "measure_glare", "run"]

VARIANTS = ("no_glare", "glare", "glare_removed", "glare_removed_true", "full", "full_glare_removed")


def _frames(ts, L, variant: str, est, seed=None, frame: int = 0) -> list[np.ndarray]:
    from core.imaging.glare import remove_glare

    out = []
    for v, model in enumerate(ts.scene.imaging):
        if seed is not None:  # the noisy chain, corrected as the pipeline does (clipped to [0, 1])
            raw = model.apply(L[v], rng=np.random.default_rng([int(seed), v, int(frame), 0x61A2E]))
            f = np.clip(model.to_float(raw, flatfield=model.flatfield(L[v].shape)), 0.0, 1.0)
            if variant == "full_glare_removed":
                f = remove_glare(f, est[v].fraction, est[v].sigma_px)
            out.append(np.asarray(ts.corrections[v].unwarp(f.astype(np.float32)), np.float64))
            continue
        quiet = replace(model, photons_per_pixel=None, read_noise_dn=0.0)
        glare_only = type(model)(glare_fraction=model.glare_fraction, glare_sigma_px=model.glare_sigma_px,
                                 gain_dn=model.gain_dn, dark_dn=model.dark_dn)
        if variant == "no_glare":
            f = np.exp(-L[v].astype(np.float64))
        elif variant.startswith("glare"):
            f = glare_only.expected_dn(L[v]) - model.dark_dn
            f = f / (glare_only.flatfield(L[v].shape) - model.dark_dn)
            if variant == "glare_removed":
                f = remove_glare(f, est[v].fraction, est[v].sigma_px, clip=None)
            elif variant == "glare_removed_true":
                f = remove_glare(f, model.glare_fraction, model.glare_sigma_px, clip=None)
        else:
            flat = quiet.flatfield(L[v].shape) - model.dark_dn
            ok = flat > 1e-6 * model.gain_dn
            f = np.where(ok, (quiet.expected_dn(L[v]) - model.dark_dn) / np.where(ok, flat, 1.0), 0.0)
            if variant == "full_glare_removed":
                f = remove_glare(f, est[v].fraction, est[v].sigma_px, clip=None)
            f = ts.corrections[v].unwarp(f.astype(np.float32))
        out.append(np.asarray(f, np.float64))
    return out


def _tissue(ts, L, truth) -> np.ndarray:
    """The soft tissue's line integral: the frame's minus the bones' (the tracker's bone models at
    the truth) and the walkway's."""
    from core.synthetic.analytic import slab_line_integrals

    bones = ts.renderer.render(truth[None], roi="full").numpy()[0].sum(axis=1)
    T = np.asarray(L, np.float64) - bones
    if ts.scene.floor is not None:
        z, t, mu = ts.scene.floor
        for v, cam in enumerate(ts.scene.rig):
            T[v] -= slab_line_integrals(cam, (0.0, 0.0, z - t / 2), (0.0, 0.0, 1.0), t, mu)
    return T


def run(*, pixels: int = 256, voxel: float = 1.0, frames=(10, 40, 70), bones=(0, 1, 2), n_disc: int = 4,
        n_flat: int = 10, variants=VARIANTS, iters: int = 8, seeds: int = 0) -> dict:
    """Run the study (module docs); returns the JSON-ready results."""
    from core.studies.tracking.acceptance import TrackingScene, pose_errors
    from core.tracking.bound import pose_bound
    from core.tracking.cost import prepare_frame, search_roi
    from core.tracking.likelihood_cost import LikelihoodCost

    t0 = time.perf_counter()
    ts = TrackingScene(n_frames=100, pixels=pixels, spacing=voxel, phase=(0.0, 0.6), device="cpu")
    est = [measure_glare(c, m, corr.unwarp, n_disc=n_disc, n_flat=n_flat, seed=v)
           for v, (c, m, corr) in enumerate(zip(ts.scene.rig, ts.scene.imaging, ts.corrections, strict=True))]
    out = {"study": "core.studies.imaging.glare_study", "machine": "this 2-core CPU machine", "device": "cpu",
           "pixels": pixels, "voxel_mm": voxel, "frames": list(frames), "variants": list(variants),
           "glare": [{"view": v, "true_fraction": m.glare_fraction, "true_sigma_px": m.glare_sigma_px,
                      "pixel_mm": c.pixel_size, **e.to_dict(pixel_mm=c.pixel_size),
                      "fraction_error_rel": e.fraction / m.glare_fraction - 1,
                      "sigma_error_rel": e.sigma_px / m.glare_sigma_px - 1}
                     for v, (c, m, e) in enumerate(zip(ts.scene.rig, ts.scene.imaging, est, strict=True))],
           "disc": {"diameter_mm": 60.0, "lead_mm": 2.0, "frames": n_disc, "empty_field_frames": n_flat},
           "seconds_setup": time.perf_counter() - t0, "rows": []}
    noisy = [(v, s) for v in ("full", "full_glare_removed") if v in variants for s in range(int(seeds))]
    covs: dict = {}
    for f in frames:
        L = ts.scene.line_integrals(f, renderer=ts._scene_renderer)
        truth = ts.truth(f)
        keep = np.exp(_tissue(ts, L, truth))  # the tissue taken out in the fluence (log) domain
        if seeds:
            for b in bones:
                covs.setdefault(ts.names[b], []).append(pose_bound(
                    ts.renderer, b, truth[b], ts.models[b].centroid, line_integral=L,
                    quanta_per_pixel=[m.photons_per_pixel for m in ts.scene.imaging]).covariance)
        for var, seed in [(v, None) for v in variants] + noisy:
            ims = _frames(ts, L, var, est, seed, f)
            frame = prepare_frame([im * k for im, k in zip(ims, keep, strict=True)], valid_range=(1e-4, 1e3))
            for b in bones:
                m = ts.models[b]
                oth = [k for k in range(len(ts.models)) if k != b]
                roi = search_roi(ts.renderer, truth[b], b, views=[0, 1], center=m.centroid, reach_mm=2.0)
                cost = LikelihoodCost(ts.renderer, frame, bone=b, base_pose=truth[b], center=m.centroid,
                                      roi=roi, others=(truth[oth], oth), others_gain=False, background=2)
                x = cost.refine(iters=iters)["x"]
                e = pose_errors(cost.poses(x[None])[0], truth[b], m.centroid)
                out["rows"].append({"frame": f, "variant": var if seed is None else f"{var}_noisy",
                                    "seed": seed, "bone": ts.names[b],
                                    "error_mm": float(np.linalg.norm(e[:3])),
                                    "error_deg": float(np.linalg.norm(e[3:])), "error": e.round(5).tolist()})
        print(f"frame {f} done {time.perf_counter() - t0:.0f}s", flush=True)
    out["summary"] = _summary(out["rows"], list(variants) + sorted({f"{v}_noisy" for v, _ in noisy}),
                              [ts.names[b] for b in bones])
    for n, cs in covs.items():
        C = np.mean(cs, axis=0)
        bound = (float(np.sqrt(np.trace(C[:3, :3]))), float(np.sqrt(np.trace(C[3:, 3:]))))
        out.setdefault("bound", {})[n] = {"rms_mm": bound[0], "rms_deg": bound[1]}
        for var, d in out["summary"].items():
            if var.endswith("_noisy") and n in d:
                d[n]["rms_over_bound"] = [d[n]["bias_mm"] / bound[0], d[n]["bias_deg"] / bound[1]]
    out["total_s"] = time.perf_counter() - t0
    return out


def _summary(rows, variants, names) -> dict:
    """Per variant and bone: the RMS over frames (and noise draws) of the optimum's distance from
    the truth (for noise-free variants the bias, for ``_noisy`` ones the whole error)."""
    s: dict = {}
    for var in variants:
        for n in names:
            r = [x for x in rows if x["variant"] == var and x["bone"] == n]
            if r:
                s.setdefault(var, {})[n] = {
                    "bias_mm": float(np.sqrt(np.mean([x["error_mm"] ** 2 for x in r]))),
                    "bias_deg": float(np.sqrt(np.mean([x["error_deg"] ** 2 for x in r]))),
                    "max_mm": max(x["error_mm"] for x in r), "max_deg": max(x["error_deg"] for x in r)}
    return s


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m core.studies.imaging.glare_study",
                                description=__doc__.split("\n")[0])
    p.add_argument("--pixels", type=int, default=256)
    p.add_argument("--voxel", type=float, default=1.0)
    p.add_argument("--frames", default="10,40,70")
    p.add_argument("--bones", default="0,1,2", help="bone indices (0 tibia, 1 talus, 2 calcaneus)")
    p.add_argument("--disc-frames", type=int, default=4)
    p.add_argument("--flat-frames", type=int, default=10)
    p.add_argument("--variants", default=",".join(VARIANTS))
    p.add_argument("--seeds", type=int, default=0,
                   help="noise draws of the whole chain without and with the measured glare removed")
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    res = run(pixels=a.pixels, voxel=a.voxel, frames=[int(x) for x in a.frames.split(",")],
              bones=[int(x) for x in a.bones.split(",")], n_disc=a.disc_frames, n_flat=a.flat_frames,
              variants=a.variants.split(","), seeds=a.seeds)
    from core.io.atomic import print_json

    print_json(res, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
