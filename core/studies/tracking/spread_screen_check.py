"""Checks of :mod:`core.studies.tracking.spread_screen`'s linearisation (``python -m
core.studies.tracking.spread_screen_check``).

On one frame of the acceptance trial (grid correction, glare undone; the other bones at their
true poses and subtracted) and its noise draws, per bone: the screen's Gauss–Newton step from the
truth (:func:`~core.studies.tracking.spread_screen.wls_step`) against the device stage's own step
(:meth:`core.tracking.engine_likelihood.LikelihoodEngine.step` on the same frame: ``engine_max_diff``),
and the spread over the draws of the screen's step against that of the estimate refined to
convergence (:meth:`core.tracking.likelihood_cost.LikelihoodCost.refine`, up to 12 Gauss–Newton
steps from the truth): the stage without its robust round, high-pass ``highpass`` px at 1024²
scaled. Both spreads over the bone's Cramér–Rao bound of that frame (mm, °).

JSON on stdout (``--out``: also to a file).
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np

__all__ = ["check", "main"]


def check(*, pixels: int = 512, voxel: float = 0.5, frame: int = 50, bones=(0, 1), highpass: float = 4.0,
          draws: int = 12, device: str | None = "cpu") -> dict:
    """The checks (module docs); JSON-ready."""
    from core.geometry.transforms import pose_from_params
    from core.studies.tracking import spread_screen as ss
    from core.studies.tracking.background_fit import _Sources
    from core.tracking.bound import pose_bound
    from core.tracking.cost import fluoro_rois, prepare_frame, search_roi, snap_roi
    from core.tracking.engine_likelihood import LikelihoodEngine
    from core.tracking.likelihood_cost import LikelihoodCost

    t0 = time.perf_counter()
    ts = _Sources(pixels, voxel, 100, 0, device).scene("grid")
    sc = ts.scene
    L = sc.line_integrals(frame, renderer=ts._scene_renderer)
    P = ts.truth(frame)
    N = [m.photons_per_pixel for m in sc.imaging]
    fr = [prepare_frame(ss._chain(ts, L, frame, d)) for d in [None, *range(draws)]]
    h, hp, views = 0.05 * 1024 / pixels, highpass * pixels / 1024, (0, 1)
    cand = ss.parse(f"hp{highpass:g}+norobust")
    out = {"study": "core.studies.tracking.spread_screen_check", "machine": platform.machine(),
           "device": device, "pixels": pixels, "voxel_mm": voxel, "frame": frame, "draws": draws,
           "highpass_px_at_1024": highpass, "results": {}}
    X = np.concatenate([np.zeros((1, 6)), np.eye(6) * h, -np.eye(6) * h])
    for b in bones:
        m = ts.models[b]
        oth = [k for k in range(len(ts.names)) if k != b]
        C = pose_bound(ts.renderer, b, P[b], m.centroid, line_integral=L, quanta_per_pixel=N).covariance
        roi = snap_roi(search_roi(ts.renderer, P[b], b, views=views, center=m.centroid, reach_mm=1.0,
                                  margin_px=4), ts.renderer, views)
        ra = np.asarray(roi)[None, :, None, :]
        p6 = np.concatenate([X[:, :3], np.radians(X[:, 3:])], axis=1)
        Pd = pose_from_params(p6, center=m.centroid, base=P[b])
        D = ts.renderer.render(Pd[:, None], views=views, bones=[b], roi=ra).numpy()[:, :, 0]
        O = ts.renderer.render(P[oth][None], views=views, bones=oth, roi=ra).numpy()[0].sum(axis=1)
        vds = []
        for i in range(len(views)):
            wd, ht = int(roi[i][2]), int(roi[i][3])
            Oi = O[i, :ht, :wd].astype(np.float64)
            vds.append(ss._ViewData(D[:, i, :ht, :wd].astype(np.float64), Oi, None, {}, Oi))
        regions = []
        for f_ in fr:
            ys, ms = fluoro_rois(ts.renderer, f_, views=views, roi=roi)
            regions.append([(y.astype(np.float64), mk) for y, mk in zip(ys, ms, strict=True)])
        lin = ss._wls_steps(cand, vds, regions, pixels / 1024, h, None)
        eng = LikelihoodEngine(ts.renderer, bone=b, views=views, highpass_px=hp)
        eng.set_frame(fr[1], base_pose=P[b], center=m.centroid, roi=roi, others=(P[oth], oth))
        s = eng.step(np.zeros(6), np.full(6, h))
        ref = []
        for f_ in fr:
            lc = LikelihoodCost(ts.renderer, f_, bone=b, base_pose=P[b], center=m.centroid, roi=roi,
                                others=(P[oth], oth), others_gain=False, highpass_px=hp, background=0)
            ref.append(lc.refine(iters=12, step=(h, h), tol=(1e-5, 1e-5))["x"])
        ref = np.asarray(ref)

        def spread(S, C=C):
            dev = (S[1:] - S[1:].mean(0)) * np.sqrt(draws / (draws - 1))
            return [float(np.sqrt(np.mean(np.sum(dev[:, :3] ** 2, 1)) / np.trace(C[:3, :3]))),
                    float(np.sqrt(np.mean(np.sum(dev[:, 3:] ** 2, 1)) / np.trace(C[3:, 3:])))]

        out["results"][ts.names[b]] = {
            "engine_max_diff": float(np.max(np.abs(np.linalg.solve(s["JJ"], s["Jr"]) - lin[1]))),
            "linearised_spread_over_bound": np.round(spread(lin), 3).tolist(),
            "refined_spread_over_bound": np.round(spread(ref), 3).tolist(),
            "linearised_bias": np.round(lin[0], 5).tolist(), "refined_bias": np.round(ref[0], 5).tolist(),
            "refined_minus_linearised_rms": np.round(np.sqrt(np.mean((ref[1:] - lin[1:]) ** 2, axis=0)),
                                                     5).tolist(),
            "bound_sigma": np.round(np.sqrt(np.diag(C)), 5).tolist()}
        print(ts.names[b], out["results"][ts.names[b]], flush=True)
    out["total_s"] = time.perf_counter() - t0
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.spread_screen_check",
                                description=__doc__.split("\n")[0])
    p.add_argument("--pixels", type=int, default=512)
    p.add_argument("--voxel", type=float, default=0.5)
    p.add_argument("--frame", type=int, default=50)
    p.add_argument("--bones", default="0,1")
    p.add_argument("--highpass", type=float, default=4.0)
    p.add_argument("--draws", type=int, default=12)
    p.add_argument("--device", default="cpu")
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    from core.io.atomic import print_json

    res = check(pixels=a.pixels, voxel=a.voxel, frame=a.frame, highpass=a.highpass, draws=a.draws,
                bones=[int(x) for x in a.bones.split(",") if x], device=a.device)
    print_json(res, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
