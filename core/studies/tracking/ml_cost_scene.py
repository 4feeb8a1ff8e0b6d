"""The scene of :mod:`core.studies.tracking.ml_cost` and the studies built on it: the acceptance
trial's frames synthesised through the image chain (in worker processes), its Cramér–Rao bound,
and the per-bone error summaries (:func:`_scene`, :func:`synthesise`, :func:`_pose_errs`,
:func:`_summary`)."""

from __future__ import annotations

import platform
import time

import numpy as np

from core.studies.tracking.trial_frames import synthesise  # the trial's frames in worker processes

__all__ = ["synthesise"]


def _pose_errs(ts, nm, poses, frames):
    from core.studies.tracking.acceptance import pose_errors

    b = ts.names.index(nm)
    return [np.full(6, np.nan) if poses[(nm, f)] is None else
            pose_errors(poses[(nm, f)], ts.truth(f)[b], ts.models[b].centroid) for f in frames]


def _summary(E, bound, cov=None) -> dict:
    ok = np.all(np.isfinite(E), axis=1)
    E = E[ok]
    cov = None if cov is None else [c for c, k in zip(cov, ok, strict=True) if k]
    et, er = np.linalg.norm(E[:, :3], axis=1), np.linalg.norm(E[:, 3:], axis=1)
    s = {"rms_mm": float(np.sqrt(np.mean(et**2))), "rms_deg": float(np.sqrt(np.mean(er**2))),
         "mean_error": E.mean(0).round(4).tolist(), "std_error": E.std(0).round(4).tolist(),
         "max_mm": float(et.max()), "max_deg": float(er.max()), "missing": int((~ok).sum())}
    if bound:
        s["over_bound"] = {"mm": s["rms_mm"] / bound["rms_mm"], "deg": s["rms_deg"] / bound["rms_deg"]}
    if cov is not None:
        sig = np.sqrt(np.array([np.diag(c) for c in cov]))
        s["within_2_sigma"] = float(np.mean(np.abs(E) <= 2 * sig))
    return s


def _scene(n: int, pixels: int, voxel: float, device, workers: int, header: dict, *, glare: bool = False,
           correction: str = "model", keep_raw: bool = False):
    """``(ts, out, bound)``: the trial's scene of ``n`` frames with its frames synthesised (the raw
    frames kept when ``keep_raw``), and the results' head — ``header``, the machine and device,
    sizes, synthesis time and the Cramér–Rao bound of every tenth frame (``cramer_rao``,
    ``bound_s``; ``bound`` in full, per bone)."""
    from core.studies.tracking.acceptance import TrackingScene, cramer_rao

    t0 = time.perf_counter()
    ts = TrackingScene(n_frames=max(n, 2), pixels=pixels, spacing=voxel, phase=(0.0, 0.6 * max(n, 2) / 100.0),
                       device=device, glare=glare, correction=correction, keep_raw=keep_raw)
    synthesise(ts, range(n), workers)
    out = {**header, "machine": platform.machine(), "device": str(ts.renderer.device), "pixels": pixels,
           "voxel_mm": voxel, "frames": n}
    out["synthesis_s"] = time.perf_counter() - t0
    out["residual_distortion_rms_mm"] = ts.residual_distortion_mm()
    if correction == "grid":  # the fitted models, cross-validation tables and alignments
        out["correction_fits"] = [c.summary() for c in ts.corrections]
    try:
        import warp as wp

        out["device_name"] = wp.get_device(str(ts.renderer.device)).name
    except Exception:  # a name only
        pass
    t0 = time.perf_counter()
    bound = cramer_rao(ts, range(0, n, max(1, n // 10)))
    out["cramer_rao"] = {k: {"rms_mm": v["rms_mm"], "rms_deg": v["rms_deg"]} for k, v in bound.items()}
    out["bound_s"] = time.perf_counter() - t0
    return ts, out, bound
