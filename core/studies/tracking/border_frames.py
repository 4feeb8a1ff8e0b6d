"""What the edge of the usable image costs the tibia under the likelihood final stage
(``python -m core.studies.tracking.border_frames``).

The trial's views (:func:`core.synthetic.make_foot_scene`) have the intensifier's round field
(``aperture_radius`` 1.0): outside it the frames are black, and
:func:`core.tracking.cost.prepare_frame` marks black pixels and 3 px around them unusable
(``TrackingOptions.erode_px``). The final stage's high-pass (a Gaussian of σ 4 px at 1024²,
truncated at 4 σ) blurs the line integrals of the whole region, unusable pixels included, and
those hold ``-log(1/4096) = 8.3`` against the bones' and tissue's 1-3: the step at the field's rim
spreads into the usable pixels over about 3 σ, hundreds of times the bone's own high-passed signal.
Only the tibia reaches the rim (at 1024², of its voxels' projections within the field 1.0 % lie
within 15 px of the rim and 1.9 % within 27 px on average over frames 0-90, up to 2.4 % and 4.5 %;
none of the talus's or calcaneus's).

Here the tibia's final stage (:func:`core.tracking.final_stage._refine` with the trial's stage
model, the other bones at their TRUE poses subtracted) starts from the TRUE pose of frames
``--frames`` with the exact distortion model (no calibration error), on the same frames
(``--kinds``: ``replicate`` the trial's; ``black`` the undistortion's border black instead of
replicated, as :class:`core.imaging.pipeline.UndistortStep` leaves it; ``undistorted`` the chain
without distortion) prepared three ways (:func:`prepared`, ``--preps``): ``trial`` as the tracker
does it; ``fill`` the same usable pixels, the unusable ones given the nearest usable pixel's value
(no step for the high-pass to spread); ``erode`` the unusable band grown to 3 σ of the high-pass.
Per preparation and high-pass σ: the RMS error over the frames' Cramér–Rao bound
(:func:`core.studies.tracking.acceptance.cramer_rao`), the mean error, and the stage's sandwich σ
over the bound (its confidence; large where the residual is structured); ``--noise-free``: on
noise-free frames (the stage's bias). ``field_bound``: the bound over the frame's usable pixels
against all pixels of the bone's region (what :func:`~core.studies.tracking.acceptance.cramer_rao`
counts). Study only: it reads the truth. JSON on stdout (and ``--out``).

Measured on this 2-core CPU machine (``resources/benchmarks/tracking_border_frames_cpu.json``;
512², 1 mm voxels, so the trial's 4 and 8 px are 2 and 4 px here; × the bound mm / °):

* the step is the tibia's structured residual: the stage's sandwich σ is 3.3 / 1.5× the bound at
  4 px and 13.4 / 7.5× at 8 px (noisy frames), 1.5 / 0.8× and 2.8 / 1.8× with ``fill`` or
  ``erode`` (on one NVIDIA H200 the tracked tibia's σ was 7× the bound in mm at 4 px, 17× at 8 px,
  ``tracking_exact_correction_h200.json``);
* at 8 px it biases the tibia: noise-free 1.06 / 0.57 (``trial``) against 0.83 / 0.41 (``fill``)
  and 0.67 / 0.36 (``erode``); noisy (10 frames, 0-90) 1.78 / 1.55 against 1.59 / 1.42 and
  1.52 / 1.47, paired 0.89 (95 % 0.77-0.99) and 0.85 (0.72-0.96) of the ``trial`` RMS in mm;
* at 4 px (the stage's default) it costs little: noisy 1.83 / 1.60 against 1.74 / 1.59 and
  1.81 / 1.60 (paired intervals include no change); the noise-free bias stays 0.57-0.59× in mm
  with any preparation (the tissue, blur and glare of the chain, not the rim);
* with the step gone the wider high-pass is the better one for the tibia (8 px 1.52-1.59 against
  4 px 1.74-1.83 in mm), as the noise-only spreads of the two high-passes say
  (:func:`core.studies.tracking.bound_gap.wls_spread` at 1024²: 1.16 / 1.21 against 1.41 / 1.36);
* the bound is not what is off: over the usable pixels only, the tibia's bound is 1.008 / 1.007×
  the bound over all pixels of its region (talus 1.002 / 1.003, calcaneus 1.001 / 1.000).

So the tibia sits at ~1.5× in tracking at 4 px because that high-pass's noise-only spread is
1.41 / 1.36× and its chain bias 0.57× (√(1.41² + 0.57²) = 1.52), not because of the distortion
correction; the wider high-pass that would lower the spread lets the rim's step in. The exact
correction leaves it where the grid correction does (``ml_cost --correction grid,exact``).
``ml_cost --final --erode-px`` measures the tracked trial with the wider unusable band
(``TrackingOptions.erode_px``: 12 px for 4 px, 24 px for 8 px at 1024², as ``erode``); not yet run on a GPU.
"""

from __future__ import annotations

import argparse
import platform
import time
from dataclasses import replace

import numpy as np

__all__ = ["KINDS", "PREPS", "field_bound", "frame_images", "main", "prepared", "run"]

#: How the frames are made (module docs).
KINDS = ("replicate", "black", "undistorted")
#: How the frames are prepared for the tracker (:func:`prepared`).
PREPS = ("trial", "fill", "erode")


def frame_images(ts, f: int, kind: str, *, noise: bool = True, L=None) -> list[np.ndarray]:
    """Frame ``f`` of ``ts`` (flatfield-normalised, per view) made as ``kind`` (:data:`KINDS`) with
    the exact distortion model; ``noise``: the trial's draws (``scene.frame_rng``), else none."""
    import cv2

    from core.synthetic import Distortion

    if kind not in KINDS:
        raise ValueError(f"kind: expected one of {KINDS}, got {kind!r}")
    sc = ts.scene
    L = sc.line_integrals(f, renderer=ts._scene_renderer) if L is None else L
    out = []
    for v, m in enumerate(sc.imaging):
        if not noise:
            m = replace(m, photons_per_pixel=None, read_noise_dn=0.0)
        if kind == "undistorted":
            m = replace(m, distortion=None)
        raw = m.apply(L[v], rng=sc.frame_rng(f, v) if noise else None)
        x = m.to_float(raw)
        if kind != "undistorted":
            d = m.distortion
            assert isinstance(d, Distortion)
            x = d.unwarp(x, border=cv2.BORDER_REPLICATE if kind == "replicate" else cv2.BORDER_CONSTANT)
        out.append(x)
    return out


def prepared(images, prep: str, highpass_px: float):
    """:func:`core.tracking.cost.prepare_frame` of ``images`` as ``prep`` (:data:`PREPS`): ``trial``
    as the tracker does it (black and saturated pixels and 3 px around them unusable); ``fill``
    the same usable pixels, but the unusable ones given the nearest usable pixel's value first
    (no step at the field's rim for the stage's high-pass to spread); ``erode`` the unusable
    pixels grown by 3 σ of the stage's high-pass (``highpass_px``) instead of 3 px."""
    from scipy import ndimage

    from core.tracking.cost import prepare_frame

    if prep not in PREPS:
        raise ValueError(f"prep: expected one of {PREPS}, got {prep!r}")
    if prep == "trial":
        return prepare_frame(images)
    if prep == "erode":
        return prepare_frame(images, erode_px=int(np.ceil(3 * highpass_px)))
    out, masks = [], []
    for img in images:
        x = np.asarray(img, np.float32)
        ok = (x > 0.02) & (x < 0.999)
        masks.append(ndimage.binary_erosion(ok, iterations=3, border_value=1))
        idx = ndimage.distance_transform_edt(~masks[-1], return_distances=False, return_indices=True)
        out.append(x[idx[0], idx[1]])
    return prepare_frame(out, masks=masks, valid_range=None)


def field_bound(ts, frames, images) -> dict:
    """Per bone the Cramér–Rao bound (mean covariance over ``frames``, as
    :func:`core.studies.tracking.acceptance.cramer_rao`) over all pixels of the bone's region
    (``all``: what the trial's bound counts) and over the usable pixels of the frame only
    (``field``: ``images(f)`` prepared as the tracker does; the pixels outside the intensifier's
    round field hold no quanta), and their ratio."""
    from core.tracking.bound import _derivatives

    N = [m.photons_per_pixel for m in ts.scene.imaging]
    acc: dict = {}
    for f in frames:
        L = ts.scene.line_integrals(f, renderer=ts._scene_renderer)
        frame = prepared(images(f, L), "trial", 0.0)
        for b, nm in enumerate(ts.names):
            _, Nv, D = _derivatives(ts.renderer, b, ts.truth(f)[b], ts.models[b].centroid, line_integral=L,
                                    quanta_per_pixel=N, views=None, step=(0.1, 0.1), margin_px=6)
            J = {"all": np.zeros((6, 6)), "field": np.zeros((6, 6))}
            for v, (u0, v0, w, h), Dv, Lv in D:
                q = Nv[v] * np.exp(-Lv)
                _, m = frame.region(v, slice(v0, v0 + h), slice(u0, u0 + w))
                G = Dv.reshape(6, -1)
                J["all"] += (G * q.ravel()) @ G.T
                J["field"] += (G * (q * (np.ones_like(q, bool) if m is None else m)).ravel()) @ G.T
            for k, Jk in J.items():
                acc.setdefault(nm, {}).setdefault(k, []).append(np.linalg.inv(Jk))
    out = {}
    for nm, d in acc.items():
        row = {}
        for k, cs in d.items():
            C = np.mean(cs, axis=0)
            row[k] = {"rms_mm": float(np.sqrt(np.trace(C[:3, :3]))),
                      "rms_deg": float(np.sqrt(np.trace(C[3:, 3:])))}
        row["field_over_all"] = [round(row["field"][u] / row["all"][u], 4) for u in ("rms_mm", "rms_deg")]
        out[nm] = row
    return out


def _stage(ts, frame, f: int, b: int, highpass_px: float,
           rim: float | None = None) -> tuple[np.ndarray, np.ndarray, int]:
    """Bone ``b``'s final stage from its true pose in frame ``f`` (the neighbours at theirs
    subtracted), with the band at the round field's rim of ``rim`` σ (None: none;
    :mod:`core.studies.tracking.rim_band`): its error (6,) (mm, degrees), its sandwich covariance's
    σ (6,) (mm, degrees) and the usable pixels the band took."""
    import core.tracking.final_stage as fst
    from core.studies.tracking.acceptance import pose_errors
    from core.studies.tracking.stage_limits import Variant
    from core.tracking.cost import search_roi, snap_roi
    from core.tracking.likelihood_rim import apply_rim, rim_keep

    P = ts.truth(f)
    m = ts.models[b]
    with Variant({"hp": float(highpass_px)}, ts) as var:
        o = var.options.registration
        views = tuple(range(len(ts.scene.rig)))
        roi = snap_roi(search_roi(ts.renderer, P[b], b, views=views, center=m.centroid, reach_mm=1.0,
                                  margin_px=o.margin_px), ts.renderer, views)
        oth = [k for k in range(len(ts.names)) if k != b]
        eng = fst.likelihood_engine(ts.renderer, bone=b, views=views, highpass_px=o.final_highpass_px,
                                    others_gain=o.final_others_gain)
        eng.set_frame(frame, base_pose=P[b], center=m.centroid, roi=roi,
                      others=(P[oth], oth) if oth else None)
        cut = 0
        if rim:
            keep = rim_keep(frame, views, roi, rim * highpass_px, eng._cap)
            cut = 0 if keep is None else int(np.count_nonzero((keep == 0) & (eng._w.numpy() > 0)))
            apply_rim(eng, frame, rim * highpass_px)
        r = fst._refine(eng, o, fst.MODEL)
    e = pose_errors(eng.poses(np.asarray(r["x"])[None])[0], P[b], m.centroid)
    C = np.asarray(r.get("covariance", np.full((6, 6), np.nan)), float)
    return e, np.sqrt(np.abs(np.diag(C))), cut  # (the stage's parameters: mm, degrees)


def run(*, pixels: int = 512, voxel: float = 1.0, frames=(0, 20, 40, 60, 80), bones=("tibia",),
        highpass=(2.0, 4.0), kinds=("replicate",), preps=PREPS, noise: bool = True,
        device: str | None = "cpu", checkpoint=None) -> dict:
    """The study (module docs); ``highpass``: the stage's σ in px at ``pixels`` (2 and 4 px at 512²
    are the trial's 4 and 8 px at 1024²)."""
    from core.studies.tracking.acceptance import TrackingScene, cramer_rao

    t0 = time.perf_counter()
    ts = TrackingScene(n_frames=100, pixels=pixels, spacing=voxel, device=device, correction="exact")
    frames = [int(f) for f in frames]
    bound = cramer_rao(ts, frames)
    out = {"study": "core.studies.tracking.border_frames", "machine": platform.machine(), "pixels": pixels,
           "voxel_mm": voxel, "frames": frames, "noise": noise, "highpass_px": list(highpass),
           "cramer_rao": {k: {"rms_mm": v["rms_mm"], "rms_deg": v["rms_deg"]} for k, v in bound.items()},
           "field_bound": field_bound(ts, frames,
                                      lambda f, L: frame_images(ts, f, "replicate", noise=False, L=L)),
           "setup_s": time.perf_counter() - t0}
    if checkpoint:
        checkpoint(out)
    rec: dict = {}
    for f in frames:
        L = ts.scene.line_integrals(f, renderer=ts._scene_renderer)
        for kind in kinds:
            imgs = frame_images(ts, f, kind, noise=noise, L=L)
            for hp in highpass:
                for prep in preps:
                    frame = prepared(imgs, prep, hp)
                    for nm in bones:
                        e, sg, _ = _stage(ts, frame, f, ts.names.index(nm), hp)
                        rec.setdefault((f"{kind}/{prep}", hp, nm), []).append((e, sg))
        out["seconds"] = time.perf_counter() - t0
        out["results"] = _summaries(rec, bound)
        out["frames_done"] = f
        if checkpoint:
            checkpoint(out)
    return out


def _summaries(rec: dict, bound: dict) -> dict:
    out: dict = {}
    for (kind, hp, nm), rows in rec.items():
        E = np.array([r[0] for r in rows])
        S = np.array([r[1] for r in rows])
        b = bound[nm]
        rt, rr = np.sqrt(np.mean(np.sum(E[:, :3] ** 2, 1))), np.sqrt(np.mean(np.sum(E[:, 3:] ** 2, 1)))
        st = np.sqrt(np.nanmean(np.sum(S[:, :3] ** 2, 1)))
        sr = np.sqrt(np.nanmean(np.sum(S[:, 3:] ** 2, 1)))
        out.setdefault(kind, {}).setdefault(f"hp{hp:g}", {})[nm] = {
            "over_bound": [round(rt / b["rms_mm"], 3), round(rr / b["rms_deg"], 3)],
            "sandwich_sigma_over_bound": [round(st / b["rms_mm"], 3), round(sr / b["rms_deg"], 3)],
            "mean_error": E.mean(0).round(5).tolist(), "per_frame_error": E.round(5).tolist(), "n": len(E)}
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.border_frames",
                                description=__doc__.split("\n")[0])
    p.add_argument("--pixels", type=int, default=512)
    p.add_argument("--voxel", type=float, default=1.0)
    p.add_argument("--frames", default="0,20,40,60,80")
    p.add_argument("--bones", default="tibia")
    p.add_argument("--highpass", default="2,4", help="the stage's high-pass σ (px at --pixels)")
    p.add_argument("--kinds", default="replicate", help=f"frames made as: {', '.join(KINDS)}")
    p.add_argument("--preps", default=",".join(PREPS), help=f"frames prepared as: {', '.join(PREPS)}")
    p.add_argument("--noise-free", action="store_true")
    p.add_argument("--device", default="cpu")
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    from core.io.atomic import json_checkpoint, print_json

    checkpoint = json_checkpoint(a.out, indent=2)

    kinds = tuple(k for k in a.kinds.split(",") if k)
    preps = tuple(k for k in a.preps.split(",") if k)
    if any(k not in KINDS for k in kinds) or any(k not in PREPS for k in preps):
        p.error(f"--kinds, --preps: expected some of {', '.join(KINDS)} and of {', '.join(PREPS)}")
    res = run(pixels=a.pixels, voxel=a.voxel, frames=[int(x) for x in a.frames.split(",") if x],
              bones=tuple(a.bones.split(",")), highpass=[float(x) for x in a.highpass.split(",") if x],
              kinds=kinds, preps=preps, noise=not a.noise_free, device=a.device, checkpoint=checkpoint)
    print_json(res, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
