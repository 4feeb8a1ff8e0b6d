"""Is the harder trial's Cramér–Rao bound right? (``python -m core.studies.tracking.hard_bound_check``)

On one NVIDIA H200 (``resources/benchmarks/tracking_hard_stats_h200.json``) the talus's per-frame
RMS error came out 0.81–1.05× the bound that :meth:`core.studies.tracking.hard_trial.HardRun.bounds`
computed, and no unbiased per-frame estimator can beat a correct bound. Three explanations: the
bound is mis-computed for this trial, the tracker's estimate is not one of a single frame
(shrinkage toward its start), or sampling. This study tells them apart on one frame of the trial
at reduced size, on the CPU:

* :func:`bounds_at` — the bound of each tracked bone from four renderers of its pose
  derivatives: the trial's (the tracker's CT — the truth blurred, resampled and noisy — under the
  tracker's thresholded transfer), the truth's volume under the tracker's transfer, the CT under
  the generator's transfer, and the truth's volume under the generator's transfer (the renderer
  that synthesised the frames, which the bound's derivation asks for: :mod:`core.tracking.bound`);
  plus the information left after the chain's PSF, glare and read noise
  (:func:`core.tracking.bound.chain_information`) from the truth.
* :func:`noise_check` — the frames' own per-pixel noise over many draws of one frame (the trial's
  chain: quanta, PSF, glare, roll-off, distortion, read noise, 12 bits, flatfield, the 3 %-wrong
  inverse) against the bound's ``exp(-L) / N`` (relative fluence), per pixel and summed over 8×8
  blocks (the blur moves noise between neighbours but keeps the sum).
* :func:`spread` — the spread (standard deviation over noise draws, about their mean) of three
  estimates started at the truth: an oracle Poisson maximum-likelihood fit with the truth's
  renderer and every other structure known (Fisher scoring, as ``tests/core/tracking/
  test_tracking_bound.py`` checks the bound) on quanta-only frames and on the trial's frames, and
  the tracker's own registration (the trial's options: ``newton``, GC of the components, the
  likelihood final stage, the other tracked bones subtracted at their true poses), its similarity
  optimum and its stage; the tracker also from a start ``far`` off the truth on the same draws
  (shrinkage toward the start shows as a difference).
* :func:`response` — the tracker's estimate on noise-free frames with the bone moved by ±``δ``
  along each axis, started at the unmoved truth: ``M = dθ̂/dθ`` (``I`` for an estimator that is
  locally unbiased; a smaller response would shrink the spread below the bound).

``--bound-ratio FRAMES`` (:func:`bound_ratio`): only the CT's bound against the truth's, on frames
of the trial at any size (the H200's 1024², 0.5 mm by default), beside a run's JSON.

Results (``resources/benchmarks/tracking_hard_bound_check_cpu.json``, this 2-core CPU machine)
-----------------------------------------------------------------------------------------------
The bound was mis-computed: the CT's derivatives gave a bound 1.3-1.7× the truth's — at 192², 1 mm
(seed 0, frame 1) talus 0.0378 mm / 0.140° against 0.0238 mm / 0.0863°; at 1024², 0.5 mm on the
H200 run's frames 0.61-0.62× (mm) and 0.60× (°) for the talus, 0.75-0.76 / 0.66-0.68 the tibia,
0.60-0.61 / 0.58-0.59 the calcaneus, steady from frame to frame. The CT's blur, resampling and
noise do it; the tracker's transfer does not (the truth's volume under it: within 1 % of the
truth's bound at 192², 4-5 % below it at 1024²). The chain after the quanta (``truth_chain``)
raises the truth's bound by 1-6 % at 1024² (frame 0), 7-8 % at 192². At 192²: the oracle fit on
quanta-only frames spreads 0.94 / 0.92× the truth's bound (64 draws) and 0.59 / 0.57× the CT's; on
the trial's frames 1.20 / 1.15× the truth's (1.11 / 1.07× the chain's, whose read noise matters at
192²'s 12,200 quanta per pixel). The frames' noise is the bound's: quanta-only draws 0.99-1.02×
``exp(-L) / N`` per pixel, the trial's frames 0.40× per pixel and 0.90-0.92× in 8×8 sums (the
glare's ``(1 - 0.05)²``). The tracker from the truth spreads 1.75 / 1.36× the truth's bound (stage;
the similarity 1.92 / 1.58×), 1.10 / 0.84× the CT's — the H200's "below the bound" at small size;
its response ``M`` has a diagonal of 0.97-1.18 and a start 1 mm / 1.5° off moves its result by
0.003 mm / 0.009° RMS (6 draws): no shrinkage toward the start or the prediction.

JSON on stdout (``--out``: also to a file).
"""

from __future__ import annotations

import platform
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from core.geometry.transforms import pose_from_params
from core.studies.tracking import _study_cli as cli
from core.studies.tracking.acceptance import pose_errors

__all__ = ["bound_ratio", "bounds_at", "main", "noise_check", "oracle_ml", "response", "run", "spread",
           "trial_options"]


def trial_options(final: bool = True):
    """The harder trial's registration options on the H200 (``--search newton --metric components
    --final likelihood``)."""
    from core.tracking.trial import TrackingOptions

    reg = TrackingOptions(refine_likelihood=final).registration
    return replace(reg, search="newton",
                   terms=tuple(replace(t, options={**t.options, "components": True}) if t.kind == "gc" else t
                               for t in reg.terms))


def _renderers(hr, device):
    """The four derivative renderers of :func:`bounds_at` (the tracked bones, in order)."""
    from core.render import DRRRenderer

    nb = len(hr.names)
    scene_mu = hr.scene.bone_transfer
    return {"trial": hr.renderer,
            "truth_tracker_transfer": DRRRenderer(
                hr.scene.rig, [v.to_attenuation(hr.transfer) for v in hr.trial.truth_volumes], device=device),
            "ct_scene_transfer": DRRRenderer(hr.scene.rig, [m.volume.to_attenuation(scene_mu)
                                                            for m in hr.models], device=device),
            "truth": DRRRenderer(hr.scene.rig, [v.to_attenuation(scene_mu) for v in hr.scene.bones[:nb]],
                                 device=device)}


def _pair(pb) -> list[float]:
    return [round(float(pb.rms_mm), 5), round(float(pb.rms_deg), 5)]


def bounds_at(hr, f: int, *, device: str | None = None, chain: bool = True) -> dict:
    """Per tracked bone: ``[rms_mm, rms_deg]`` of the bound from each renderer (module docs), the
    chain's (``chain``), and the truth's over the trial's."""
    from core.studies.tracking.bound_gap import _chain_terms
    from core.tracking.bound import chain_information, pose_bound

    L = hr.line_integrals(f)
    N = [m.photons_per_pixel for m in hr.scene.imaging]
    T = hr.truth(f)
    rs = _renderers(hr, device)
    out = {}
    for b, (n, m) in enumerate(zip(hr.names, hr.models, strict=True)):
        d = {k: _pair(pose_bound(r, b, T[b], m.centroid, line_integral=L, quanta_per_pixel=N))
             for k, r in rs.items()}
        if chain:
            J = chain_information(rs["truth"], b, T[b], m.centroid, line_integral=L, quanta_per_pixel=N,
                                  **_chain_terms(hr))
            C = np.linalg.inv(J)
            d["truth_chain"] = [round(float(np.sqrt(np.trace(C[:3, :3]))), 5),
                                round(float(np.sqrt(np.trace(C[3:, 3:]))), 5)]
        d["truth_over_trial"] = [round(d["truth"][i] / d["trial"][i], 4) for i in range(2)]
        out[n] = d
    return out


def _draw(hr, L, f: int, k: int, *, quanta_only: bool = False) -> list[np.ndarray]:
    """Noise draw ``k`` of frame ``f`` through the trial's chain (:meth:`HardRun.frames`), or of the
    quantum stage alone (relative fluence)."""
    out = []
    for v, (m, c) in enumerate(zip(hr.scene.imaging, hr.corrections, strict=True)):
        g = np.random.default_rng([int(hr.scene.seed), 0x5EED, int(f), int(v), int(k)])
        if quanta_only:
            n0 = m.photons_per_pixel
            out.append(g.poisson(n0 * np.exp(-np.asarray(L[v], np.float64))) / n0)
        else:
            out.append(c.unwarp(m.to_float(m.apply(L[v], rng=g))))
    return out


def noise_check(hr, f: int, bone: str = "talus", *, draws: int = 64, block: int = 8) -> dict:
    """The frames' per-pixel variance over ``draws`` noise draws of frame ``f`` against the bound's
    ``exp(-L) / N`` (relative fluence), over ``bone``'s region, per view: the median ratio per
    pixel and the ratio of ``block``×``block`` sums (module docs)."""
    from core.tracking.cost import search_roi

    b = hr.names.index(bone)
    L = hr.line_integrals(f)
    T = hr.truth(f)
    roi = search_roi(hr.renderer, T[b], b, views=range(len(hr.scene.rig)), center=hr.models[b].centroid,
                     reach_mm=0.0, margin_px=6)
    out = {}
    for label, qo in (("trial_chain", False), ("quanta_only", True)):
        S = np.array([_draw(hr, L, f, k, quanta_only=qo) for k in range(draws)])  # (draws, V, H, W)
        views = []
        for v, (u0, v0, w, h) in enumerate(roi):
            w, h = (w // block) * block, (h // block) * block
            y = S[:, v, v0:v0 + h, u0:u0 + w]
            n0 = hr.scene.imaging[v].photons_per_pixel
            var0 = np.exp(-np.asarray(L[v], np.float64)[v0:v0 + h, u0:u0 + w]) / n0
            ok = np.all(y > 0, axis=0)
            r = np.var(y, axis=0, ddof=1) / var0
            ys = y.reshape(draws, h // block, block, w // block, block).sum(axis=(2, 4))
            v0s = var0.reshape(h // block, block, w // block, block).sum(axis=(1, 3))
            oks = ok.reshape(h // block, block, w // block, block).all(axis=(1, 3))
            rs = np.var(ys, axis=0, ddof=1) / v0s
            views.append({"pixels": int(ok.sum()),
                          "pixel_var_ratio_median": round(float(np.median(r[ok])), 4),
                          "pixel_var_ratio_mean": round(float(np.mean(r[ok])), 4),
                          f"block{block}_var_ratio_median": round(float(np.median(rs[oks])), 4),
                          f"block{block}_var_ratio_mean": round(float(np.mean(rs[oks])), 4)})
        out[label] = views
    out["draws"] = draws
    return out


def oracle_ml(renderer, b: int, truth, center, frames, L, N, *, iterations: int = 4, h=(0.03, 0.03),
              margin_px: int = 6) -> np.ndarray:
    """``(M, 6)`` errors (:func:`pose_errors`) of the Poisson maximum-likelihood pose of bone ``b``
    from ``frames`` (``(M, V, H, W)`` relative fluence, counts ``N · frame``) by Fisher scoring
    from the truth, with ``renderer`` (the truth's) and every other structure known: the frame's
    line integrals ``L`` less the bone's own DRR at the truth."""
    from core.tracking.cost import search_roi

    V = len(renderer.cameras)
    roi = search_roi(renderer, truth, b, views=range(V), center=center, reach_mm=1.0, margin_px=margin_px)
    Hm, Wm = int(roi[:, 3].max()), int(roi[:, 2].max())

    def render(P):  # (B, V, Hm, Wm)
        return renderer.render(P[:, None], views=list(range(V)), bones=[b],
                               roi=roi[None, :, None, :]).numpy()[:, :, 0].astype(np.float64)

    own = render(np.asarray(truth, float)[None])[0]
    rest = np.zeros((V, Hm, Wm))
    valid = np.zeros((V, Hm, Wm), bool)
    n = np.zeros((len(frames), V, Hm, Wm))
    Nv = np.asarray(N, float)[:, None, None]
    for v, (u0, v0, w, hh) in enumerate(roi):
        rest[v, :hh, :w] = np.asarray(L[v], np.float64)[v0:v0 + hh, u0:u0 + w] - own[v, :hh, :w]
        valid[v, :hh, :w] = True
        n[:, v, :hh, :w] = np.asarray(frames)[:, v, v0:v0 + hh, u0:u0 + w] * Nv[v]
    valid &= np.all(n > 0, axis=0)
    M = len(frames)
    x = np.zeros((M, 6))
    step = np.array([h[0]] * 3 + [h[1]] * 3)
    E = np.concatenate([np.zeros((1, 6)), np.diag(step), -np.diag(step)])
    for _ in range(iterations):
        X = (x[:, None, :] + E[None]).reshape(-1, 6)
        P = pose_from_params(np.c_[X[:, :3], np.radians(X[:, 3:])], center=center, base=truth)
        img = render(P).reshape(M, 13, V, Hm, Wm)
        lam = Nv * np.exp(-(img[:, 0] + rest)) * valid
        G = ((img[:, 1:7] - img[:, 7:]) / (2 * step[None, :, None, None, None])).reshape(M, 6, -1)
        lf, nf = lam.reshape(M, -1), (n * valid).reshape(M, -1)
        info = np.einsum("mip,mp,mjp->mij", G, lf, G)
        score = np.einsum("mip,mp->mi", G, lf - nf)
        x = x + np.linalg.solve(info, score[..., None])[..., 0]
    P = pose_from_params(np.c_[x[:, :3], np.radians(x[:, 3:])], center=center, base=truth)
    return np.array([pose_errors(p, truth, center) for p in P])


def _register(hr, imgs, b: int, start, T, options):
    """The tracker's registration of bone ``b`` (the similarity, then the final stage with the other
    tracked bones subtracted at their true poses); ``(stage error, similarity error)``."""
    from core.tracking.cost import prepare_frame
    from core.tracking.final_stage import stage_neighbours
    from core.tracking.register import register

    m = hr.models[b]
    others = [i for i in range(len(hr.names)) if i != b]
    with stage_neighbours((T[others], others)):
        r = register(hr.renderer, prepare_frame(imgs), bone=b, initial_pose=start, center=m.centroid,
                     options=options, outline=m.outline)
    fit = getattr(r, "fit", None)
    sim = fit.similarity.pose if fit is not None and getattr(fit, "similarity", None) is not None else r.pose
    return pose_errors(r.pose, T[b], m.centroid), pose_errors(sim, T[b], m.centroid)


def _summary(E: np.ndarray, bound) -> dict:
    """Spread (about the mean) and mean of errors ``E (M, 6)`` and the spread over ``bound``
    (``[rms_mm, rms_deg]``)."""
    E = np.asarray(E, float)
    mu = E.mean(axis=0)
    D = E - mu
    s_mm = float(np.sqrt(np.mean(np.sum(D[:, :3] ** 2, axis=1)) * len(E) / (len(E) - 1)))
    s_deg = float(np.sqrt(np.mean(np.sum(D[:, 3:] ** 2, axis=1)) * len(E) / (len(E) - 1)))
    return {"spread_mm": round(s_mm, 5), "spread_deg": round(s_deg, 5),
            "mean": mu.round(5).tolist(), "sd": D.std(axis=0, ddof=1).round(5).tolist(),
            "spread_over_bound": {k: [round(s_mm / v[0], 3), round(s_deg / v[1], 3)]
                                  for k, v in bound.items()}}


def spread(hr, f: int, bone: str = "talus", *, draws: int = 24, tracker_draws: int | None = None,
           far=(1.0, 1.5), far_draws: int = 8, bounds: dict | None = None, device: str | None = None,
           progress=None) -> dict:
    """The estimates' spread over noise draws of frame ``f`` (module docs); ``bounds``
    (:func:`bounds_at`'s entry of ``bone``) to divide by."""
    b = hr.names.index(bone)
    L = hr.line_integrals(f)
    T = hr.truth(f)
    m = hr.models[b]
    N = [im.photons_per_pixel for im in hr.scene.imaging]
    truth_r = _renderers(hr, device)["truth"]
    bd = {k: v for k, v in (bounds or {}).items() if k in ("trial", "truth", "truth_chain")}
    out = {"draws": draws}
    for label, qo in (("oracle_ml_quanta_only", True), ("oracle_ml_trial_frames", False)):
        frames = np.array([_draw(hr, L, f, k, quanta_only=qo) for k in range(draws)])
        out[label] = _summary(oracle_ml(truth_r, b, T[b], m.centroid, frames, L, N), bd)
    nt = draws if tracker_draws is None else min(int(tracker_draws), draws)
    opts = trial_options()
    st, si, far_e = [], [], []
    t0 = time.perf_counter()
    g = np.random.default_rng(11)
    for k in range(nt):
        imgs = _draw(hr, L, f, k)
        e1, e0 = _register(hr, imgs, b, T[b], T, opts)
        st.append(e1)
        si.append(e0)
        if k < far_draws:
            from core.studies.tracking.acceptance import _random_offset

            start = pose_from_params(_random_offset(g, *far), center=m.centroid, base=T[b])
            far_e.append(_register(hr, imgs, b, start, T, opts)[0])
        if progress:
            progress(k + 1, nt)
    out["tracker_stage"] = _summary(np.array(st), bd)
    out["tracker_similarity"] = _summary(np.array(si), bd)
    out["tracker_draws"] = nt
    out["tracker_s_per_registration"] = round((time.perf_counter() - t0) / (nt + len(far_e)), 2)
    if far_e:
        d = np.array(far_e) - np.array(st[: len(far_e)])
        out["far_start"] = {"start_error": f"{far[0]} mm, {far[1]} deg", "draws": len(far_e),
                            "max_abs_difference_from_truth_start": np.abs(d).max(axis=0).round(5).tolist(),
                            "rms_difference_mm": round(float(np.sqrt(np.mean(np.sum(d[:, :3] ** 2, 1)))), 5),
                            "rms_difference_deg": round(float(np.sqrt(np.mean(np.sum(d[:, 3:] ** 2, 1)))), 5)}
    return out


def _noise_free(hr, L) -> list[np.ndarray]:
    return [c.unwarp(m.to_float(m.expected_dn(L[v])))
            for v, (m, c) in enumerate(zip(hr.scene.imaging, hr.corrections, strict=True))]


def response(hr, f: int, bone: str = "talus", *, delta=(0.1, 0.3), device: str | None = None) -> dict:
    """The tracker's ``M = dθ̂/dθ`` (6×6; columns the true moves) from noise-free frames with the
    bone moved by ±``delta`` (mm, degrees) along each axis, every registration started at the
    unmoved truth; and the noise-free frame's error (the cost's bias)."""
    b = hr.names.index(bone)
    L = np.asarray(hr.line_integrals(f), np.float64)
    T = hr.truth(f)
    m = hr.models[b]
    scene_r = hr.scene.renderer(device=device)._bones  # the bones the frames were rendered from
    own = scene_r.render(hr.scene.poses(f)[None, [b]], bones=[b], roi="full").numpy()[0][:, 0]
    own = own.astype(np.float64)
    opts = trial_options()
    e0, s0 = _register(hr, _noise_free(hr, L), b, T[b], T, opts)
    h = np.array([delta[0]] * 3 + [delta[1]] * 3)
    Ms, Msim = np.zeros((6, 6)), np.zeros((6, 6))
    for i in range(6):
        est = []
        for sgn in (1, -1):
            x = np.zeros(6)
            x[i] = sgn * h[i]
            P = pose_from_params(np.r_[x[:3], np.radians(x[3:])], center=m.centroid, base=T[b])
            moved = scene_r.render(P[None, None], bones=[b], roi="full").numpy()[0][:, 0].astype(np.float64)
            Tm = T.copy()
            Tm[b] = P
            e, s = _register(hr, _noise_free(hr, L - own + moved), b, T[b], Tm, opts)
            est.append((e + x, s + x))  # the estimate relative to the unmoved truth
        Ms[:, i] = (est[0][0] - est[1][0]) / (2 * h[i])
        Msim[:, i] = (est[0][1] - est[1][1]) / (2 * h[i])
    return {"delta": list(delta), "noise_free_error_stage": e0.round(5).tolist(),
            "noise_free_error_similarity": s0.round(5).tolist(),
            "stage_M": Ms.round(3).tolist(), "stage_M_diagonal": np.diag(Ms).round(3).tolist(),
            "similarity_M_diagonal": np.diag(Msim).round(3).tolist()}


def bound_ratio(*, pixels: int = 1024, spacing: float = 0.5, n_frames: int = 40, seed: int = 0,
                frames=(0, 20), device: str | None = "cpu", cache: str | None = None,
                reference: str | None = None) -> dict:
    """The trial's bound from the tracker's CT against the truth's (:meth:`HardRun.bounds`
    ``derivatives``) on ``frames`` of the trial as tracked (the H200's size by default: the same
    seeded frames as ``n_frames`` there), per bone; ``reference`` a ``hard_trial`` JSON (or one
    with ``seeds``) whose ``per_frame_bound`` of those frames the CT's bound should reproduce."""
    from core.studies.tracking.hard_trial import HardRun

    t0 = time.perf_counter()
    hr = HardRun(n_frames=n_frames, pixels=pixels, spacing=spacing, seed=seed, device=device, cache=cache)
    frames = [int(f) for f in frames]
    old = hr.bounds(frames, derivatives="tracker")
    new = hr.bounds(frames)
    ref = None
    if reference:
        import json

        d = json.loads(Path(reference).read_text(encoding="utf-8"))
        d = d["seeds"][str(seed)] if "seeds" in d else d
        ref = next(iter(d["runs"].values()))["bones"]
    out = {"pixels": pixels, "voxel_mm": spacing, "n_frames": n_frames, "seed": seed, "frames": frames,
           "bones": {}}
    for n in hr.names:
        o, t = np.asarray(old[n]), np.asarray(new[n])
        e = {"tracker_ct": o.round(5).tolist(), "truth": t.round(5).tolist(),
             "truth_over_tracker_ct": (t / o).round(4).tolist(),
             "rms_truth_over_rms_tracker_ct":
                 np.sqrt(np.mean(t**2, axis=0) / np.mean(o**2, axis=0)).round(4).tolist()}
        if ref is not None:
            e["reference_per_frame_bound"] = [ref[n]["per_frame_bound"][f] for f in frames]
        out["bones"][n] = e
    out["s"] = round(time.perf_counter() - t0, 1)
    return out


def run(*, pixels: int = 192, spacing: float = 1.0, n_frames: int = 4, frame: int = 1, seed: int = 0,
        bone: str = "talus", draws: int = 24, tracker_draws: int | None = None, noise_draws: int = 64,
        far_draws: int = 8, with_response: bool = True, device: str | None = "cpu", cache: str | None = None,
        progress=None) -> dict:
    """All four checks on frame ``frame`` of the harder trial (module docs); JSON-ready."""
    from core.studies.tracking.hard_trial import HardRun

    t0 = time.perf_counter()
    hr = HardRun(n_frames=n_frames, pixels=pixels, spacing=spacing, seed=seed, device=device, cache=cache)
    out = {"study": "core.studies.tracking.hard_bound_check", "machine": platform.machine(),
           "config": {"pixels": pixels, "voxel_mm": spacing, "frames": n_frames, "frame": frame, "seed": seed,
                      "bone": bone, "quanta_per_pixel": [m.photons_per_pixel for m in hr.scene.imaging],
                      "psf_sigma_px": [m.psf_sigma_px for m in hr.scene.imaging],
                      "options": trial_options().to_dict()}}
    out["bounds"] = bounds_at(hr, frame, device=device)
    out["noise"] = noise_check(hr, frame, bone, draws=noise_draws)
    out["spread"] = spread(hr, frame, bone, draws=draws, tracker_draws=tracker_draws, far_draws=far_draws,
                           bounds=out["bounds"][bone], device=device, progress=progress)
    if with_response:
        out["response"] = response(hr, frame, bone, device=device)
    out["total_s"] = round(time.perf_counter() - t0, 1)
    return out


def main(argv=None) -> int:
    p = cli.parser("core.studies.tracking.hard_bound_check", __doc__)
    p.add_argument("--pixels", type=int, default=192)
    p.add_argument("--voxel", type=float, default=1.0)
    p.add_argument("--frames", type=int, default=4)
    p.add_argument("--frame", type=int, default=1)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--bone", default="talus")
    p.add_argument("--draws", type=int, default=24)
    p.add_argument("--tracker-draws", type=int, default=None)
    p.add_argument("--noise-draws", type=int, default=64)
    p.add_argument("--far-draws", type=int, default=8)
    p.add_argument("--no-response", action="store_true")
    p.add_argument("--bound-ratio", default=None, metavar="FRAMES",
                   help="instead: the CT's bound against the truth's on these comma-separated frames")
    p.add_argument("--reference", default=None, help="with --bound-ratio: a hard_trial JSON to compare with")
    p.add_argument("--device", default="cpu")
    p.add_argument("--cache", default=None)
    cli.add_output(p)
    a = p.parse_args(argv)
    import sys

    if a.bound_ratio:
        return cli.finish(bound_ratio(pixels=a.pixels, spacing=a.voxel, n_frames=a.frames, seed=a.seed,
                                      device=a.device, cache=a.cache, frames=cli.ints(a.bound_ratio),
                                      reference=a.reference), a)
    res = run(pixels=a.pixels, spacing=a.voxel, n_frames=a.frames, frame=a.frame, seed=a.seed, bone=a.bone,
              draws=a.draws, tracker_draws=a.tracker_draws, noise_draws=a.noise_draws, far_draws=a.far_draws,
              with_response=not a.no_response, device=a.device, cache=a.cache,
              progress=lambda k, n: print(f"{k}/{n}", file=sys.stderr, flush=True))
    return cli.finish(res, a)


if __name__ == "__main__":
    raise SystemExit(main())
