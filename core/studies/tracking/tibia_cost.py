"""What moves the tibia's optimum under the default tracker's cost (``python -m
core.studies.tracking.tibia_cost``).

The acceptance trial's tibia (:class:`core.studies.tracking.acceptance.TrackingScene`) is registered
from its TRUE pose by the default tracker (:func:`core.tracking.register.register` with
``TrackingOptions().registration``: gradient correlation of the gradient magnitudes, both images
smoothed by 0.3 mm, Gauss–Newton steps at full resolution), the talus and calcaneus at their true
poses subtracted, on frames taken apart one part at a time (``--variants``):

* ``trial`` — the trial's frame (the chain, the calibration session's grid correction), prepared as
  the tracker prepares it (black and saturated pixels and 3 px around them unusable);
* ``norim`` — the same without the intensifier's round field (no black outside: no rim);
* ``fill`` — the trial's frame, its unusable pixels given the nearest usable pixel's value (the same
  usable pixels, no black step for the smoothing and the gradient to spread);
* ``band`` — the trial's frame, the usable pixels within ``band_px`` of a black one (the rim's
  band; by default 4 σ of the smoothing plus 2 px, :func:`core.tracking.cost.rim_radius`) unusable
  too, through the frame's own masks;
* ``notissue`` — without the soft-tissue envelope; ``alone`` — without the other bones (nothing
  subtracted); ``exact`` — the distortion undone by the true model (the residual distortion
  removed).

and with the cost changed (``--costs``, on the frames of ``--cost-variants``): ``gc`` (the default),
``gc45``, ``gc60`` (both images smoothed by 0.45, 0.6 mm), ``components`` (GC of the gradient
components), ``band`` (the tracker's band at the rim, the ``gc`` term's option ``rim_sigmas=4``,
:data:`core.tracking.cost.RIM_OPTION`; ``+band`` adds it to another cost; the others are without
it, whatever the default; ``+noise``: the quantum noise's share taken out of the magnitudes,
``noise_correction``; ``+tight``: the Gauss–Newton steps until a step is below 0.002 mm / ° and
no stop on the predicted decrease, at most 16); ``ncc``, ``gd``, ``gi`` (that kind alone, both images
smoothed by 0.3 mm) and ``gcnccNN``, ``gcgdNN``, ``gcgiNN`` (GC and NN/100 times that kind, weights
normalised): the Gauss–Newton engine takes one term, so the mixtures are searched by the quadratic
model at full resolution (design half-widths 0.25 mm / 0.5°, to a 0.005 step), ``+quad`` on GC for the
same search, ``+fine`` with half-widths 0.1 mm / 0.2°. Each frame noise-free (the cost's bias) and
noisy (the trial's own noise draw; ``--draws N``: N draws per frame, the trial's own then independent
ones, with the long-axis spread over the draws and the RMS of their per-frame means).

Per variant, cost and noise: the RMS error (mm, °) over the frames, the rotation about the tibia's
long axis (its mean and RMS; the first principal axis of its surface, in the lab), and the RMS of
the optimum's move from the ``trial``/``gc`` optimum of the same frame (paired: what that part
moves); the Cramér–Rao bound of this scene's frames for scale. ``rim``: per frame and view the
tibia's usable pixels (its DRR's support at the true pose within the search region) within
``band_px`` of a black pixel. Study only: it reads the truth. JSON on stdout (and ``--out``).

Measured (``resources/benchmarks/tracking_tibia_cost_cpu.json``, this 2-core x86_64 machine, shared;
1024², 1 mm voxels, grid correction; × this scene's bound 0.018 mm / 0.111°):

* noise-free, frames 0–90 every 15th: the tibia's GC optimum 0.0275 mm / 0.142° off the truth,
  0.140° RMS about its long axis (mean −0.074°); what moves it (RMS over the frames, mm / °,
  long axis): the soft tissue 0.026 / 0.137 (0.132; without it 0.022° about the long axis), the rim
  0.009–0.012 / 0.036–0.049 (``norim``, ``fill``, ``band``), the residual distortion 0.007 / 0.029,
  the other bones 0.004 / 0.048; GC of the components 0.040 / 0.161 (its long-axis offset 0.047°
  RMS, +0.031° mean);
* smoothing by 0.45 / 0.6 mm moves the noise-free optimum by 0.06 / 0.15 mm (frames 81, 20, 50): the
  rim's step spread further (0.022 / 0.026 mm with the band), the long-axis offset then −0.14 /
  −0.20°;
* noisy (the trial's draw, one per frame): the rotation error is mostly the noise's spread (frames
  81, 20, 50: 0.27° RMS against 0.078° noise-free; frames 0–90: 0.146°); the rim, the band and the
  distortion move the noisy optimum by ≤ 0.04°, the noise correction by 0.042°, GC of the components
  by 0.153° (0.169° RMS);
* the search's share: started 0.3° about the long axis off the truth (``--start-deg ±0.3``), the
  default Gauss–Newton search ends 0.01–0.12° from where it ends started at the truth, towards the
  start in 13 of 14 registrations (frames 0–90, noisy; 0.183° RMS from +0.3°, 0.155° from −0.3°,
  0.146° from the truth): the cost is flat about that axis and the search stops (a step below 0.02,
  or its predicted decrease below a tenth of the cost's roughness) with part of its start left. Run
  to a 0.002 step (``+tight``) it ends within 0.008° of the same point from the truth and from +0.3°
  (0.175 and 0.176° RMS; 0.040° from the default search's end from the truth): the cost's own
  optimum, 1.6× this scene's bound in rotation on these frames, is what the tibia's
  rotation error is made of; stopping earlier leaves the start's error in its place, better or
  worse.
* mixtures (``resources/benchmarks/tracking_tibia_cost_mix_cpu.json``, 512², frames 20 and 60, four
  draws each, σ about the long axis 0.110°): GC's default search spreads 0.140° about the long
  axis (bias 0.006°); on the quadratic search GC 0.194° (bias 0.183°), GC + 0.25 / 0.5 NCC 0.248 /
  0.196°, GC + 0.25 GD 0.197°: none narrows it; on the fine design GC 0.164°, GC + 0.5 NCC 0.239°
  (0.051° on frame 20, but 0.24° / 0.10 mm off the truth there: the tissue's shading), GC + 0.25 GD
  0.271°.

``--acceptance COST`` runs the acceptance study instead (both modes on the same frames, the capture
range off; ``--seed`` its scene) with ``COST`` for every bone (:func:`acceptance_with`); ``--speed``
the tracking speed without and with the band (:func:`speed`).
"""

from __future__ import annotations

import platform
import re
import time
from dataclasses import replace

import numpy as np

from core.studies.tracking import _study_cli as cli

__all__ = ["COSTS", "VARIANTS", "acceptance_with", "long_axis", "run", "speed", "variant_frames"]

VARIANTS = ("trial", "norim", "fill", "band", "notissue", "alone", "exact")
COSTS = ("gc", "gc45", "gc60", "components", "band")
_BLACK = 0.005  # relative fluence at or below which a pixel is black (a quarter of the valid range's 0.02)


def long_axis(model) -> np.ndarray:
    """The bone's long axis in its CT frame: the first principal axis of its surface points."""
    from core.studies.tracking.acceptance import surface_points

    P = surface_points(model)
    P = P - P.mean(axis=0)
    return np.linalg.eigh(P.T @ P)[1][:, -1]


def _parts(ts, f: int) -> dict:
    """Line integrals of frame ``f`` (float64, per view): all, the tissue's, each bone's."""
    sr, sc = ts._scene_renderer, ts.scene
    P = sc.poses(f)
    Lb = sr._bones.render(P[None], roi="full").numpy()[0].astype(np.float64)  # (views, bones, H, W)
    Lt = sr._tissue.render(P[list(sc.tissue_bones)][None], roi="full").numpy()[0].sum(axis=1)
    return {"all": sc.line_integrals(f, renderer=sr).astype(np.float64), "tissue": Lt.astype(np.float64),
            "bones": Lb}


def _rng(ts, f: int, v: int, draw: int) -> np.random.Generator:
    """The noise generator of frame ``f``, view ``v``: the trial's own for ``draw`` 0, another
    independent one per ``draw`` > 0."""
    if draw == 0:
        return ts.scene.frame_rng(f, v)
    return np.random.default_rng([int(ts.scene.seed), 0x5CE4E, int(f), int(v), int(draw)])


def _chain(ts, L, noise: bool, f: int, *, aperture: bool = True, corrections=None,
           draw: int = 0) -> list[np.ndarray]:
    """The trial's chain on line integrals ``L``: flatfield-normalised, undistorted by
    ``corrections`` (the scene's by default); noise draw ``draw`` of frame ``f`` (0: the trial's
    own, :func:`_rng`) or none."""
    out = []
    for v, m in enumerate(ts.scene.imaging):
        if not noise:
            m = replace(m, photons_per_pixel=None, read_noise_dn=0.0)
        if not aperture:
            m = replace(m, aperture_radius=None)
        raw = m.apply(L[v], rng=_rng(ts, f, v, draw) if noise else None)
        out.append((corrections or ts.corrections)[v].unwarp(m.to_float(raw)).astype(np.float32))
    return out


def _black_distance(img: np.ndarray) -> np.ndarray:
    """Each pixel's Euclidean distance (px) to the nearest black pixel (inf where none)."""
    import cv2

    dark = img <= _BLACK
    if not dark.any():
        return np.full(img.shape, np.inf, np.float32)
    return cv2.distanceTransform((~dark).view(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5)


def _filled(images) -> tuple[list, list]:
    """The frames with their unusable pixels (as the tracker marks them) given the nearest usable
    pixel's value, and those usable masks."""
    from scipy import ndimage

    out, masks = [], []
    for img in images:
        x = np.asarray(img, np.float32)
        ok = ndimage.binary_erosion((x > 0.02) & (x < 0.999), iterations=3, border_value=1)
        idx = ndimage.distance_transform_edt(~ok, return_distances=False, return_indices=True)
        out.append(x[idx[0], idx[1]])
        masks.append(ok)
    return out, masks


def variant_frames(ts, f: int, name: str, noise: bool, parts: dict, band_px: float, exact=None,
                   draw: int = 0):
    """``(FrameImages, others_bones)`` of frame ``f`` taken apart as ``name`` (:data:`VARIANTS`),
    noise draw ``draw`` where ``noise``."""
    from core.tracking.cost import prepare_frame

    L = parts["all"]
    others = [1, 2]
    if name in ("trial", "fill", "band"):
        imgs = _chain(ts, L, noise, f, draw=draw)
    elif name == "norim":
        imgs = _chain(ts, L, noise, f, aperture=False, draw=draw)
    elif name == "notissue":
        imgs = _chain(ts, L - parts["tissue"], noise, f, draw=draw)
    elif name == "alone":
        imgs = _chain(ts, L - parts["bones"][:, 1] - parts["bones"][:, 2], noise, f, draw=draw)
        others = []
    elif name == "exact":
        imgs = _chain(ts, L, noise, f, corrections=exact, draw=draw)
    else:
        raise ValueError(f"variant: expected one of {VARIANTS}, got {name!r}")
    if name == "fill":
        imgs, masks = _filled(imgs)
        return prepare_frame(imgs, masks=masks, valid_range=None), others
    if name == "band":
        return prepare_frame(imgs, masks=[_black_distance(x) > band_px for x in imgs]), others
    return prepare_frame(imgs), others


def _options(cost: str):
    from core.tracking.cost import MetricTerm
    from core.tracking.options import TrackingOptions

    o = TrackingOptions().registration
    parts = cost.split("+")
    band, noise, tight = "band" in parts[1:], "noise" in parts[1:], "tight" in parts[1:]
    fine = "fine" in parts[1:]
    quad = "quad" in parts[1:] or fine
    base = "gc" if cost == "band" else parts[0]
    mixed = re.fullmatch(r"gc(ncc|gd|gi)(\d+)", base)
    smooth = {"fluoro_sigma_mm": 0.3, "drr_sigma_mm": 0.3}
    if base in ("gc", "gc45", "gc60", "components"):
        s = 0.3 if base in ("gc", "components") else int(base[2:]) / 100
        terms = (MetricTerm("gc", 1.0, {"fluoro_sigma_mm": s, "drr_sigma_mm": s,
                                        **({"components": True} if base == "components" else {})}),)
    elif base in ("ncc", "gd", "gi"):  # one term of that kind, both images smoothed by 0.3 mm
        terms = (MetricTerm(base, 1.0, smooth),)
    elif mixed:  # gc and w = NN/100 times the other kind (both smoothed by 0.3 mm)
        terms = (MetricTerm("gc", 1.0, smooth), MetricTerm(mixed[1], int(mixed[2]) / 100, smooth))
        quad = True  # the Gauss-Newton engine takes one term
    else:
        raise ValueError(f"cost: expected one of {COSTS}, 'ncc', 'gd', 'gi' or 'gcnccNN', 'gcgdNN', 'gcgiNN' "
                         f"(or one with '+band', '+noise', '+tight', '+quad', '+fine'), got {cost!r}")
    if band or cost == "band":
        terms = tuple(replace(t, options={**t.options, "rim_sigmas": 4.0}) for t in terms)
    o = replace(o, terms=terms, noise_correction=noise)  # (the option sets the gc term's flag)
    from core.tracking.register_options import FINAL_STEP, Level

    if quad:  # the quadratic-model search at full resolution on the (any-term) cost, to a 0.005 step
        # ('+fine': design half-widths 0.1 mm / 0.2 deg instead of FINAL_STEP's 0.25 / 0.5)
        o = replace(o, levels=(Level(scale=1.0, method="quadratic", sigma=(0.1, 0.2) if fine else FINAL_STEP,
                                     max_generations=12, tol_x=0.005, options={"tol_noise": 1e-3}),))
    elif tight:  # the full-resolution Gauss-Newton steps run until a step is below 0.002 (mm, degrees)
        o = replace(o, levels=(Level(scale=1.0, method="gauss_newton", sigma=FINAL_STEP, max_generations=16,
                                     tol_x=0.002, options={"tol_noise": 1e-4}),))
    return o


def _rim_pixels(ts, frame_imgs, truth, roi, band_px: float) -> list[int]:
    """Per view: the tibia's usable pixels (its DRR > 0 at the truth, inside ``roi``) within
    ``band_px`` of a black pixel."""
    out = []
    drr = ts.renderer.render(truth[0][None, None], views=(0, 1), bones=[0], roi=roi[None, :, None, :]).numpy()
    for v, img in enumerate(frame_imgs):
        u0, v0, w, h = (int(a) for a in roi[v])
        sup = drr[0, v, 0, :h, :w] > 0
        d = _black_distance(img)[v0:v0 + h, u0:u0 + w]
        ok = (img[v0:v0 + h, u0:u0 + w] > 0.02)
        out.append(int(np.sum(sup & ok & (d <= band_px))))
    return out


def _rms(E) -> float:
    E = np.asarray(E, float).reshape(-1, 3)
    return float(np.sqrt(np.mean(np.sum(E**2, axis=1))))


def _summary(rows: list, ref: list | None, bound: dict) -> dict:
    E = np.array([r["error"] for r in rows])
    la = np.array([r["long_axis_deg"] for r in rows])
    out = {"rms_mm": round(_rms(E[:, :3]), 5), "rms_deg": round(_rms(E[:, 3:]), 5),
           "long_axis_mean_deg": round(float(la.mean()), 5),
           "long_axis_rms_deg": round(float(np.sqrt(np.mean(la**2))), 5)}
    fr = np.array([r["frame"] for r in rows])
    if len(fr) > len(set(fr.tolist())):  # several noise draws per frame: the spread and the bias
        mean = {f: la[fr == f].mean() for f in set(fr.tolist())}
        dev = la - [mean[f] for f in fr]  # (the standard deviation over the draws, n - 1 per frame)
        out["long_axis_spread_deg"] = round(float(np.sqrt(np.sum(dev**2) / (len(fr) - len(mean)))), 5)
        out["long_axis_bias_rms_deg"] = round(float(np.sqrt(np.mean(np.square(list(mean.values()))))), 5)
        out["draws"] = int(len(fr) // len(mean))
    if bound:
        out["over_bound"] = [round(out["rms_mm"] / bound["rms_mm"], 3),
                             round(out["rms_deg"] / bound["rms_deg"], 3)]
    if ref is not None:
        D = E - np.array([r["error"] for r in ref])
        out["move_from_trial_mm"] = round(_rms(D[:, :3]), 5)
        out["move_from_trial_deg"] = round(_rms(D[:, 3:]), 5)
        out["long_axis_move_rms_deg"] = round(float(np.sqrt(np.mean(
            (la - np.array([r["long_axis_deg"] for r in ref])) ** 2))), 5)
    return out


def run(*, pixels: int = 1024, voxel: float = 1.0, frames=(0, 20, 40, 60, 81), variants=VARIANTS,
        costs=("gc", "gc45", "gc60", "components", "band"), cost_variants=("trial",),
        noises=("free", "noisy"), band_px: float | None = None, device: str | None = "cpu",
        correction: str = "grid", start_deg: float = 0.0, draws: int = 1, checkpoint=None) -> dict:
    """The study (module docs). ``band_px`` None: 4 σ of the default smoothing plus 2 px.
    ``start_deg``: each registration starts from the true pose turned by this much about the
    tibia's long axis (about its centroid) instead of the true pose (the search's share).
    ``draws``: noise draws per noisy frame (the trial's own, then independent ones)."""
    from core.geometry.transforms import pose_from_params
    from core.studies.tracking.acceptance import TrackingScene, cramer_rao, pose_errors
    from core.studies.tracking.grid_correction import model_corrections
    from core.tracking.cost import mm_per_pixel, rim_radius
    from core.tracking.register import register, search_region

    t0 = time.perf_counter()
    ts = TrackingScene(n_frames=100, pixels=pixels, spacing=voxel, device=device, correction=correction)
    exact = model_corrections(ts.scene, 0.0) if "exact" in variants else None
    frames = [int(f) for f in frames]
    m = ts.models[0]
    axis = long_axis(m)
    px_mm = mm_per_pixel(ts.renderer, ts.truth(frames[0])[0], m.centroid)
    if band_px is None:
        band_px = rim_radius(4.0, 0.3 / px_mm)
    bound = cramer_rao(ts, frames).get("tibia", {})
    out = {"study": "core.studies.tracking.tibia_cost", "machine": platform.machine(), "device": str(device),
           "pixels": pixels, "voxel_mm": voxel, "correction": correction, "frames": frames,
           "px_mm_at_bone": round(px_mm, 5), "band_px": band_px, "start_deg": start_deg,
           "long_axis_ct": axis.round(4).tolist(),
           "cramer_rao": {k: bound[k] for k in ("rms_mm", "rms_deg", "sigma") if k in bound},
           "rim": {}, "per_frame": {}, "results": {}}
    jobs = [(v, "gc") for v in variants] + [(v, c) for v in cost_variants for c in costs if c != "gc"]
    rows: dict = {}
    for f in frames:
        parts = _parts(ts, f)
        truth = ts.truth(f)
        lab_axis = truth[0][:3, :3] @ axis
        start = pose_from_params(np.r_[0.0, 0.0, 0.0, np.radians(start_deg) * lab_axis], center=m.centroid,
                                 base=truth[0])
        roi = search_region(ts.renderer, truth[0], 0, views=(0, 1), center=m.centroid,
                            options=_options("gc"), outline=m.outline)
        for noise, draw in [(n, d) for n in noises for d in (range(draws) if n == "noisy" else (0,))]:
            made: dict = {}
            for v, c in jobs:
                if v not in made:
                    made[v] = variant_frames(ts, f, v, noise == "noisy", parts, band_px, exact, draw)
                    if v == "trial" and draw == 0:
                        out["rim"].setdefault(noise, {})[str(f)] = _rim_pixels(
                            ts, [made[v][0]._fluence[k] for k in (0, 1)], truth, roi, band_px)
                frame, oth = made[v]
                r = register(ts.renderer, frame, bone=0, initial_pose=start, center=m.centroid,
                             options=_options(c), others=(truth[oth], oth) if oth else None,
                             outline=m.outline, roi=roi)
                e = pose_errors(r.pose, truth[0], m.centroid)
                rows.setdefault((v, c, noise), []).append(
                    {"frame": f, "draw": draw, "error": e.round(6).tolist(), "converged": bool(r.converged),
                     "long_axis_deg": round(float(e[3:] @ lab_axis), 6)})
        res: dict = {}
        for (v, c, noise), rr in rows.items():
            ref = rows.get(("trial", "gc", noise))
            res[f"{v}/{c}/{noise}"] = _summary(rr, None if (v, c) == ("trial", "gc") else ref,
                                               bound if noise == "noisy" else {})
            out["per_frame"][f"{v}/{c}/{noise}"] = rr
        out["results"] = res
        out["frames_done"] = f
        out["seconds"] = round(time.perf_counter() - t0, 1)
        print(f"frame {f} {out['seconds']:.0f} s", flush=True)
        for k, s in res.items():
            mv = (f"  move {s['move_from_trial_mm']:.4f} mm {s['move_from_trial_deg']:.4f} deg "
                  f"(long {s['long_axis_move_rms_deg']:.4f})" if "move_from_trial_mm" in s else "")
            print(f"  {k:28s} {s['rms_mm']:.4f} mm {s['rms_deg']:.4f} deg  long axis "
                  f"{s['long_axis_mean_deg']:+.4f}{mv}", flush=True)
        if checkpoint:
            checkpoint(out)
    return out


def acceptance_with(cost: str, *, modes=("joint", "sequential"), seed: int = 0, quick: bool = False,
                    n_frames: int | None = None, workers: int = 0, capture_trials: int | None = 0,
                    device: str | None = None) -> dict:
    """The acceptance study (:func:`core.studies.tracking.acceptance.run`, its scene and frames,
    ``modes`` in turn on the same frames) with the registration's cost ``cost`` (a name of
    :data:`COSTS`, ``+band`` allowed) for every bone instead of the default's, and the scene of
    ``seed``; the capture range off unless ``capture_trials``."""
    import core.studies.tracking.acceptance as acc
    from core.studies.tracking.acceptance_goals import compare_modes

    terms = _options(cost).terms
    base = acc.study_options

    def options(*a, **k):
        o = base(*a, **k)
        return replace(o, registration=replace(o.registration, terms=terms))

    t0 = time.perf_counter()
    ts = acc.tracking_scene(quick=quick, device=device, seed=seed, n_frames=n_frames)
    out = {"study": "core.studies.tracking.tibia_cost (acceptance)", "cost": cost, "seed": seed,
           "terms": [t.to_dict() for t in terms], "modes": list(modes), "scene_s": time.perf_counter() - t0,
           "runs": {}}
    acc.study_options = options
    try:
        for k, m in enumerate(modes):
            out["runs"][m] = acc.run(capture_trials=capture_trials if k == 0 else 0, mode=m, ts=ts,
                                     workers=workers, device=device)
    finally:
        acc.study_options = base
    if len(modes) > 1:
        out["joint_vs_sequential"] = compare_modes(out["runs"])
    return out


def speed(costs=("gc", "band", "gc", "band"), cases=((0,), (0, 1, 2)), *, frames: int = 100,
          repeats: int = 3, workers: int = 0, device: str | None = None) -> dict:
    """The tracking speed with each cost of ``costs`` in turn (alternating: the host's speed drifts)
    for each bone set of ``cases`` (joint tracking), on the benchmark's scene (1024², 0.5 mm, the 3 %
    model correction; :func:`core.studies.tracking.benchmark._case`: end to end, the median of
    ``repeats``, and a profiled run)."""
    from core.studies.tracking.acceptance import TrackingScene
    from core.studies.tracking.benchmark import _case
    from core.studies.tracking.trial_frames import synthesise
    from core.tracking.trial import TrackingOptions

    ts = TrackingScene(n_frames=frames, pixels=1024, spacing=0.5, phase=(0.0, 0.6 * frames / 100.0),
                       device=device)
    synthesise(ts, range(frames), workers=workers)
    base = TrackingOptions(mode="joint")
    out: dict = {"frames": frames, "order": list(costs), "cases": {}}
    for bones in cases:
        key = "+".join(ts.names[b] for b in bones)
        for k, c in enumerate(costs):
            o = replace(base, registration=replace(base.registration, terms=_options(c).terms))
            out["cases"].setdefault(key, {})[f"{k}_{c}"] = _case(ts, list(bones), o, frames, repeats)
    return out


def main(argv=None) -> int:
    p = cli.parser("core.studies.tracking.tibia_cost", __doc__)
    p.add_argument("--pixels", type=int, default=1024)
    p.add_argument("--voxel", type=float, default=1.0)
    p.add_argument("--frames", default="0,20,40,60,81")
    p.add_argument("--variants", default=",".join(VARIANTS))
    p.add_argument("--costs", default="gc,gc45,gc60,components,band")
    p.add_argument("--cost-variants", default="trial")
    p.add_argument("--noises", default="free,noisy")
    p.add_argument("--band-px", type=float, default=None)
    p.add_argument("--correction", default="grid")
    p.add_argument("--start-deg", type=float, default=0.0,
                   help="start each registration turned by this much about the tibia's long axis")
    p.add_argument("--draws", type=int, default=1, help="noise draws per noisy frame (the trial's own first)")
    p.add_argument("--device", default="cpu", help="Warp device (auto: CUDA where present)")
    cli.add_machine_name(p)
    p.add_argument("--acceptance", default=None, metavar="COST",
                   help="instead: the acceptance study (both modes) with this cost for every bone")
    p.add_argument("--seed", type=int, default=0, help="--acceptance: the scene's seed")
    p.add_argument("--quick", action="store_true", help="--acceptance: the quick size (256², 20 frames)")
    p.add_argument("--workers", type=int, default=0, help="--acceptance: processes for the image chain")
    p.add_argument("--speed", action="store_true", help="instead: tracking speed without and with the band")
    cli.add_output(p, machine_name=False)
    a = p.parse_args(argv)
    device = None if a.device == "auto" else a.device
    if a.speed:
        return cli.finish(speed(workers=a.workers, device=device), a)
    if a.acceptance:
        return cli.finish(acceptance_with(a.acceptance, seed=a.seed, quick=a.quick, workers=a.workers,
                                          device=device), a)

    def split(s):
        return tuple(cli.names(s))

    res = run(pixels=a.pixels, voxel=a.voxel, frames=cli.ints(a.frames), variants=split(a.variants),
              costs=split(a.costs), cost_variants=split(a.cost_variants), noises=split(a.noises),
              band_px=a.band_px, device=a.device, correction=a.correction, start_deg=a.start_deg,
              draws=a.draws, checkpoint=cli.checkpoint(a))
    return cli.finish(res, a)


if __name__ == "__main__":
    raise SystemExit(main())
