"""Failure flags of the tracker against the truth (``python -m core.studies.tracking.flag_study``).

Tracks a bone (or the tibia, talus and calcaneus) of a trial with ground truth twice — with the
tracker's failure check (:func:`core.tracking.checks.failures`) and with the check it replaced
(:func:`legacy_failures`: a score below 0.7 × the first frame's score always flags) — and counts
per bone and check:

* ``failures`` — frames whose error exceeds ``large`` (1 mm or 2°) or 4× the frame's Cramér–Rao
  bound (:func:`core.tracking.bound.pose_bound`, when the frames have quantum noise);
* ``silent`` — such frames without a review flag;
* ``false_flags`` — flagged frames whose error is within 4× the bound and below ``large``.

Then it injects failures into frames of the tracked trial, each registered as the tracker
registers a frame (:func:`core.tracking.attempt.register_checked`, with the score history the
tracking run had at that frame): ``wrong_start`` (the predicted pose 5 mm and 5° off the truth
in random directions, so start and guess are both wrong), ``swapped_views`` (the two views'
images exchanged) and ``other_frame`` (the images of a frame ``offset`` later). Each is
``corrected`` (error within ``large``), ``flagged`` or ``silent``.

Scenes: ``demo`` — :class:`core.studies.tracking.acceptance.TrackingScene` over the whole stance
the foot demo spans (``phase`` 0–0.9: the late stance in which the talus' score falls); ``walk`` —
the same scene over the benchmark's phases (:mod:`core.studies.tracking.benchmark`, 0.6 of the
stance per 100 frames); ``hard`` — :class:`core.studies.tracking.hard_trial.HardRun`. Sizes are
the CPU's by default (256², 1 mm); ``--bound-every k`` evaluates the bound on every k-th frame and
judges every frame by their RMS (the benchmark's bound).

Checks (``--checks``): ``before`` (:func:`legacy_failures`), ``previous`` (the score-history
check without the bone's track, :func:`previous_failures`) and ``after`` (the tracker's checks).
Each tracked frame also gets what a user could judge it by (:func:`_features`) and, per bone,
how well each separates the failures from the good frames (:func:`separation`).

On the acceptance trial (1024², joint, 100 frames, one H200,
``resources/benchmarks/tracking_flags2_h200.json``) the frames over 4× the bound (tibia 7,
calcaneus 1, within 0.07 mm / 0.55°) are silent under every check and no feature separates them
(AUC 0.37–0.76; catching all seven tibia frames would flag 55–100 % of its good frames); the
motion check took the frames out of order from 4 of 12 silent to 0, with no false flag.

Result (one H100, ``resources/benchmarks/tracking_flags_h100.json``): the talus tracked alone over
the demo's stance (256², 60 frames) is lost in the late stance; the fixed floor flagged frames
42–59, the score history check 44–59, every frame over 1 mm or 2° flagged either way. The joint
demo-like trial (512², 60 frames) and the harder trial (512², 12 frames) never crossed the floor:
same flags, same poses. Exchanged views were flagged in 20 of 20 injections, 5 mm / 5° starts
corrected in 19 of 20, and the images of a frame 10 later went unflagged in 10 of 20 (9 with the
fixed floor): images of the bone 2–7 mm away, four of them over the 4 mm jump limit, which the
tracker's retry doubles. Keeping the limit on retries (tried on this 2-core CPU, the talus with
its neighbours at the truth, ``--others-at-truth``) flagged those but also both starts 5 mm off
that the retry had corrected: see :func:`core.tracking.checks.failures`.
"""

from __future__ import annotations

import argparse
import platform
import time
from dataclasses import replace

import numpy as np

from core.geometry.transforms import pose_from_params
from core.studies.tracking.acceptance import _random_offset, pose_errors

__all__ = ["FEATURES", "INJECTIONS", "classify", "legacy_failures", "main", "previous_failures", "run",
           "separation"]

INJECTIONS = ("wrong_start", "swapped_views", "other_frame")


def legacy_failures(res, guess_pose, center, good_scores, o, *, start_score=None,
                    jump_factor: float = 1.0, **_later) -> list[str]:
    """The failure check before the score history floor: a score below ``min_start_ratio`` × the
    bone's first good score always flags (kept here for the comparison)."""
    from core.tracking.checks import _distance

    out = []
    if not res.converged:
        out.append(f"not converged ({res.reason})")
    if good_scores:
        med = float(np.median(good_scores[-o.history:]))
        if res.score < o.min_score_ratio * med:
            out.append(f"score drop ({res.score:.3f} < {o.min_score_ratio:g} x recent median {med:.3f})")
    if start_score is not None and res.score < o.min_start_ratio * start_score:
        out.append(f"score below the start ({res.score:.3f} < {o.min_start_ratio:g} x first frame "
                   f"{start_score:.3f})")
    dt, dr = _distance(guess_pose, res.pose, center)
    if dt > o.max_jump[0] * jump_factor or dr > o.max_jump[1] * jump_factor:
        out.append(f"pose jump ({dt:.2f} mm, {dr:.2f} deg from the guess)")
    return out


def classify(err_mm: float, err_deg: float, bound=None, *, large=(1.0, 2.0)) -> str:
    """``"large"`` (over ``large``), ``"over_4x"`` (over 4× the bound ``(mm, deg)``) or ``"good"``."""
    if not (np.isfinite(err_mm) and np.isfinite(err_deg)):
        return "large"
    if err_mm > large[0] or err_deg > large[1]:
        return "large"
    if bound is not None and np.all(np.isfinite(bound)) and (err_mm > 4 * bound[0] or err_deg > 4 * bound[1]):
        return "over_4x"
    return "good"


#: Per-frame quantities a user has (:func:`_features`), each oriented so that larger is more suspect
FEATURES = ("score_drop", "sigma_mm", "sigma_deg", "sigma_mm_rel", "sigma_deg_rel", "motion_rel")


def _features(rows: list, center, n: int) -> None:
    """Add to each row (tracking order) what a user could judge it by, from the run's own
    unflagged frames before it: ``score_drop`` (1 − score / median of the last ``n`` good scores),
    ``sigma_mm``/``sigma_deg`` (lengths of the confidence σ), ``*_rel`` (over the median of the
    last ``n`` good frames'), ``motion_rel`` (miss of the motion prediction over the limit of
    :func:`core.tracking.checks.motion_check`, the larger of mm and degrees)."""
    from core.tracking.checks import motion_miss

    hist, scores, sig = [], [], []
    for r in rows:
        st = sr = None
        if r["sigma"] is not None and None not in r["sigma"]:
            st, sr = float(np.linalg.norm(r["sigma"][:3])), float(np.linalg.norm(r["sigma"][3:]))
        med_s = float(np.median(scores[-n:])) if scores else None
        med_sig = np.median(np.asarray(sig[-n:]), axis=0) if len(sig) >= 3 else None
        pose = None
        if r["pose"] is not None:
            pose = np.eye(4)
            pose[:3] = np.asarray(r["pose"], float).reshape(3, 4)
        mm = motion_miss(pose, hist, r["frame"], center, n=n) if pose is not None else None
        r["features"] = {
            "score_drop": None if med_s is None else round(1.0 - r["score"] / med_s, 4),
            "sigma_mm": st, "sigma_deg": sr,
            "sigma_mm_rel": None if med_sig is None or st is None else round(st / med_sig[0], 3),
            "sigma_deg_rel": None if med_sig is None or sr is None else round(sr / med_sig[1], 3),
            "motion_rel": None if mm is None else round(max(mm[0] / mm[2], mm[1] / mm[3]), 3)}
        if pose is not None and not r["flags"]:
            hist.append((r["frame"], pose))
            scores.append(r["score"])
            if st is not None and sr is not None:
                sig.append((st, sr))


def separation(rows: list) -> dict:
    """Per feature of :func:`_features`: the area under the ROC curve separating the frames over
    4× the bound or large from the good ones (0.5: no better than chance), and the fraction of
    good frames at or above the feature's smallest value among those failures (the false-flag
    rate of a limit that would catch them all)."""
    out = {}
    for k in FEATURES:
        bad = [r["features"][k] for r in rows if r["kind"] != "good" and r["features"].get(k) is not None]
        good = [r["features"][k] for r in rows if r["kind"] == "good" and r["features"].get(k) is not None]
        if not bad or not good:
            out[k] = None
            continue
        b, g = np.asarray(bad, float), np.asarray(good, float)
        auc = float(np.mean((b[:, None] > g[None, :]) + 0.5 * (b[:, None] == g[None, :])))
        out[k] = {"auc": round(auc, 3), "failures": len(b), "good": len(g),
                  "good_flagged_to_catch_all": round(float(np.mean(g >= b.min())), 3)}
    return out


class _Trial:
    """A trial's frames, truth, bone models and tracking renderer (``bones``: the tracked ones)."""

    def __init__(self, scene: str, *, pixels: int, spacing: float, n_frames: int, seed: int, bones,
                 device: str | None) -> None:
        from core.render import DRRRenderer

        if scene in ("demo", "walk"):
            from core.studies.tracking.acceptance import TrackingScene

            phase = (0.0, 0.9) if scene == "demo" else (0.0, 0.6 * max(n_frames, 2) / 100.0)
            ts = TrackingScene(n_frames=n_frames, pixels=pixels, spacing=spacing, seed=seed, phase=phase,
                               device=device)
            self.names_all, models, transfer = ts.names, ts.models, ts.scene.bone_transfer
            self.frames, self._truth = ts.frames, ts.truth
            sr = ts._scene_renderer
            self.line_integrals = lambda f: ts.scene.line_integrals(f, renderer=sr)
            self.quanta = [m.photons_per_pixel for m in ts.scene.imaging]
            self.rig = ts.scene.rig
        elif scene == "hard":
            from core.studies.tracking.hard_trial import HardRun

            hr = HardRun(n_frames=n_frames, pixels=pixels, spacing=spacing, seed=seed, device=device)
            self.names_all, models, transfer = hr.names, hr.models, hr.transfer
            self.frames, self._truth, self.line_integrals = hr.frames, hr.truth, hr.line_integrals
            self.quanta = [m.photons_per_pixel for m in hr.scene.imaging]
            self.rig = hr.scene.rig
            truth_volumes = hr.scene.bones, hr.scene.bone_transfer
        else:
            raise ValueError(f"scene: expected 'demo', 'walk' or 'hard', got {scene!r}")
        self.names = tuple(bones or self.names_all)
        self.index = [self.names_all.index(n) for n in self.names]
        self.models = [models[i] for i in self.index]
        self.renderer = DRRRenderer(self.rig, [m.volume.to_attenuation(transfer) for m in self.models],
                                    device=device)
        #: the bound's derivatives come from the volumes the frames were rendered from: on the hard
        #: scene the tracker's CT is the truth blurred and resampled, and its bound 1.3-1.7x too large
        #: (:func:`core.studies.tracking.hard_trial.truth_bounds`)
        self.bound_renderer = self.renderer
        if scene == "hard":
            vols, tr = truth_volumes
            self.bound_renderer = DRRRenderer(self.rig, [vols[i].to_attenuation(tr) for i in self.index],
                                              device=device)

    def truth(self, f: int) -> np.ndarray:
        return self._truth(f)[self.index]

    def bound(self, f: int, b: int):
        from core.tracking.bound import pose_bound
        from core.tracking.cost import OutsideViewError

        if any(q is None for q in self.quanta):
            return None
        try:
            pb = pose_bound(self.bound_renderer, b, self.truth(f)[b], self.models[b].centroid,
                            line_integral=self.line_integrals(f), quanta_per_pixel=self.quanta)
        except OutsideViewError:
            return None
        return (pb.rms_mm, pb.rms_deg)


def previous_failures(res, guess_pose, center, good_scores, o, *, start_score=None,
                      jump_factor: float = 1.0, **_later) -> list[str]:
    """:func:`core.tracking.checks.failures` without the bone's track: no motion check, no
    flagged first frame's reference (the check before them, kept for the comparison; with it the
    relative ``"uncertain"`` check is off too, :func:`_patched`)."""
    from core.tracking.checks import failures

    return failures(res, guess_pose, center, good_scores, o, start_score=start_score,
                    jump_factor=jump_factor)


def _patched(check):
    """Context: the tracker's attempts use ``check`` as their failure check (and no relative
    ``"uncertain"`` check unless it is the tracker's own)."""
    import contextlib

    import core.tracking.attempt as attempt
    from core.tracking.checks import failures

    @contextlib.contextmanager
    def ctx():
        old, old_sig = attempt._failures, attempt._sigma_check
        attempt._failures = check
        if check is not failures:
            attempt._sigma_check = lambda *a, **k: []
        try:
            yield
        finally:
            attempt._failures, attempt._sigma_check = old, old_sig
    return ctx()


def _track(tr: _Trial, o, frames, keyframes, check, bounds, tracked, *, large) -> tuple[dict, dict]:
    from core.tracking.trial import track

    skip = {n: {f: tr.truth(f)[b] for f in frames} for b, n in enumerate(tr.names) if n not in tracked}
    with _patched(check):
        t0 = time.perf_counter()
        res = track(tr.renderer, tr.models, tr.frames, frames, keyframes=keyframes, options=o, skip=skip)
        wall = time.perf_counter() - t0
    per = {}
    for b, (n, m) in enumerate(zip(tr.names, tr.models, strict=True)):
        if n not in tracked:
            continue
        rows = []
        for f in frames:
            fr = res.results[(n, f)]
            e = (pose_errors(fr.pose, tr.truth(f)[b], m.centroid) if fr.pose is not None
                 else np.full(6, np.nan))
            et, er = float(np.linalg.norm(e[:3])), float(np.linalg.norm(e[3:]))
            bd = bounds[n].get(f)
            kind = classify(et, er, bd, large=large)
            sig = (fr.confidence or {}).get("sigma")
            sig = None if sig is None else [None if v is None else round(v, 4) for v in sig]
            inside = (None if sig is None or any(v is None for v in sig) or fr.pose is None
                      else bool(np.all(np.abs(e) <= 2 * np.array(sig, float))))
            rows.append({"frame": int(f), "score": round(float(fr.score), 4), "error_mm": round(et, 4),
                         "error_deg": round(er, 4),
                         "bound": None if bd is None else [round(v, 4) for v in bd],
                         "kind": kind, "flags": list(fr.flags), "notes": list(fr.notes), "sigma": sig,
                         "within_2_sigma": inside, "time_s": round(fr.time_s, 2),
                         "pose": None if fr.pose is None else [round(float(v), 5)
                                                               for v in fr.pose[:3].ravel()]})
        _features(rows, m.centroid, o.history)
        bad = [r["frame"] for r in rows if r["kind"] != "good"]
        n_good = sum(1 for r in rows if r["kind"] == "good")
        per[n] = {"failures": bad,
                  "large": [r["frame"] for r in rows if r["kind"] == "large"],
                  "silent": [r["frame"] for r in rows if r["kind"] != "good" and not r["flags"]],
                  "silent_large": [r["frame"] for r in rows if r["kind"] == "large" and not r["flags"]],
                  "false_flags": [r["frame"] for r in rows if r["kind"] == "good" and r["flags"]],
                  "good_frames": n_good,
                  "false_flag_rate": (sum(1 for r in rows if r["kind"] == "good" and r["flags"]) / n_good
                                      if n_good else None),
                  "separation": separation(rows),
                  "flagged": [r["frame"] for r in rows if r["flags"]],
                  "within_2_sigma": float(np.mean([r["within_2_sigma"] for r in rows
                                                   if r["within_2_sigma"] is not None] or [np.nan])),
                  "rms_error_mm": float(np.sqrt(np.nanmean([r["error_mm"] ** 2 for r in rows]))),
                  "rms_error_deg": float(np.sqrt(np.nanmean([r["error_deg"] ** 2 for r in rows]))),
                  "frames": rows}
    return per, {"wall_s": wall, "summary": res.summary(), "result": res}


def _inject(tr: _Trial, o, res, frames, check, injections, at, tracked, *, large, offset: int,
            seed: int) -> list:
    """Injected failures at frames ``at`` of the tracked run ``res`` (see the module docs)."""
    from core.tracking.attempt import register_checked
    from core.tracking.cost import prepare_frame
    from core.tracking.trial import predict_pose

    out = []
    g = np.random.default_rng(seed + 101)
    order = list(frames)
    for b, (n, m) in enumerate(zip(tr.names, tr.models, strict=True)):
        if n not in tracked:
            continue
        ids = [i for i, nn in enumerate(tr.names) if nn not in tracked]  # subtracted at the truth
        for f in at:
            others = (np.stack([tr.truth(f)[i] for i in ids]), ids) if ids else None
            k = order.index(f)
            good = [(g_f, res.results[(n, g_f)]) for g_f in order[:k]
                    if res.results[(n, g_f)].pose is not None and not res.results[(n, g_f)].flags]
            if len(good) < 2:
                continue
            history = [(g_f, r.pose) for g_f, r in good]
            scores = [r.score for _, r in good]
            sigmas = [(r.confidence["translation_mm"], r.confidence["rotation_deg"]) for _, r in good
                      if r.confidence and r.confidence.get("translation_mm") is not None
                      and r.confidence.get("rotation_deg") is not None]
            guess = predict_pose(history, f, m.centroid, guess=o.guess)
            for kind in injections:
                imgs = tr.frames(f)
                start = guess
                if kind == "wrong_start":
                    start = pose_from_params(_random_offset(g, 5.0, 5.0), center=m.centroid,
                                             base=tr.truth(f)[b])
                elif kind == "swapped_views":
                    imgs = list(imgs)[::-1]
                elif kind == "other_frame":
                    j = order[min(k + offset, len(order) - 1)]
                    imgs = tr.frames(j)
                with _patched(check):
                    a = register_checked(tr.renderer, prepare_frame(imgs, valid_range=o.valid_range,
                                                                    erode_px=o.erode_px),
                                         m, b, start, start, o.registration, o, scores, others, None, history,
                                         start_score=scores[0], seed=f, frame_number=f, good_sigmas=sigmas)
                if a.result is None:
                    out.append({"bone": n, "frame": int(f), "kind": kind, "outcome": "flagged",
                                "flags": list(a.flags)})
                    continue
                e = pose_errors(a.result.pose, tr.truth(f)[b], m.centroid)
                et, er = float(np.linalg.norm(e[:3])), float(np.linalg.norm(e[3:]))
                wrong = classify(et, er, None, large=large) != "good"
                outcome = "flagged" if a.flags else ("silent" if wrong else "corrected")
                out.append({"bone": n, "frame": int(f), "kind": kind, "outcome": outcome,
                            "error_mm": round(et, 3), "error_deg": round(er, 3),
                            "score": round(float(a.result.score), 4), "flags": list(a.flags),
                            "notes": list(a.notes)})
    return out


def run(*, scene: str = "demo", pixels: int = 256, spacing: float = 1.0, n_frames: int = 60,
        bones=("talus",), mode: str = "sequential", search: str = "newton", seed: int = 0,
        device: str | None = None, checks=("before", "after"), injections=INJECTIONS, inject_every: int = 10,
        offset: int = 10, large=(1.0, 2.0), start=(0.0, 0.0), others_at_truth: bool = False,
        bound_every: int = 1, progress=None) -> dict:
    """Track and inject under each check; returns the JSON-ready counts (module docs).
    ``others_at_truth``: the scene's other bones are given at their true poses and subtracted
    (joint mode), so ``bones`` are tracked as joint tracking does once its neighbours are right."""
    from core.tracking.checks import failures
    from core.tracking.trial import TrackingOptions

    t0 = time.perf_counter()
    tr = _Trial(scene, pixels=pixels, spacing=spacing, n_frames=n_frames, seed=seed,
                bones=None if others_at_truth else bones, device=device)
    tracked = tuple(bones or tr.names)
    if others_at_truth:
        mode = "joint"
    frames = list(range(n_frames))
    for f in frames:
        tr.frames(f)
    bounds = {n: {} for n in tr.names}
    for f in frames[::max(int(bound_every), 1)]:
        for b, n in enumerate(tr.names):
            if n not in tracked:
                continue
            bd = tr.bound(f, b)
            if bd is not None:
                bounds[n][f] = bd
    if bound_every > 1:  # the RMS over the frames evaluated stands for every frame (the benchmark's bound)
        for n, bd in bounds.items():
            if bd:
                rms = tuple(float(np.sqrt(np.mean(np.square(v)))) for v in zip(*bd.values(), strict=True))
                bounds[n] = {f: rms for f in frames}
    setup = time.perf_counter() - t0
    o = TrackingOptions(mode=mode, registration=replace(TrackingOptions().registration, search=search))
    g = np.random.default_rng(seed + 7)
    keyframes = {n: {0: pose_from_params(_random_offset(g, *start), center=m.centroid, base=tr.truth(0)[b])
                     if start[0] or start[1] else tr.truth(0)[b]}
                 for b, (n, m) in enumerate(zip(tr.names, tr.models, strict=True)) if n in tracked}
    out = {"study": "core.studies.tracking.flag_study", "machine": platform.machine(),
           "device": str(tr.renderer.device),
           "config": {"scene": scene, "pixels": pixels, "voxel_mm": spacing, "frames": n_frames, "seed": seed,
                      "bones": list(tracked), "others_at_truth": others_at_truth, "mode": mode,
                      "search": search, "large": list(large),
                      "start_error": list(start), "inject_every": inject_every, "offset": offset,
                      "bound_every": bound_every},
           "setup_s": setup, "checks": {}}
    variants = {"before": legacy_failures, "previous": previous_failures, "after": failures}
    at = frames[inject_every::inject_every] if inject_every else []
    for name in checks:
        per, info = _track(tr, o, frames, keyframes, variants[name], bounds, tracked, large=large)
        inj = _inject(tr, o, info.pop("result"), frames, variants[name], injections, at, tracked, large=large,
                      offset=offset, seed=seed) if at and injections else []
        counts = {k: {"n": sum(1 for r in inj if r["kind"] == k),
                      **{oc: sum(1 for r in inj if r["kind"] == k and r["outcome"] == oc)
                         for oc in ("corrected", "flagged", "silent")}} for k in injections}
        out["checks"][name] = {"bones": per, "injected": counts, "injected_frames": inj, **info}
        if progress is not None:
            progress(name, out["checks"][name])
    out["total_s"] = time.perf_counter() - t0
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.flag_study",
                                description=__doc__.split("\n")[0])
    p.add_argument("--scene", choices=("demo", "walk", "hard"), default="demo")
    p.add_argument("--pixels", type=int, default=256)
    p.add_argument("--voxel", type=float, default=1.0)
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--bones", default="talus", help="comma-separated tracked bones ('all': every one)")
    p.add_argument("--mode", choices=("sequential", "joint"), default="sequential")
    p.add_argument("--search", default="newton")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device", default=None)
    p.add_argument("--checks", default="before,after")
    p.add_argument("--inject-every", type=int, default=10)
    p.add_argument("--injections", default=",".join(INJECTIONS))
    p.add_argument("--offset", type=int, default=10,
                   help="other_frame: the images of the frame this much later")
    p.add_argument("--others-at-truth", action="store_true",
                   help="give the other bones at their true poses and subtract them (joint mode)")
    p.add_argument("--start", default="0,0", help="frame-0 start error 'mm,deg' (default the truth)")
    p.add_argument("--bound-every", type=int, default=1,
                   help="the bound of every k-th frame only, their RMS for all (the benchmark's bound)")
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    bones = None if a.bones == "all" else tuple(a.bones.split(","))
    inj = tuple(k for k in a.injections.split(",") if k)
    done = {}

    def partial(name, data):  # each check's results as soon as they are in (a run may be cut short)
        if a.out:
            import json

            from core.io.atomic import atomic_write

            done[name] = data
            atomic_write(a.out + ".partial", json.dumps({"checks": done}, indent=1))

    res = run(scene=a.scene, pixels=a.pixels, spacing=a.voxel, n_frames=a.frames, bones=bones, mode=a.mode,
              search=a.search, seed=a.seed, device=a.device, checks=tuple(a.checks.split(",")),
              injections=inj, inject_every=a.inject_every, offset=a.offset, others_at_truth=a.others_at_truth,
              start=tuple(float(v) for v in a.start.split(",")), bound_every=a.bound_every, progress=partial)
    from core.io.atomic import print_json

    print_json(res, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
