"""Why the tracker's per-frame error is about twice the Cramér–Rao bound (``python -m
core.studies.tracking.bound_gap``).

A controlled experiment on a few frames of the standard synthetic walking trial of
:mod:`core.studies.tracking.acceptance` at reduced size on the CPU. For each frame and bone the
other bones sit at their true poses (the bound's assumption), and each cost's optimum is found
from the true pose by the same local search (:func:`local_newton`: Newton steps on a
finite-difference quadratic model of the cost, so the search is not what differs). The frames
are synthesised through image chains that switch the degradations on one after the other:

* ``poisson`` — Poisson quanta only: exactly the bound's model;
* ``blur`` — plus the intensifier's PSF, veiling glare and roll-off (no distortion, no read
  noise);
* ``full`` — the trial's chain (plus distortion undone with the trial's 3 %-wrong inverse, read
  noise, 12-bit quantisation).

Each chain is rendered without noise (the optimum there is the cost's *bias*) and with
``--seeds`` noise draws (the spread about it is its *variance*). Costs: ``gc`` (the tracker's
default: gradient correlation of the gradient magnitudes, both images smoothed by 0.3 mm),
``gc_components`` (Penney's form) and ``wls[_psf]_hp<σ>`` (:class:`core.tracking.likelihood_cost.
LikelihoodCost`: weighted least squares on the line-integral image, weights the expected counts,
gain and offset fitted linearly, the neighbours subtracted; both images high-passed by σ pixels
of a 256² view, scaled with the size, ``hp0`` = a plane background instead; ``_psf``: the DRR
blurred by the PSF *estimated* from synthetic pinhole calibration frames,
:func:`core.imaging.psf.psf_from_pinholes`).

Bounds: the trial's bound (:func:`core.tracking.bound.pose_bound`, Poisson quanta before any
blur) and ``chain`` — the information left after the PSF, glare and read noise
(:func:`core.tracking.bound.chain_information`). :func:`wls_spread` predicts the weighted least
squares estimate's spread from the noise alone (linearised), by high-pass σ.

Results (``resources/benchmarks/tracking_bound_gap_cpu.json``, this 2-core CPU machine;
``tracking_ml_cost_h200.json``, one NVIDIA H200):

* the bound is not what is optimistic: the chain after the quanta raises it by 2–7 % at 1024²;
* the gap is the soft-tissue envelope, which the bound (rightly, for what it measures) treats as
  known and every cost leaves unmodelled: on noise-free frames of bones + soft tissue the
  tracker's GC optimum lies 0.01–0.09 mm / 0.02–0.28° from the truth (256², others known; the
  bound is 0.018–0.049 mm / 0.11–0.21°), on bones + walkway ≤ 0.001 mm / 0.003°, on bones alone
  0 for every cost. Blur, glare, roll-off and residual distortion change little at 256².
* a weighted least-squares fit without high-pass reaches the bound's spread (1.01–1.11× at
  1024², predicted) but fits the tissue with the bone's gain (biased by millimetres); a high-pass
  trades that bias for spread (predicted 1.10–1.21× at 8 px, 1.19–1.41× at 4 px, 1024²). On the
  standard trial (talus alone, every 4th frame, one H200) refining the tracker's poses so
  lowered the error from 2.01 / 2.14× to 1.59 / 1.57× the bound (4 px) or 1.69 / 1.81× (8 px);
  blurring the DRR by the estimated PSF did not help (1.84 / 1.97×).
* the ceiling (study-only: the tissue's true line integral subtracted, quadratic background): the
  same fit is unbiased and at 0.86–1.16× the bound on quanta-only frames, but through the trial's
  chain two more biases appear — veiling glare (5 %) compresses contrast where the fluence is low
  and moves the log-domain fit by 0.18–0.30 mm / 0.14–0.91° (talus, calcaneus); the residual
  distortion (the 3 %-wrong inverse) moves any cost by up to ~0.06 mm / 0.1° (GC: up to 0.037 mm
  for the tibia, whose bound is 0.018 mm). Neither is in the bound.

JSON on stdout (``--out``: also to a file).
"""

from __future__ import annotations

import argparse
import platform
import time
from dataclasses import replace

import numpy as np

__all__ = ["local_newton", "main", "run"]

VARIANTS = ("poisson", "blur", "full")


def local_newton(fun, x0, *, h=(0.1, 0.1), iters: int = 8, max_step=(0.5, 0.5)) -> np.ndarray:
    """Minimise ``fun(X (B, 6)) -> (B,)`` near ``x0``: Newton steps on the quadratic through the
    centre, the 12 axial points ``±h`` and the 60 diagonal points ``(±h_i, ±h_j)`` (one batch of
    73 per step), the Hessian made positive definite, each step clipped to ``max_step`` and
    backtracked (fractions 1, ½, ¼, ⅛ of it in one batch; the best that lowers the cost)."""
    x = np.asarray(x0, float).copy()
    hv = np.array([h[0]] * 3 + [h[1]] * 3)
    ms = np.array([max_step[0]] * 3 + [max_step[1]] * 3)
    E = np.eye(6) * hv
    pairs = [(i, j) for i in range(6) for j in range(i + 1, 6)]
    D = [np.zeros(6)] + [E[i] for i in range(6)] + [-E[i] for i in range(6)]
    for i, j in pairs:
        D += [E[i] + E[j], E[i] - E[j], -E[i] + E[j], -E[i] - E[j]]
    D = np.array(D)
    fr = np.array([1.0, 0.5, 0.25, 0.125])
    for _ in range(iters):
        c = np.asarray(fun(x + D), float)
        c0 = c[0]
        cp, cm = c[1:7], c[7:13]
        g = (cp - cm) / (2 * hv)
        H = np.diag((cp - 2 * c0 + cm) / hv**2)
        for k, (i, j) in enumerate(pairs):
            a, b, cc, d = c[13 + 4 * k: 17 + 4 * k]
            H[i, j] = H[j, i] = (a - b - cc + d) / (4 * hv[i] * hv[j])
        w, V = np.linalg.eigh(H)
        w = np.maximum(np.abs(w), 1e-3 * max(np.abs(w).max(), 1e-12))
        step = np.clip(-(V / w) @ V.T @ g, -ms, ms)
        ct = np.asarray(fun(x + fr[:, None] * step), float)
        k = int(np.argmin(ct))
        if ct[k] >= c0:
            break
        x = x + fr[k] * step
        if np.all(np.abs(fr[k] * step) < 0.01 * hv):
            break
    return x


# ---------------------------------------------------------------------- frames
def _chain(model, variant: str, noise: bool):
    """The ImagingModel of ``variant`` (see the module docs), with or without noise."""
    if variant == "poisson":
        m = type(model)(photons_per_pixel=model.photons_per_pixel, gain_dn=model.gain_dn,
                        dark_dn=model.dark_dn)
    elif variant == "blur":
        m = replace(model, distortion=None, aperture_radius=None, read_noise_dn=0.0)
    elif variant == "full":
        m = model
    else:
        raise ValueError(f"variant: expected one of {VARIANTS}, got {variant!r}")
    if not noise:
        m = replace(m, photons_per_pixel=None, read_noise_dn=0.0)
    return m


def synth(ts, L, variant: str, seed: int | None) -> list[np.ndarray]:
    """Flatfield-normalised (and, for ``full``, approximately undistorted) frames of line
    integrals ``L`` (n_views, H, W) through ``variant``'s chain; ``seed`` None = noise-free."""
    out = []
    for v, model in enumerate(ts.scene.imaging):
        m = _chain(model, variant, seed is not None)
        raw = m.apply(L[v], rng=None if seed is None else np.random.default_rng([seed, v, 77]))
        f = m.to_float(raw)
        if variant == "full":
            f = ts.corrections[v].unwarp(f)
        out.append(f)
    return out


def estimated_psf(ts, view: int = 0, frames: int = 200):
    """The PSF estimated from synthetic pinhole calibration frames of ``view``'s chain
    (:func:`core.imaging.psf.psf_from_pinholes`): what a lab measures, not the generator's kernel."""
    from core.imaging.psf import psf_from_pinholes
    from core.synthetic.calibration import pinhole_frames

    model = replace(ts.scene.imaging[view], distortion=None, aperture_radius=None)
    fr = pinhole_frames(ts.scene.rig[view], model, n_frames=frames, rng=11)
    est = psf_from_pinholes(fr.image.astype(float), size=11)
    return est.psf, fr.psf


def _chain_terms(ts) -> dict:
    """The trial's chain after the quantum stage as :func:`core.tracking.bound.chain_information`
    takes it: the Gaussian PSF, the light outside the glare, and the read noise plus 12-bit
    quantisation in quanta at full fluence (roll-off left out: its centre value, 1)."""
    from core.imaging.psf import gaussian_psf

    ms = ts.scene.imaging
    return {"psf": [gaussian_psf(m.psf_sigma_px) for m in ms],
            "added_noise": [np.sqrt(m.read_noise_dn**2 + 1 / 12) * m.photons_per_pixel / m.gain_dn
                            for m in ms],
            "contrast": [1 - m.glare_fraction for m in ms]}


# ---------------------------------------------------------------------- predicted spread
def wls_spread(renderer, bone: int, pose, center, *, line_integral, quanta_per_pixel: float,
               highpass_px=(None, 4.0, 8.0), psf=None, model_psf=None, margin_px: int = 24) -> dict:
    """Linearised covariance of the weighted least-squares estimate (:class:`core.tracking.likelihood_cost.
    LikelihoodCost`: gain and offset fitted, weights the fluence, the line integrals high-passed
    by σ = ``highpass_px``, None = not; the DRR blurred by ``model_psf`` or not) when the only
    error is the quanta's noise and the frame is blurred by ``psf`` (None = not): with ``G`` the
    model's pose derivatives (high-passed, gain and offset directions projected out), ``A = Gᵀ W
    G``, ``B`` the covariance of ``Gᵀ W H δy`` and ``M = A⁻¹ Gᵀ W H ∂y/∂θ`` the estimate's
    response to a true pose change (``I`` when the model's blur is the frame's), the covariance
    of the estimate rescaled to unit response is ``M⁻¹ A⁻¹ B A⁻¹ M⁻ᵀ``. Without high-pass and blur
    it equals the Cramér–Rao bound up to the gain and offset it does not know. Returns
    ``{label: (rms_mm, rms_deg)}``."""
    import cv2

    from core.similarity.likelihood import highpass
    from core.tracking.bound import _derivatives

    _, N, D = _derivatives(renderer, bone, pose, center, line_integral=line_integral,
                           quanta_per_pixel=quanta_per_pixel, views=None, step=(0.05, 0.05),
                           margin_px=margin_px)

    def conv(k):
        if k is None:
            return lambda a: a
        k = np.asarray(k, np.float64) / np.sum(k)
        return lambda a: cv2.filter2D(a, -1, k[::-1, ::-1], borderType=cv2.BORDER_REPLICATE)

    K, Km = conv(psf), conv(model_psf)
    out = {}
    for hp in highpass_px:
        def H(a, hp=hp):
            return a if hp is None else highpass(a, hp).astype(np.float64)

        A, B, R_ = np.zeros((6, 6)), np.zeros((6, 6)), np.zeros((6, 6))
        for v, (u0, v0, wd, h), Dv, Lv in D:
            roi = np.array([[u0, v0, wd, h]])
            D0 = renderer.render(np.asarray(pose, float)[None, None], views=[v], bones=[bone],
                                 roi=roi[None, :, None, :]).numpy()[0, 0, 0, :h, :wd].astype(np.float64)
            F = np.exp(-Lv)
            KF = K(F)
            w = KF.ravel()
            R = np.stack([H(Km(D0)), np.ones_like(D0)]).reshape(2, -1)  # gain and offset regressors
            G = np.stack([H(Km(Dv[i])) for i in range(6)]).reshape(6, -1)
            coef = np.linalg.solve((R * w) @ R.T, (R * w) @ G.T)  # W-projection off the regressors
            G = G - coef.T @ R
            A += (G * w) @ G.T
            dy = np.stack([H(K(F * Dv[i]) / KF) for i in range(6)]).reshape(6, -1)  # the frame's response
            R_ += (G * w) @ dy.T
            T = np.stack([K(H((w * G[i]).reshape(Dv.shape[1:])) / KF) for i in range(6)]).reshape(6, -1)
            B += (T * (F.ravel() / N[v])) @ T.T
        Ai = np.linalg.inv(A)
        Mi = np.linalg.inv(Ai @ R_)
        C = Mi @ Ai @ B @ Ai @ Mi.T
        out["none" if hp is None else f"hp{hp:g}"] = (float(np.sqrt(np.trace(C[:3, :3]))),
                                                      float(np.sqrt(np.trace(C[3:, 3:]))))
    return out


# ---------------------------------------------------------------------- costs
def _wls_options(name: str, pixels: int, psf) -> dict:
    """LikelihoodCost options of a cost name ``wls[_psf]_hp<σ>``: ``σ`` the high-pass σ in pixels of
    a 256² view (scaled with ``pixels``; ``hp0``: a plane background instead), ``_psf`` the DRR
    blurred by the estimated PSF; the neighbours' DRRs subtracted at gain 1 as the tracker does."""
    parts = name.split("_")
    hp = float(parts[-1][2:]) if parts[-1].startswith("hp") else 0.0
    o = {"others_gain": False, "psf": psf if "psf" in parts else None}
    if hp > 0:
        o.update(background=0, highpass_px=hp * pixels / 256)
    return o


def _gc_cost(ts, frame, b, truth, others, roi, components: bool):
    from core.tracking.cost import DEFAULT_TERMS, RegistrationCost, metric_terms

    terms = metric_terms("components") if components else DEFAULT_TERMS
    m = ts.models[b]
    return RegistrationCost(ts.renderer, frame, bone=b, base_pose=truth[b], center=m.centroid, roi=roi,
                            terms=terms, others=others)


def run(*, pixels: int = 512, voxel: float = 0.5, frames=(10, 40, 70), bones=(1,), seeds: int = 3,
        variants=VARIANTS, costs=("gc", "gc_components", "wls_hp2", "wls_psf_hp2"),
        chain_bound: bool = True) -> dict:
    """Run the study (module docs); returns the JSON-ready results."""
    from core.studies.tracking.acceptance import TrackingScene, pose_errors
    from core.tracking.bound import chain_information, pose_bound
    from core.tracking.cost import prepare_frame, search_roi
    from core.tracking.likelihood_cost import LikelihoodCost

    t0 = time.perf_counter()
    ts = TrackingScene(n_frames=100, pixels=pixels, spacing=voxel, phase=(0.0, 0.6), device="cpu")
    psf_est, psf_true = estimated_psf(ts)
    out = {"study": "core.studies.tracking.bound_gap", "machine": platform.machine(), "device": "cpu",
           "pixels": pixels, "voxel_mm": voxel, "frames": list(frames), "seeds": seeds,
           "psf": {"estimated_sigma_px": _sigma(psf_est), "true_sigma_px": _sigma(psf_true),
                   "model_sigma_px": float(ts.scene.imaging[0].psf_sigma_px)},
           "results": {}}
    N = [m.photons_per_pixel for m in ts.scene.imaging]
    rows: dict = {}
    for f in frames:
        L = ts.scene.line_integrals(f, renderer=ts._scene_renderer)
        truth = ts.truth(f)
        imgs = {(var, s): synth(ts, L, var, s) for var in variants for s in [None, *range(seeds)]}
        for b in bones:
            name = ts.names[b]
            m = ts.models[b]
            bd = pose_bound(ts.renderer, b, truth[b], m.centroid, line_integral=L, quanta_per_pixel=N)
            rec = rows.setdefault(name, {"bound_cov": [], "chain_cov": [], "err": {}})
            rec["bound_cov"].append(bd.covariance)
            if chain_bound:
                J = chain_information(ts.renderer, b, truth[b], m.centroid, line_integral=L,
                                      quanta_per_pixel=N, **_chain_terms(ts))
                rec["chain_cov"].append(np.linalg.inv(J))
            oth = [k for k in range(len(ts.models)) if k != b]
            others = (truth[oth], oth) if oth else None
            roi = search_roi(ts.renderer, truth[b], b, views=[0, 1], center=m.centroid, reach_mm=2.0)
            for (var, s), im in imgs.items():
                frame = prepare_frame(im)
                for c in costs:
                    if c.startswith("gc"):
                        fun = _gc_cost(ts, frame, b, truth, others, roi, c == "gc_components")
                    else:
                        fun = LikelihoodCost(ts.renderer, frame, bone=b, base_pose=truth[b],
                                             center=m.centroid, roi=roi, others=others,
                                             **_wls_options(c, pixels, psf_est))
                    x = local_newton(fun, np.zeros(6), h=(0.1 * 256 / pixels, 0.1 * 256 / pixels))
                    e = pose_errors(fun.poses(x[None])[0], truth[b], m.centroid)
                    rec["err"].setdefault(f"{var}/{c}", {}).setdefault("free" if s is None else "noisy",
                                                                       []).append(e.tolist())
            print(f"frame {f} bone {name} done {time.perf_counter() - t0:.0f}s", flush=True)
    for name, rec in rows.items():
        C = np.mean(rec["bound_cov"], axis=0)
        res = {"bound": {"rms_mm": float(np.sqrt(np.trace(C[:3, :3]))),
                         "rms_deg": float(np.sqrt(np.trace(C[3:, 3:])))}}
        if rec["chain_cov"]:
            Cc = np.mean(rec["chain_cov"], axis=0)
            res["chain_bound"] = {"rms_mm": float(np.sqrt(np.trace(Cc[:3, :3]))),
                                  "rms_deg": float(np.sqrt(np.trace(Cc[3:, 3:])))}
        for key, d in rec["err"].items():
            E0 = np.array(d["free"])  # (frames, 6): bias per frame
            En = np.array(d["noisy"]).reshape(len(frames), seeds, 6)
            dev = En - E0[:, None]
            tot = En.reshape(-1, 6)
            r = {"bias_mm": _rms3(E0[:, :3]), "bias_deg": _rms3(E0[:, 3:]),
                 "spread_mm": _rms3(dev.reshape(-1, 6)[:, :3]),
                 "spread_deg": _rms3(dev.reshape(-1, 6)[:, 3:]),
                 "rms_mm": _rms3(tot[:, :3]), "rms_deg": _rms3(tot[:, 3:])}
            r["over_bound"] = {"mm": r["rms_mm"] / res["bound"]["rms_mm"],
                               "deg": r["rms_deg"] / res["bound"]["rms_deg"],
                               "spread_mm": r["spread_mm"] / res["bound"]["rms_mm"],
                               "spread_deg": r["spread_deg"] / res["bound"]["rms_deg"]}
            res[key] = r
        out["results"][name] = res
    out["total_s"] = time.perf_counter() - t0
    return out


def _rms3(E) -> float:
    E = np.asarray(E).reshape(-1, 3)
    return float(np.sqrt(np.mean(np.sum(E**2, axis=1))))


def _sigma(k) -> float:
    k = np.asarray(k, float)
    h = k.shape[0] // 2
    y, x = np.mgrid[-h:h + 1, -h:h + 1]
    return float(np.sqrt(0.5 * np.sum(k * (x**2 + y**2)) / k.sum()))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.bound_gap",
                                description=__doc__.split("\n")[0])
    p.add_argument("--pixels", type=int, default=512)
    p.add_argument("--voxel", type=float, default=0.5)
    p.add_argument("--frames", default="10,40,70")
    p.add_argument("--bones", default="1", help="bone indices (0 tibia, 1 talus, 2 calcaneus)")
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--variants", default=",".join(VARIANTS))
    p.add_argument("--costs", default="gc,gc_components,wls_hp2,wls_psf_hp2")
    p.add_argument("--no-chain-bound", action="store_true")
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    res = run(pixels=a.pixels, voxel=a.voxel, frames=[int(x) for x in a.frames.split(",")],
              bones=[int(x) for x in a.bones.split(",")], seeds=a.seeds, variants=a.variants.split(","),
              costs=a.costs.split(","), chain_bound=not a.no_chain_bound)
    from core.io.atomic import print_json

    print_json(res, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
