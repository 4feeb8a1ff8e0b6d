"""Self-calibration of the residual distortion from the tracked trial
(``python -m core.studies.tracking.self_calibration``).

The acceptance trial (:class:`core.studies.tracking.acceptance.TrackingScene`) undistorts its
frames with a 3 %-wrong inverse, leaving a smooth residual warp that the poses absorb. This study
tracks the trial (joint mode, Gauss–Newton search; case ``final``: with the weighted
least-squares final stage, ``TrackingOptions.refine_likelihood``), estimates each view's residual
warp from the frames and the tracked poses only (:func:`core.tracking.residual_warp.
refine_residual_warp`, a generic polynomial field of ``--order``, not the generator's form) and
tracks the re-warped frames again. Only this study reads the truth:

* the estimated field against the true residual ``C⁻¹(D(x)) - x`` (``C`` the trial's inverse,
  ``D`` the true distortion), RMS in pixels of the truth, the estimate, their difference and the
  difference without its best affine part (what a motion of the rig can absorb and the images do
  not determine): over the round field (``field``) and over the pixels the bones cover
  (``field_over_bones``, :func:`footprints`; ``--recompare`` redoes both for a results file);
* per bone, per-frame RMS errors (mm, °) of the first run, of the poses moved by the fit's pose
  changes (``fitted``, estimated frames only) and of the re-tracked run, over the Cramér–Rao bound
  (:func:`core.studies.tracking.acceptance.cramer_rao`, every tenth frame); lag-1
  autocorrelation of the translation errors (smooth errors are the warp's signature);
* case ``truth``: the estimator alone from the true poses, with the field held at zero
  (``poses_only``: the image model's own pose bias) and with the field;
* cases ``oracle_plain`` / ``oracle_final``: the trial tracked on frames with the TRUE residual
  removed (:class:`TrueWarp`): the most any self-calibration could give.

Measured (``resources/benchmarks/tracking_self_calibration_*.json``): negative. The estimator's
pixel model (bone DRRs against band-passed line integrals) leaves out the skin's and walkway's
edges; even with robust weights its poses from the truth are 0.9-1.5× the bound at 1024² (one
H200) and its field fits that mismatch: 0.22-0.26 px off over the bones against a true field of
0.17-0.21 px, and re-tracking on it did not lower the tibia's error.

What a perfect correction would give at 1024² (``oracle_final``'s frames, measured by
:mod:`core.studies.tracking.stage_limits`, one NVIDIA H200, 100 frames, three bones jointly with
the final stage): tibia 2.16/1.46 → 1.52/1.39× its bound (mm/°), talus 1.39/1.31 → 1.38/1.29,
calcaneus 1.90/1.40 → 1.19/1.33, the tibia's two silent frames gone. The distortion fitted to grid
frames (``TrackingScene(correction="grid")``, ``tracking_grid_correction_h200.json``: 1.50/1.42,
1.38/1.31, 1.20/1.36) is within 0.03 of it: there is nothing left for a self-calibration to take.

Sizes: ``--pixels`` / ``--voxel`` / ``--frames`` (default 256², 1 mm, 20 frames: this 2-core CPU).
JSON to stdout and ``--out`` (rewritten after each case).
"""

from __future__ import annotations

import argparse
import platform
import time
from dataclasses import replace

import numpy as np

__all__ = ["TrueWarp", "field_comparison", "footprints", "main", "recompare", "run", "true_field"]


def true_field(ts, view: int, uv: np.ndarray) -> np.ndarray:
    """The trial's residual warp in ``view`` at ``uv``: where the corrected frame shows the content
    that belongs at ``uv`` (minus ``uv``)."""
    m, c = ts.scene.imaging[view], ts.corrections[view]
    return c.inverse(m.distortion.forward(uv)) - uv


def footprints(ts, frames) -> list[np.ndarray]:
    """Per view the pixels that some tracked bone covers in ``frames`` (true poses): where the
    field acts on the registrations."""
    out = []
    for v, cam in enumerate(ts.scene.rig):
        m = np.zeros((cam.height, cam.width), bool)
        for f in frames:
            m |= ts.renderer.render_full(ts.truth(f), v) > 0
        out.append(m)
    return out


def field_comparison(ts, warp, step: int = 4, masks=None) -> list[dict]:
    """Per view: RMS (px) of the true field, the estimate, their difference, the difference
    without its least-squares affine part, over the round field (r < 0.95 of the distortion's
    radius) or, with ``masks`` (per view, e.g. :func:`footprints`), over those pixels."""
    out = []
    for v, cam in enumerate(ts.scene.rig):
        d = ts.scene.imaging[v].distortion
        if masks is None:
            vv, uu = np.mgrid[0:cam.height:step, 0:cam.width:step]
            uv = np.stack([uu.ravel(), vv.ravel()], axis=1).astype(float)
            uv = uv[np.hypot(uv[:, 0] - d.center[0], uv[:, 1] - d.center[1]) < 0.95 * d.scale_px]
        else:
            vv, uu = np.nonzero(masks[v])
            uv = np.stack([uu, vv], axis=1).astype(float)[::max(1, step // 2)]
        g, e = true_field(ts, v, uv), warp.displacement(v, uv)
        diff = e - g
        A = np.column_stack([np.ones(len(uv)), uv - uv.mean(0)])
        diff_na = diff - A @ np.linalg.lstsq(A, diff, rcond=None)[0]
        g_na = g - A @ np.linalg.lstsq(A, g, rcond=None)[0]
        _, depth = cam.project(np.zeros((1, 3)), return_depth=True)
        mm = float(depth[0]) / cam.fx

        def rms(x):
            return float(np.sqrt(np.mean(np.sum(x**2, axis=1))))

        out.append({"true_rms_px": rms(g), "estimate_rms_px": rms(e), "difference_rms_px": rms(diff),
                    "true_non_affine_rms_px": rms(g_na), "difference_non_affine_rms_px": rms(diff_na),
                    "relative_error": rms(diff) / rms(g),
                    "relative_error_non_affine": rms(diff_na) / rms(g_na), "mm_per_px_at_isocentre": mm})
    return out


def _errors(ts, poses: dict, frames) -> dict:
    from core.studies.tracking.acceptance import pose_errors

    out = {}
    for b, (nm, m) in enumerate(zip(ts.names, ts.models, strict=True)):
        E = np.array([pose_errors(poses[(nm, f)], ts.truth(f)[b], m.centroid)
                      if poses.get((nm, f)) is not None else np.full(6, np.nan) for f in frames])
        out[nm] = E
    return out


def _summary(E: np.ndarray, bound: dict | None) -> dict:
    ok = np.all(np.isfinite(E), axis=1)
    E = E[ok]
    et, er = np.linalg.norm(E[:, :3], axis=1), np.linalg.norm(E[:, 3:], axis=1)
    s = {"rms_mm": float(np.sqrt(np.mean(et**2))), "rms_deg": float(np.sqrt(np.mean(er**2))),
         "mean_error": E.mean(0).round(4).tolist(), "std_error": E.std(0).round(4).tolist(),
         "missing": int((~ok).sum())}
    if len(E) > 2:
        ac = []
        for k in range(3):
            x = E[:, k] - E[:, k].mean()
            ac.append(float(np.sum(x[1:] * x[:-1]) / max(np.sum(x * x), 1e-30)))
        s["lag1_autocorrelation_mm"] = np.round(ac, 3).tolist()
    if bound:
        s["over_bound"] = {"mm": s["rms_mm"] / bound["rms_mm"], "deg": s["rms_deg"] / bound["rms_deg"]}
    return s


def _truth_case(ts, bound, fl, kw) -> dict:
    """The estimator alone from the true poses: the poses only (the field held at zero), then with
    the field."""
    from core.tracking.residual_warp import estimate_residual_warp

    poses = {(nm, f): ts.truth(f)[b] for b, nm in enumerate(ts.names) for f in fl}
    out = {}
    only = {"ridge": 1e9, "ridge_low": 1e9, "iterations": 1}
    for label, extra in (("poses_only", only), ("with_field", {})):
        est = estimate_residual_warp(ts.renderer, ts.models, ts.frames, poses, frame_list=fl,
                                     **{**kw, **extra})
        out[label] = {"estimate": est.to_dict(), "field": field_comparison(ts, est.warp),
                      "field_over_bones": field_comparison(ts, est.warp, masks=_FOOT[0]),
                      "fitted": {nm: _summary(E, bound.get(nm))
                                 for nm, E in _errors(ts, est.poses, fl).items()}}
    return out


def _track_case(ts, bound, fl, o, every: int, kw, retrack: bool) -> dict:
    from core.tracking.residual_warp import refine_residual_warp
    from core.tracking.trial import track

    kf = {nm: {0: ts.truth(0)[b]} for b, nm in enumerate(ts.names)}
    track(ts.renderer, ts.models, ts.frames, fl[:3], keyframes=kf, options=o)  # kernels compiled, not timed
    t1 = time.perf_counter()
    first = track(ts.renderer, ts.models, ts.frames, fl, keyframes=kf, options=o)
    out = {"first_track_s": time.perf_counter() - t1}
    t1 = time.perf_counter()
    est, _ = refine_residual_warp(ts.renderer, ts.models, ts.frames, first, options=o, retrack=False,
                                  every=every, **kw)
    out["estimate_s"] = time.perf_counter() - t1
    runs = {"first": {(nm, f): first.results[(nm, f)].pose for nm in ts.names for f in fl},
            "fitted": est.poses}
    out["first_flagged"] = int(sum(bool(r.flags) for r in first.results.values()))
    if retrack:  # as refine_residual_warp does, timed apart
        keyframes = {nm: {fl[0]: first.results[(nm, fl[0])].pose} for nm in ts.names}
        t1 = time.perf_counter()
        again = track(ts.renderer, ts.models, est.warp.frames(ts.frames), fl, keyframes=keyframes, options=o)
        out["retrack_s"] = time.perf_counter() - t1
        runs["retracked"] = {(nm, f): again.results[(nm, f)].pose for nm in ts.names for f in fl}
        out["retracked_flagged"] = int(sum(bool(r.flags) for r in again.results.values()))
    out["estimate"] = est.to_dict()
    out["field"] = field_comparison(ts, est.warp)
    out["field_over_bones"] = field_comparison(ts, est.warp, masks=_FOOT[0])
    out["tracking"] = {label: {nm: _summary(E, bound.get(nm)) for nm, E in _errors(ts, P, fl).items()}
                       for label, P in runs.items()}
    out["per_frame_error"] = {label: {nm: np.round(E, 5).tolist() for nm, E in _errors(ts, P, fl).items()}
                              for label, P in runs.items() if label != "fitted"}
    return out


class TrueWarp:
    """The trial's true residual field as a frame source's correction (study only: the truth):
    output ``x`` samples the corrected frame at ``x + g(x)``, ``g`` from :func:`true_field`."""

    def __init__(self, ts):
        import cv2

        self._maps = []
        for v, cam in enumerate(ts.scene.rig):
            vv, uu = np.mgrid[0:cam.height, 0:cam.width].astype(float)
            uv = np.stack([uu.ravel(), vv.ravel()], axis=1)
            src = uv + true_field(ts, v, uv)
            self._maps.append((src[:, 0].reshape(cam.height, cam.width).astype(np.float32),
                               src[:, 1].reshape(cam.height, cam.width).astype(np.float32)))
        self._remap = cv2.remap
        self._flags = (cv2.INTER_LINEAR, cv2.BORDER_REPLICATE)

    def frames(self, frames):
        def read(i):
            return [None if x is None else self._remap(np.asarray(x, np.float32), *self._maps[v],
                                                       self._flags[0], borderMode=self._flags[1])
                    for v, x in enumerate(frames(i))]
        return read


def _oracle_case(ts, bound, fl, o) -> dict:
    """The trial tracked as it is and on frames re-warped by the TRUE residual field (what a
    perfect self-calibration could give at most)."""
    from core.tracking.trial import track

    kf = {nm: {0: ts.truth(0)[b]} for b, nm in enumerate(ts.names)}
    track(ts.renderer, ts.models, ts.frames, fl[:3], keyframes=kf, options=o)  # kernels compiled, not timed
    runs, out = {}, {}
    for label, src in (("first", ts.frames), ("true_field_removed", TrueWarp(ts).frames(ts.frames))):
        t1 = time.perf_counter()
        res = track(ts.renderer, ts.models, src, fl, keyframes=kf, options=o)
        out[f"{label}_track_s"] = time.perf_counter() - t1
        out[f"{label}_flagged"] = int(sum(bool(r.flags) for r in res.results.values()))
        runs[label] = {(nm, f): res.results[(nm, f)].pose for nm in ts.names for f in fl}
    out["tracking"] = {label: {nm: _summary(E, bound.get(nm)) for nm, E in _errors(ts, P, fl).items()}
                       for label, P in runs.items()}
    return out


def run(*, pixels: int = 256, voxel: float = 1.0, frames: int = 20, device: str | None = None,
        cases=("truth", "plain"), every: int = 1, retrack: bool = True, workers: int = 0,
        budget_s: float | None = None, checkpoint=None, **kw) -> dict:
    """Run the study (module docs); returns the JSON-ready results. ``cases``: ``truth`` (the
    estimator from the true poses), ``plain`` (tracked with the Gauss–Newton search, estimated,
    re-tracked), ``final`` (the same with the weighted least-squares final stage),
    ``oracle_plain`` / ``oracle_final`` (tracked, and tracked on frames with the true residual
    field removed: the most a self-calibration could give); ``kw`` goes to
    :func:`core.tracking.residual_warp.estimate_residual_warp`; a case is skipped once
    ``budget_s`` has passed."""
    from core.studies.tracking.ml_cost import _scene
    from core.tracking.trial import TrackingOptions

    t0 = time.perf_counter()
    header = {"study": "core.studies.tracking.self_calibration", "estimator": kw, "every": every}
    ts, out, bound = _scene(frames, pixels, voxel, device, workers, header)
    out["machine"] = platform.machine()
    out["residual_distortion_rms_mm"] = ts.residual_distortion_mm()
    fl = list(range(frames))
    out["true_field"] = field_comparison(ts, _Zero(ts))
    _FOOT[:] = [footprints(ts, fl[::max(1, frames // 10)])]
    out["true_field_over_bones"] = field_comparison(ts, _Zero(ts), masks=_FOOT[0])
    base = TrackingOptions(mode="joint")
    plain = replace(base, registration=replace(base.registration, search="newton"))
    final = replace(plain, registration=replace(plain.registration, final_highpass_px=4.0),
                    refine_likelihood=True)
    for case in cases:
        if budget_s is not None and time.perf_counter() - t0 > budget_s:
            out.setdefault("skipped", []).append(case)
            continue
        t1 = time.perf_counter()
        if case == "truth":
            out["truth"] = _truth_case(ts, bound, fl[::every], kw)
        elif case.startswith("oracle_"):  # oracle_plain, oracle_final
            out[case] = _oracle_case(ts, bound, fl, {"plain": plain, "final": final}[case[7:]])
        else:
            out[case] = _track_case(ts, bound, fl, {"plain": plain, "final": final}[case], every, kw, retrack)
        out[case]["case_s"] = time.perf_counter() - t1
        out["total_s"] = time.perf_counter() - t0
        if checkpoint:
            checkpoint(out)
    out["total_s"] = time.perf_counter() - t0
    return out


_FOOT: list = []  # the trial's bone footprints per view (run sets it)


def recompare(path: str, device: str | None = None) -> dict:
    """The field comparisons of a results JSON of this study redone from its estimates' coefficients
    (round field and over the bones' footprints), without tracking again; ``{case: {label: ...}}``."""
    import json

    from core.studies.tracking.acceptance import TrackingScene
    from core.tracking.residual_warp import ResidualWarp

    res = json.load(open(path))
    n = int(res["frames"])
    ts = TrackingScene(n_frames=n, pixels=int(res["pixels"]), spacing=float(res["voxel_mm"]),
                       phase=(0.0, 0.6 * n / 100.0), device=device)
    masks = footprints(ts, range(0, n, max(1, n // 10)))
    out = {"true_field_over_bones": field_comparison(ts, _Zero(ts), masks=masks)}
    for case in ("truth", "plain", "final"):
        if case not in res:
            continue
        items = [(k, v["estimate"]) for k, v in res[case].items() if isinstance(v, dict) and "estimate" in v]
        if "estimate" in res[case]:
            items.append(("estimate", res[case]["estimate"]))
        for label, e in items:
            w = ResidualWarp(e["warp"]["shapes"], e["warp"]["order"], e["warp"]["coef"])
            out.setdefault(case, {})[label] = {"field": field_comparison(ts, w),
                                               "field_over_bones": field_comparison(ts, w, masks=masks)}
    return out


class _Zero:
    """A field of zeros (the truth's own RMS in :func:`field_comparison`)."""

    def __init__(self, ts):
        self.n = len(ts.scene.rig)

    def displacement(self, view, uv):
        return np.zeros((len(uv), 2))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.self_calibration",
                                description=__doc__.split("\n")[0])
    p.add_argument("--pixels", type=int, default=256)
    p.add_argument("--voxel", type=float, default=1.0)
    p.add_argument("--frames", type=int, default=20)
    p.add_argument("--device", default=None, help="Warp device (cpu, cuda:0)")
    p.add_argument("--cases", default="truth,plain",
                   help="comma-separated: truth, plain, final, oracle_plain, oracle_final")
    p.add_argument("--every", type=int, default=1, help="estimate from every k-th frame")
    p.add_argument("--order", type=int, default=3, help="polynomial order of the field")
    p.add_argument("--iterations", type=int, default=2)
    p.add_argument("--ridge", type=float, default=1e-3)
    p.add_argument("--ridge-low", type=float, default=1e3,
                   help="ridge of the order <= 1 terms (negative: as --ridge)")
    p.add_argument("--highpass", type=float, default=None, help="band-pass high-pass sigma, px")
    p.add_argument("--smooth", type=float, default=None, help="band-pass smoothing sigma, px")
    p.add_argument("--no-retrack", action="store_true")
    p.add_argument("--workers", type=int, default=0, help="processes synthesising the frames")
    p.add_argument("--budget", type=float, default=None, help="skip the remaining cases after this many s")
    p.add_argument("--out", default=None, help="also write the JSON here (after each case)")
    p.add_argument("--recompare", default=None, metavar="JSON",
                   help="only redo the field comparisons of this results file (round field, over the bones)")
    a = p.parse_args(argv)
    from core.io.atomic import json_checkpoint, print_json

    checkpoint = json_checkpoint(a.out, indent=2)

    if a.recompare:
        print_json(recompare(a.recompare, a.device), a.out)
        return 0
    res = run(pixels=a.pixels, voxel=a.voxel, frames=a.frames, device=a.device,
              cases=tuple(c for c in a.cases.split(",") if c), every=a.every, retrack=not a.no_retrack,
              workers=a.workers, budget_s=a.budget, checkpoint=checkpoint, order=a.order,
              iterations=a.iterations,
              ridge=a.ridge, ridge_low=None if a.ridge_low < 0 else a.ridge_low, highpass_px=a.highpass,
              smooth_px=a.smooth)
    print_json(res, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
