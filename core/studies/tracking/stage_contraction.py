"""Why the likelihood final stage's Gauss–Newton steps contract slowly, and the stage's result
against its start (``python -m core.studies.tracking.stage_contraction``).

The scene is :mod:`core.studies.tracking.stage_residue`'s (held-out seed 4, the grid correction,
the high-pass scaled from 4 px at 1024², the other bones at their true poses subtracted, the
stored 1024² runs' poses as starts):

* ``cause`` — one bone-frame (the calcaneus's frame 30) on frames of the image's parts
  (:func:`core.studies.tracking.stage_limits.component_frames`: the bones alone, with the soft
  tissue and walkway, through the blur and glare, the trial's whole chain), the noisy frame and a
  frame the model's own renderer made (``self``): Gauss–Newton's steps from a stored start to
  ``tol`` (:func:`gauss_newton`), how much each is of the one before, and per pose axis the slope
  of ``JᵀWr`` over ±0.05 mm / ° about the end against ``JᵀWJ``'s diagonal (θ: 1 where the
  curvature is Gauss–Newton's; :func:`curvature_ratios`);
* ``psf`` — the ``cause`` frame's whole chain (noise-free) and noisy frame with the DRR blurred by
  the PSF estimated from synthetic pinhole frames (:func:`core.studies.tracking.bound_gap.
  estimated_psf`, what a lab measures) and by Gaussians of its σ times :data:`PSF_WIDTHS`: whether
  a PSF brings θ to 1;
* ``frames`` — per bone, frames over the trial, the stage as the tracker runs it
  (:func:`core.studies.tracking.stage_residue.stage_from`) from the truth and the stored runs'
  poses under each rule of :data:`RULES` (the fewer steps and to tol, with and without the estimated
  PSF): the steps, how far apart the starts' results are, and the error (from the run without the
  stage's pose, where the tracker starts the stage) over the Cramér–Rao bound at this size
  (:func:`core.studies.tracking.acceptance.cramer_rao`). (The steps' secant length,
  ``SECANT_STEPS``, and its rules ``secant`` and ``exact_secant`` are removed: they did not pay;
  ``tracking_stage_contraction_cpu.json`` keeps what they measured.)

Measured: :mod:`core.tracking.likelihood_steps`' docs (the cause) and the README paragraph after
"What the stage leaves on seed 4" (``resources/benchmarks/tracking_stage_contraction_cpu.json``).
"""

from __future__ import annotations

import time

import numpy as np

from core.studies.tracking import _study_cli as cli

__all__ = ["RULES", "curvature_ratios", "gauss_newton", "main", "run"]

#: the ``frames`` part's rules: label -> (to tol, the DRR blurred by the PSF estimated from pinhole
#: frames: ``psf`` part)
RULES = {"fewer": (False, False), "exact": (True, False), "psf": (False, True), "psf_exact": (True, True)}
#: the ``cause`` part's frames of the image's parts (stage_limits.COMPONENTS' names), then the
#: noisy frame and the model renderer's own (``self``)
CAUSE_KINDS = ("bones", "bones+tissue", "all", "all/blur", "all/full", "noisy", "self")
FRAMES = tuple(range(5, 100, 10))
#: the ``psf`` part's frames and the Gaussian PSFs' widths over the estimated PSF's σ (second moment)
PSF_KINDS = ("all/full", "noisy")
PSF_WIDTHS = (1.0, 1.2, 1.5, 2.0)
#: the ``frames`` part's starts: the truth, the stored runs' poses (``none``, ``stage``) and this
#: size's similarity optimum from the run without the stage's pose (``similarity``:
#: :func:`~core.studies.tracking.stage_residue.similarity`, a registration a frame). The error is
#: that from ``similarity`` where it is run, else from ``none`` (the 1024² similarity's pose, whose
#: noise is not this frame's: a stop part-way to the stage's optimum keeps some of it)
STARTS = ("truth", "none", "stage")


def _engine(ts, frame, f: int, b: int, base, hp: float, psf=None):
    """The stage's engine of bone ``b`` set on ``frame`` about ``base`` as
    :func:`~core.studies.tracking.stage_residue.stage_from` sets it (``psf``: its DRRs blurred by it)."""
    from core.studies.tracking.acceptance import study_options
    from core.studies.tracking.stage_residue import stage_engine

    o = study_options("joint", final="likelihood", final_highpass_px=hp).registration
    return stage_engine(ts, frame, b, base, o, ts.truth(f), psf=psf)


def gauss_newton(eng, *, h: float = 0.05, tol: float = 1e-3, iters: int = 20) -> dict:
    """Plain Gauss–Newton with the engine's weights from its base pose (no robust round, no stop
    but ``tol`` on every axis): the steps (mm, degrees), each one's length over the one before's,
    the end ``x``."""
    hv = np.full(6, float(h))
    x = np.zeros(6)
    steps = []
    for _ in range(int(iters)):
        s = eng.step(x, hv)
        d = np.linalg.solve(s["JJ"], s["Jr"])
        steps.append(d)
        x = x + d
        if np.all(np.abs(d) < tol):
            break
    n = [float(np.linalg.norm(d)) for d in steps]
    return {"x": x, "steps": len(steps), "first_step": steps[0].round(4).tolist(),
            "contraction": [round(n[i + 1] / n[i], 3) for i in range(len(n) - 1) if n[i] > 0][:6]}


def curvature_ratios(eng, x, *, h: float = 0.05, t: float = 0.05) -> dict:
    """About ``x``: per pose axis ``k`` the slope of ``JᵀWr``'s k-th entry over ``x ± t e_k`` against
    ``JᵀWJ``'s ``(k, k)`` entry (θ), the same along ``JᵀWJ``'s weakest eigenvector, and ``JᵀWJ``'s
    diagonal with half-steps 0.2 over 0.05 (the differences' step: a DRR rough in the pose gives
    a smaller one at the larger step)."""
    hv = np.full(6, float(h))
    s0 = eng.step(x, hv)
    H = s0["JJ"]
    th = []
    for k in range(6):
        e = np.zeros(6)
        e[k] = t
        gp, gm = eng.step(x + e, hv)["Jr"], eng.step(x - e, hv)["Jr"]
        th.append(-(gp[k] - gm[k]) / (2 * t) / H[k, k])
    v = np.linalg.eigh(H)[1][:, 0] * t
    gp, gm = eng.step(x + v, hv)["Jr"], eng.step(x - v, hv)["Jr"]
    weak = -float((gp - gm) @ v) / 2.0 / float(v @ H @ v)
    wide = np.diag(eng.step(x, np.full(6, 0.2))["JJ"]) / np.diag(H)
    return {"theta_axes": np.round(th, 3).tolist(), "theta_weakest": round(weak, 3),
            "jj_h02_over_h005": np.round(wide, 3).tolist()}


def _kind_frame(ts, f: int, b: int, kind: str):
    """Frame ``f`` of ``kind`` prepared (:data:`CAUSE_KINDS`)."""
    from core.studies.tracking.stage_limits import component_frames
    from core.studies.tracking.stage_residue import _frames_of
    from core.tracking.cost import prepare_frame

    if kind == "noisy":
        return _frames_of(ts, f, b, "noisy")
    if kind == "self":  # the bones' line integrals as the model's renderer makes them
        L = ts.renderer.render(ts.truth(f)[None], roi="full").numpy()[0].sum(axis=1).astype(np.float64)
        return prepare_frame([np.exp(-x).astype(np.float32) for x in L])
    return prepare_frame(component_frames(ts, f, (kind,))[kind])


_PSF: dict = {}


def _estimated_psf(ts) -> tuple:
    """The PSF estimated from view 0's synthetic pinhole frames (unit sum; kept per scene) and its σ
    (second moment, pixels)."""
    from core.studies.tracking.bound_gap import estimated_psf

    hit = _PSF.get(id(ts))
    if hit is None:
        est = np.asarray(estimated_psf(ts)[0], dtype=float)
        est = est / est.sum()
        r = np.arange(est.shape[0]) - est.shape[0] // 2
        hit = _PSF[id(ts)] = (est, float(np.sqrt((est * (r[:, None] ** 2 + r[None, :] ** 2)).sum() / 2.0)))
    return hit


def run(*, seed: int = 4, pixels: int = 512, voxel: float = 1.0, parts=("cause", "frames"),
        bones=("tibia", "talus", "calcaneus"), frames=FRAMES, cause=("calcaneus", 30), rules=tuple(RULES),
        starts=STARTS, device: str | None = "cpu", checkpoint=None) -> dict:
    """The study (module docs); returns the JSON-ready results."""
    from core.studies.tracking.acceptance import TrackingScene, cramer_rao, pose_errors
    from core.studies.tracking.stage_residue import RUNS, _frames_of, similarity, stage_from, stored_poses

    t0 = time.perf_counter()
    start_set = tuple(starts)
    ts = TrackingScene(n_frames=100, pixels=pixels, spacing=voxel, seed=seed, device=device,
                       correction="grid", phase=(0.0, 0.6))
    hp = 4.0 * pixels / 1024
    stored = {k: stored_poses(ts, p) for k, p in RUNS.items()}
    out = cli.header("core.studies.tracking.stage_contraction", seed=seed, pixels=pixels, voxel_mm=voxel,
                     highpass_px=hp, runs=RUNS)

    def save():
        out["seconds"] = round(time.perf_counter() - t0, 1)
        if checkpoint:
            checkpoint(out)

    if "cause" in parts:
        nm, f = cause
        b = ts.names.index(nm)
        rows = []
        for kind in CAUSE_KINDS:
            eng = _engine(ts, _kind_frame(ts, f, b, kind), f, b, stored["stage"][nm][f], hp)
            g = gauss_newton(eng)
            rows.append({"kind": kind, **{k: v for k, v in g.items() if k != "x"},
                         **curvature_ratios(eng, g["x"]),
                         "end_error": pose_errors(eng.poses(g["x"][None])[0], ts.truth(f)[b],
                                                  ts.models[b].centroid).round(4).tolist()})
            out["cause"] = {"bone": nm, "frame": f, "start": "stage", "rows": rows}
            save()
    if "psf" in parts:  # the DRR blurred by the PSF estimated from pinhole frames, and wider
        from core.imaging.psf import gaussian_psf

        nm, f = cause
        b = ts.names.index(nm)
        est, s_est = _estimated_psf(ts)
        rows = []
        for kind in PSF_KINDS:
            fr = _kind_frame(ts, f, b, kind)
            for label, k in (("none", None), ("estimated", est),
                             *((f"gaussian x{w:g}", gaussian_psf(w * s_est)) for w in PSF_WIDTHS)):
                eng = _engine(ts, fr, f, b, stored["stage"][nm][f], hp, psf=k)
                g = gauss_newton(eng)
                rows.append({"kind": kind, "psf": label, **{q: v for q, v in g.items() if q != "x"},
                             **curvature_ratios(eng, g["x"]),
                             "end_error": pose_errors(eng.poses(g["x"][None])[0], ts.truth(f)[b],
                                                      ts.models[b].centroid).round(4).tolist()})
                out["psf"] = {"bone": nm, "frame": f, "estimated_sigma_px": round(s_est, 3), "rows": rows}
                save()
    if "frames" in parts:
        res = out["frames"] = {}
        ref = "similarity" if "similarity" in start_set else "none"  # (the tracker's start)
        bound = cramer_rao(ts, frames)
        out["cramer_rao"] = bound
        for nm in bones:
            b = ts.names.index(nm)
            c = ts.models[b].centroid
            rows = []
            for f in frames:
                if f not in stored["none"].get(nm, {}):
                    continue
                fr = _frames_of(ts, f, b, "noisy")
                starts = {"truth": ts.truth(f)[b],
                          **{k: p[nm][f] for k, p in stored.items() if f in p.get(nm, {})}}
                if "similarity" in start_set:  # (this size's similarity optimum, the stage's start)
                    starts["similarity"] = similarity(ts, fr, f, b, stored["none"][nm][f])
                starts = {k: v for k, v in starts.items() if k in start_set}
                row = {"frame": f, "start_error": {k: pose_errors(P0, ts.truth(f)[b], c).round(4).tolist()
                                                   for k, P0 in starts.items()}}
                for rule in rules:
                    exact, blur = RULES[rule]
                    r = {}
                    for k, P0 in starts.items():
                        r[k] = stage_from(ts, fr, f, b, P0, highpass_px=hp, exact=exact,
                                          psf=_estimated_psf(ts)[0] if blur else None)
                    E = np.array([r[k]["error"] for k in starts])
                    row[rule] = {"steps": {k: r[k]["steps"] for k in starts},
                                 "error": {k: r[k]["error"] for k in starts},
                                 "spread": (E.max(0) - E.min(0)).round(4).tolist()}
                row["reference"] = ref
                rows.append(row)
                res[nm] = {"rows": rows, "summary": _summary(rows, rules, bound.get(nm))}
                save()
    save()
    return out


def _summary(rows: list, rules, bound: dict | None) -> dict:
    """Per rule: steps a bone-frame (mean over frames and starts, and from the reference start:
    :data:`STARTS`), the starts' spread (RMS over frames per axis, the largest in mm; where more than
    one start), the error from the reference start (RMS mm, degrees) and over the bound."""
    out = {}
    for rule in rules:
        R = [r[rule] for r in rows if rule in r]
        if not R:
            continue
        S = np.array([r["spread"] for r in R])
        ref = rows[0].get("reference", "none")
        E = np.array([r["error"][ref] for r in R])
        mm = float(np.sqrt(np.mean(np.sum(E[:, :3] ** 2, axis=1))))
        deg = float(np.sqrt(np.mean(np.sum(E[:, 3:] ** 2, axis=1))))
        steps = [v for r in R for v in r["steps"].values()]
        d = {"frames": len(R), "steps_mean": round(float(np.mean(steps)), 2),
             "steps_from_reference": round(float(np.mean([r["steps"][ref] for r in R])), 2),
             "spread_rms": np.sqrt((S ** 2).mean(0)).round(4).tolist(),
             "spread_max_mm": round(float(S[:, :3].max()), 4),
             "error_rms_mm": round(mm, 4), "error_rms_deg": round(deg, 4)}
        if bound:
            d["over_bound_mm"] = round(mm / bound["rms_mm"], 3)
            d["over_bound_deg"] = round(deg / bound["rms_deg"], 3)
        out[rule] = d
    return out


def main(argv=None) -> int:
    p = cli.parser("core.studies.tracking.stage_contraction", __doc__)
    p.add_argument("--seed", type=int, default=4)
    p.add_argument("--pixels", type=int, default=512)
    p.add_argument("--voxel", type=float, default=1.0)
    p.add_argument("--parts", default="cause,frames")
    p.add_argument("--bones", default="tibia,talus,calcaneus")
    p.add_argument("--frames", default=",".join(map(str, FRAMES)))
    p.add_argument("--rules", default=",".join(RULES))
    p.add_argument("--starts", default=",".join(STARTS))
    p.add_argument("--device", default="cpu")
    cli.add_output(p)
    a = p.parse_args(argv)
    res = run(seed=a.seed, pixels=a.pixels, voxel=a.voxel, parts=tuple(cli.names(a.parts)),
              bones=tuple(cli.names(a.bones)), frames=tuple(cli.ints(a.frames)),
              rules=tuple(cli.names(a.rules)), starts=tuple(cli.names(a.starts)), device=a.device,
              checkpoint=cli.checkpoint(a))
    return cli.finish(res, a)


if __name__ == "__main__":
    raise SystemExit(main())
