"""The Gauss–Newton search on coarse views, traced (``python -m core.studies.tracking.newton_coarse``).

The acceptance trial at 256² (:func:`core.studies.tracking.acceptance.tracking_scene`, its default
grid correction), every ``--stride``-th frame tracked sequentially from the truth moved 5 mm / 5° at
the first (as :func:`core.studies.tracking.search_robustness.strided`), one bone (``--bone``, the
scene keeps all three), with the search's state step by step: per step of every search the cost,
α before and after it, the correction, the moments' gradient, the roughness and, for an accepted
step, the correction's part along each eigenvector of αH and the secant estimate from the
corrected gradients' change against the one with the correction held fixed between the step's two
ends (the moments' change; the search's since the correction's own change was taken out of it).
``--gradient moments`` gives the search the moments' gradient and :data:`FINAL_STEP` half-steps on
any pixels (the search before :func:`~core.tracking.register_options.newton_step`'s
coarse form). ``--deep F,F,...``: at those frames' searches' ends also the cost along the bone's
rotation about z through the truth, and at the truth the moments' gradient, the scores' central
differences and the Newton steps with and without the correction (:func:`_probe`).

``--singles P``: instead, one registration per bone, frame (0-18, every second) and start (two,
0.5 mm / 1° off the truth) at P² (:func:`singles`; ``--correction model`` below 192², where the
grid fit finds no grid; ``--trial hard --voxel V``: the harder trial's frames 0-4, four starts
each). The JSON goes to stdout (and ``--out``);
``resources/benchmarks/tracking_newton_coarse_eigen_cpu.json`` has what it measured.
"""

from __future__ import annotations

import argparse
import time
from contextlib import contextmanager

import numpy as np

__all__ = ["main", "run", "singles", "traced"]


def _probe(lm, cost, x, truth, deep: bool) -> dict:
    """At a search's end: the truth in the search's parameters, the cost (the scores, each pose
    over its own domain) along the line from ``x`` to it; with ``deep`` also the cost along the
    last axis (rotation about z) through the truth (a quadratic's minimum fitted to it), and at
    the truth the moments' gradient, the scores' central differences at 1, 2 and 3 times the
    search's half-steps and the Levenberg–Marquardt step the search's last correction and α give."""
    from core.geometry.transforms import params_from_pose

    p = params_from_pose(truth, center=cost.center, base=cost.base)
    t = np.r_[p[:3], np.degrees(p[3:])]
    x = np.asarray(x, dtype=float)
    ts = np.linspace(0.0, 1.0, 5)
    line = cost(x[None] + ts[:, None] * (t - x)[None])
    out = {"truth_x": np.round(t, 4).tolist(), "line_t": ts.tolist(), "line_cost": np.round(line, 6).tolist()}
    if not deep:
        return out
    dz = np.linspace(-2.5, 2.5, 21)
    X = np.repeat(t[None], len(dz), axis=0)
    X[:, 5] += dz
    cz = cost(X)
    a2, a1, _ = np.polyfit(dz, cz, 2)
    s = cost.step(t, lm.h)
    diffs = {}
    for m in (1, 2, 3):
        c = cost.step(t, m * lm.h).costs
        diffs[str(m)] = np.round((c[1::2] - c[2::2]) / (2 * m * lm.h), 5).tolist()
    corr = getattr(lm, "_last_corr", np.zeros(6))
    A = lm.alpha * s.H
    out.update(rz_scan_deg=dz.tolist(), rz_scan_cost=np.round(cz, 6).tolist(),
               rz_scan_min_deg=round(float(-a1 / (2 * a2)), 3) if a2 > 0 else None,
               rz_scan_curvature=float(2 * a2), H_rz=float(s.H[5, 5]),
               g_moments_at_truth=np.round(s.g, 5).tolist(), score_differences_at_truth=diffs,
               last_correction=np.round(corr, 5).tolist(),
               newton_moments_at_truth=np.round(np.linalg.solve(A, -s.g), 4).tolist(),
               newton_corrected_at_truth=np.round(np.linalg.solve(A, -(s.g + corr)), 4).tolist())
    return out


#: per frame tracked, the true pose of the traced bone and its first view's image (set by :func:`run`
#: for :func:`traced`'s probe), and the tracked frames probed deeply
_TRUTHS: list = []
_IMAGES: list = []
_DEEP: set = set()


@contextmanager
def traced(records: list):
    """Record every :class:`~core.tracking.engine_search.LevenbergMarquardt` search's steps into
    ``records`` (one list per search, a dict per step) while the block runs."""
    from core.tracking import engine as eng
    from core.tracking import engine_search as es

    cls = es.LevenbergMarquardt
    init, tell, corr = cls.__init__, cls.tell, cls._correction
    step, set_frame = eng.GaussNewtonCost.step, eng.GaussNewtonCost.set_frame
    last = {}

    def _step(self, x, h):
        last["cost"] = self
        return step(self, x, h)

    def _set_frame(self, frame, **k):
        im = frame._fluence[0]
        last["index"] = next((i for i, a in enumerate(_IMAGES)
                              if a.shape == im.shape and np.array_equal(a, im)), None)
        return set_frame(self, frame, **k)

    def _init(self, *a, **k):
        init(self, *a, **k)
        self._rec = []
        self._raw_best = None
        records.append(self._rec)

    def _corr(self, s):
        c = corr(self, s)
        self._last_corr = np.array(c)
        return c

    def _tell(self, s):
        self._last_corr = np.zeros(6)
        alpha0, best0, raw_best = self.alpha, self.best, self._raw_best
        tell(self, s)
        accepted = self.best is not best0 and self.best is not None
        row = {"x": np.round(s.x, 4).tolist(), "cost": round(float(s.cost), 6), "accepted": bool(accepted),
               "alpha_before": round(alpha0, 4), "alpha": round(self.alpha, 4),
               "correction": np.round(self._last_corr, 5).tolist(),
               "g_moments": np.round(s.g, 5).tolist(), "reason": self.reason if self.done else None,
               "noise": float(self.noise)}
        if accepted:  # the correction's part of the step along each eigenvector of αH, and its gain
            lam, U = np.linalg.eigh(self.alpha * s.H)
            ci = U.T @ self._last_corr
            row.update(eig=lam.tolist(), eig_vectors=U.T.round(3).tolist(), corr_eig=ci.tolist(),
                       corr_gain=(0.5 * ci * ci / np.maximum(lam, 1e-12)).tolist())
        dx = s.x - best0.x if best0 is not None else None
        den = float(dx @ best0.H @ dx) if dx is not None else 0.0
        if accepted and raw_best is not None and den > 0:
            # the secant from the corrected gradients' change, and with the correction held fixed
            # (the moments' change): the estimate with and without the correction's own change
            # between the step's ends
            row.update(dx=np.round(dx, 4).tolist(),
                       secant_corrected=round(float((self.best.g - best0.g) @ dx) / den, 4),
                       secant_moments=round(float((s.g - raw_best) @ dx) / den, 4),
                       correction_change=np.round(self.best.g - s.g - (best0.g - raw_best), 5).tolist())
        if accepted:
            self._raw_best = np.array(s.g)
        if self.done and self.final_x is not None:
            row["final_x"] = np.round(self.final_x, 4).tolist()
        if self.done and _TRUTHS and "cost" in last and last.get("index") is not None:
            k = last["index"]
            row["track_index"] = k
            end = self.final_x if self.final_x is not None else self.best.x
            row["probe"] = _probe(self, last["cost"], end, _TRUTHS[k], k in _DEEP)
        self._rec.append(row)

    cls.__init__, cls.tell, cls._correction = _init, _tell, _corr
    eng.GaussNewtonCost.step, eng.GaussNewtonCost.set_frame = _step, _set_frame
    try:
        yield records
    finally:
        cls.__init__, cls.tell, cls._correction = init, tell, corr
        eng.GaussNewtonCost.step, eng.GaussNewtonCost.set_frame = step, set_frame


@contextmanager
def _gradient(kind: str):
    """``"moments"``: the search's half-steps and gradient of fine pixels on any pixels."""
    from core.tracking import register as reg
    from core.tracking import register_options as ro

    if kind == "default":
        yield
        return
    old_ro, old_reg = ro.newton_step, reg.newton_step

    def fine(mm_per_px):
        return ro.FINAL_STEP, {}

    ro.newton_step = reg.newton_step = fine
    reg._LEVELS.clear()
    try:
        yield
    finally:
        ro.newton_step, reg.newton_step = old_ro, old_reg
        reg._LEVELS.clear()


def run(*, bone: str = "tibia", stride: int = 2, gradient: str = "default", device: str = "cpu",
        n_frames: int = 20, seed: int = 0, frames=None, deep=()) -> dict:
    """The study (module docs)."""
    from core.geometry.transforms import pose_from_params
    from core.studies.tracking import acceptance as acc
    from core.studies.tracking.search_robustness import _options
    from core.tracking.trial import track

    t0 = time.perf_counter()
    ts = acc.tracking_scene(quick=True, device=device, seed=seed, n_frames=n_frames)
    from core.render import DRRRenderer

    b = ts.names.index(bone)
    m = ts.models[b]
    # the bone alone (sequential searches render no neighbours): a renderer of its volume only
    renderer = DRRRenderer(ts.scene.rig, [m.volume.to_attenuation(ts.scene.bone_transfer)], device=device)
    order = list(range(0, n_frames, stride)) if frames is None else list(frames)
    g = np.random.default_rng(seed + 7)  # search_robustness.strided's start
    start = pose_from_params(acc._random_offset(g, 5.0, 5.0), center=m.centroid, base=ts.truth(order[0])[b])
    for f in order:
        ts.frames(f)
    scene_s = time.perf_counter() - t0
    records: list = []
    _TRUTHS[:] = [ts.truth(f)[b] for f in order]
    _IMAGES[:] = [np.asarray(ts.frames(f)[0], dtype=np.float32) for f in order]
    _DEEP.clear()
    _DEEP.update(k for k, f in enumerate(order) if f in set(deep))
    opts = _options("newton", "sequential")
    with _gradient(gradient), traced(records):
        t = time.perf_counter()
        res = track(renderer, [m], lambda k: ts.frames(order[k]), range(len(order)),
                    keyframes={bone: {0: start}}, options=opts)
        wall = time.perf_counter() - t
    per_frame = []
    for k, f in enumerate(order):
        fr = res.results[(bone, k)]
        e = acc.pose_errors(fr.pose, ts.truth(f)[b], m.centroid)
        per_frame.append({"frame": f, "mm": round(float(np.linalg.norm(e[:3])), 4),
                          "deg": round(float(np.linalg.norm(e[3:])), 4), "error": np.round(e, 4).tolist(),
                          "flags": list(fr.flags), "evaluations": int(fr.evaluations)})
    et = np.array([r["mm"] for r in per_frame])
    er = np.array([r["deg"] for r in per_frame])
    return {"study": "core.studies.tracking.newton_coarse", "bone": bone, "stride": stride,
            "gradient": gradient,
            "frames": order, "device": str(renderer.device), "scene_s": round(scene_s, 1),
            "tracking_s": round(wall, 1), "rms_mm": float(np.sqrt(np.mean(et ** 2))),
            "rms_deg": float(np.sqrt(np.mean(er ** 2))), "per_frame": per_frame, "searches": records}


def singles(*, pixels: int = 256, frames=range(0, 20, 2), starts: int = 2, mm: float = 0.5, deg: float = 1.0,
            gradient: str = "default", device: str = "cpu", seed: int = 0, names=None,
            correction: str = "grid", trial: str = "acceptance", voxel: float = 1.0) -> dict:
    """One :func:`~core.tracking.register.register` (``search="newton"``) per bone, frame and start
    on the acceptance trial (:func:`~core.studies.tracking.acceptance.tracking_scene`, ``pixels``;
    ``correction`` its distortion correction: the grid fit finds no grid below 192²; ``trial="hard"``:
    the harder trial of :mod:`core.studies.tracking.hard_trial` instead, ``voxel`` mm),
    from the truth moved exactly ``mm`` / ``deg`` in random directions (the same draws for every
    ``gradient``); per bone the RMS errors (mm, degrees) and the poses evaluated."""
    from dataclasses import replace

    from core.geometry.transforms import pose_from_params
    from core.studies.tracking import acceptance as acc
    from core.tracking.cost import prepare_frame
    from core.tracking.register import RegistrationOptions, register

    if trial == "hard":
        from core.studies.tracking.hard_trial import HardRun

        ts = HardRun(n_frames=max(frames) + 1, pixels=pixels, spacing=voxel, seed=seed, device=device)
    else:
        ts = acc.tracking_scene(quick=True, device=device, seed=seed, n_frames=max(frames) + 1,
                                pixels=pixels, correction=correction)
    opts = replace(RegistrationOptions(), search="newton")
    g = np.random.default_rng(seed + 11)
    draws = [[acc._random_offset(g, mm, deg) for _ in range(starts)] for _ in frames]
    out = {}
    t0 = time.perf_counter()
    with _gradient(gradient):
        for b, (n, m) in enumerate(zip(ts.names, ts.models, strict=True)):
            if names and n not in names:
                continue
            rows = []
            for f, fd in zip(frames, draws, strict=True):
                frame = prepare_frame(ts.frames(f))
                truth = ts.truth(f)[b]
                for d in fd:
                    init = pose_from_params(d, center=m.centroid, base=truth)
                    r = register(ts.renderer, frame, bone=b, initial_pose=init, center=m.centroid,
                                 options=opts)
                    e = acc.pose_errors(r.pose, truth, m.centroid)
                    rows.append([f, float(np.linalg.norm(e[:3])), float(np.linalg.norm(e[3:])),
                                 int(r.evaluations)])
            et, er = np.array([r[1] for r in rows]), np.array([r[2] for r in rows])
            out[n] = {"rms_mm": round(float(np.sqrt(np.mean(et ** 2))), 4),
                      "rms_deg": round(float(np.sqrt(np.mean(er ** 2))), 4),
                      "evaluations": int(sum(r[3] for r in rows)),
                      "per_registration": [[r[0], round(r[1], 4), round(r[2], 4)] for r in rows]}
    return {"trial": trial, "pixels": pixels, "frames": list(frames), "starts": starts, "offset": [mm, deg],
            "gradient": gradient,
            "wall_s": round(time.perf_counter() - t0, 1), "bones": out}


def main(argv=None) -> int:
    from core.io.atomic import print_json

    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.newton_coarse",
                                description=__doc__.split("\n")[0])
    p.add_argument("--bone", default="tibia")
    p.add_argument("--stride", type=int, default=2)
    p.add_argument("--gradient", choices=("default", "moments"), default="default")
    p.add_argument("--device", default="cpu")
    p.add_argument("--deep", default="", help="comma-separated frames probed deeply at their search's end")
    p.add_argument("--singles", type=int, default=0, help="single registrations at these pixels instead")
    p.add_argument("--correction", choices=("grid", "model", "exact"), default="grid",
                   help="--singles: the acceptance trial's distortion correction (the grid fit finds no "
                   "grid below 192²: model there)")
    p.add_argument("--trial", choices=("acceptance", "hard"), default="acceptance",
                   help="--singles: the acceptance trial, or the harder trial (frames 0-4, 4 starts)")
    p.add_argument("--voxel", type=float, default=1.0, help="--singles --trial hard: voxel size, mm")
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    if a.singles:
        kw = ({"trial": "hard", "voxel": a.voxel, "frames": range(5), "starts": 4} if a.trial == "hard"
              else {"correction": a.correction})
        print_json(singles(pixels=a.singles, gradient=a.gradient, device=a.device, **kw), a.out)
        return 0
    res = run(bone=a.bone, stride=a.stride, gradient=a.gradient, device=a.device,
              deep=tuple(int(f) for f in a.deep.split(",") if f))
    print_json(res, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
