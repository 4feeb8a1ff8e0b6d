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
          draws: int = 12, device: str | None = "cpu", candidates=None) -> dict:
    """The checks (module docs); JSON-ready. ``candidates``: screen names (:func:`~core.studies.
    tracking.spread_screen.parse`: high-pass, ``tissue``, ``rim``, ``norobust``, ``flat``, ``edge``;
    default ``hp<highpass>+norobust``), each refined as :class:`~core.tracking.likelihood_cost.
    LikelihoodCost` with the same weights, tissue regressor and robust round."""
    from core.geometry.transforms import pose_from_params
    from core.render import DRRRenderer
    from core.studies.tracking import spread_screen as ss
    from core.studies.tracking.background_fit import _crop, _Sources, estimated_psf
    from core.studies.tracking.tissue_regressor import regressor_images, user_tissue
    from core.tracking.bound import pose_bound
    from core.tracking.cost import fluoro_rois, prepare_frame, search_roi, snap_roi
    from core.tracking.engine_likelihood import LikelihoodEngine
    from core.tracking.likelihood_cost import LikelihoodCost
    from core.tracking.likelihood_rim import rim_keep

    t0 = time.perf_counter()
    ts = _Sources(pixels, voxel, 100, 0, device).scene("grid")
    sc = ts.scene
    L = sc.line_integrals(frame, renderer=ts._scene_renderer)
    P = ts.truth(frame)
    N = [m.photons_per_pixel for m in sc.imaging]
    fr = [prepare_frame(ss._chain(ts, L, frame, d)) for d in [None, *range(draws)]]
    h, views, scale = 0.05 * 1024 / pixels, (0, 1), pixels / 1024
    cands = [ss.parse(c) for c in (candidates or [f"hp{highpass:g}+norobust"])]
    for c in cands:
        if c.kind != "wls" or c.inner or c.poly >= 0 or c.binning != 1 or c.nbr or c.newton:
            raise ValueError(f"candidate {c.name!r}: the check refines high-pass, tissue, rim, robust and "
                             "weight candidates only")
    tr = DRRRenderer(sc.rig, [v.to_attenuation(sc.tissue_transfer) for v in user_tissue(sc, "fine")],
                     device=device)
    Lt = tr.render(P[list(sc.tissue_bones)][None], roi="full").numpy()[0].astype(np.float64)
    T = regressor_images(Lt, np.asarray(estimated_psf(ts), float), False)[:, 0]
    out = {"study": "core.studies.tracking.spread_screen_check", "machine": platform.machine(),
           "device": device, "pixels": pixels, "voxel_mm": voxel, "frame": frame, "draws": draws,
           "candidates": [c.name for c in cands], "results": {}}
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
        cap = (max(int(r[3]) for r in roi), max(int(r[2]) for r in roi))
        keeps = {(c.rim, c.highpass): rim_keep(fr[0], views, roi, c.rim * c.highpass * scale, cap)
                 for c in cands if c.rim is not None}
        vds, Tc = [], []
        for i in range(len(views)):
            wd, ht = int(roi[i][2]), int(roi[i][3])
            Oi = O[i, :ht, :wd].astype(np.float64)
            Tc.append(_crop(T[i], roi[i]))
            keep = {k: None if v is None else v[i, :ht, :wd].astype(float) for k, v in keeps.items()}
            vds.append(ss._ViewData(D[:, i, :ht, :wd].astype(np.float64), Oi, Tc[-1], keep, Oi))
        regions = []
        for f_ in fr:
            ys, ms = fluoro_rois(ts.renderer, f_, views=views, roi=roi)
            regions.append([(y.astype(np.float64), mk) for y, mk in zip(ys, ms, strict=True)])
        res = out["results"].setdefault(ts.names[b], {})
        res["bound_sigma"] = np.round(np.sqrt(np.diag(C)), 5).tolist()
        for c in cands:
            lin = ss._wls_steps(c, vds, regions, scale, h, None)
            hp = c.highpass * scale
            r = {}
            if c is cands[0] and not (c.tissue or c.rim or c.weights != "counts" or c.robust):
                eng = LikelihoodEngine(ts.renderer, bone=b, views=views, highpass_px=hp)
                eng.set_frame(fr[1], base_pose=P[b], center=m.centroid, roi=roi, others=(P[oth], oth))
                s = eng.step(np.zeros(6), np.full(6, h))
                r["engine_max_diff"] = float(np.max(np.abs(np.linalg.solve(s["JJ"], s["Jr"]) - lin[1])))
            ref = []
            for f_ in fr:
                lc = LikelihoodCost(ts.renderer, f_, bone=b, base_pose=P[b], center=m.centroid, roi=roi,
                                    others=(P[oth], oth), others_gain=False, highpass_px=hp or None,
                                    background=0, regressors=[t[None] for t in Tc] if c.tissue else None)
                ws = []
                for vd, w in zip(vds, lc.weights, strict=True):
                    kp = vd.keep.get((c.rim, c.highpass)) if c.rim is not None else None
                    w = w if kp is None else w * kp
                    if c.weights == "flat":
                        w = (w > 0).astype(float)
                    elif c.weights == "edge":
                        w = w * ss._model_terms(vd, c, scale, h)[3]
                    ws.append(w)
                lc.weights = tuple(ws)
                ref.append(lc.refine(iters=12, step=(h, h), tol=(1e-5, 1e-5), robust=c.robust)["x"])
            ref = np.asarray(ref)
            d = np.sqrt(np.mean((ref[1:] - lin[1:]) ** 2, axis=0))
            r.update({"linearised": _stats(lin, C, draws), "refined": _stats(ref, C, draws),
                      "refined_minus_linearised_rms": np.round(d, 5).tolist()})
            res[c.name] = r
            print(ts.names[b], c.name, r, flush=True)
    out["total_s"] = time.perf_counter() - t0
    return out


def _stats(S, C, draws: int) -> dict:
    """Over the bound of the frame (mm, °): the draws' spread and RMS, the noise-free offset."""
    dev = (S[1:] - S[1:].mean(0)) * np.sqrt(draws / (draws - 1))
    bm, bd = np.sqrt(np.trace(C[:3, :3])), np.sqrt(np.trace(C[3:, 3:]))

    def rms(E):
        return float(np.sqrt(np.mean(np.sum(E**2, axis=1))))

    return {"spread_over_bound": [round(rms(dev[:, :3]) / bm, 3), round(rms(dev[:, 3:]) / bd, 3)],
            "rms_over_bound": [round(rms(S[1:, :3]) / bm, 3), round(rms(S[1:, 3:]) / bd, 3)],
            "noise_free": np.round(S[0], 5).tolist()}


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
    p.add_argument("--candidates", default="", help="screen names (default hp<highpass>+norobust)")
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    from core.io.atomic import print_json

    res = check(pixels=a.pixels, voxel=a.voxel, frame=a.frame, highpass=a.highpass, draws=a.draws,
                bones=[int(x) for x in a.bones.split(",") if x], device=a.device,
                candidates=[x for x in a.candidates.split(",") if x] or None)
    print_json(res, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
