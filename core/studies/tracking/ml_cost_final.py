"""The final-stage part of :mod:`core.studies.tracking.ml_cost` (``--final``): the acceptance trial
tracked with and without the likelihood stage, per bone the errors over the Cramér–Rao bound, the
frames over 4× it and how many went unflagged, the stage's per-frame probe and the 2σ coverage
(what is measured and where: that module's docs)."""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

__all__ = ["run_final", "silent_failures"]


def _sigmas(res, nm, frames) -> list:
    """Per frame the confidence σ (6,) of the tracked pose (NaN where there is none)."""
    out = []
    for f in frames:
        c = res.results[(nm, f)].confidence
        sg = None if not c else c.get("sigma")
        out.append(np.full(6, np.nan) if sg is None else np.array([np.nan if v is None else v for v in sg]))
    return out


def _coverage(E, S) -> dict:
    """Fractions within 2σ: per axis, and of frames with all six axes within."""
    E, S = np.asarray(E), np.asarray(S)
    ok = np.all(np.isfinite(E), axis=1) & np.all(np.isfinite(S), axis=1)
    if not ok.any():
        return {"axes": None, "frames": None, "frames_with_sigma": 0}
    inside = np.abs(E[ok]) <= 2 * S[ok]
    return {"axes": float(inside.mean()), "frames": float(inside.all(axis=1).mean()),
            "translation_axes": float(inside[:, :3].mean()), "rotation_axes": float(inside[:, 3:].mean()),
            "frames_with_sigma": int(ok.sum())}


class _StageProbe:
    """While installed (``with``), per (bone index, frame) the final stage's runs of a tracking run:
    the pose it returned and what its refinement saw — the move ``x`` (mm, degrees), the sandwich
    and the independent-pixel covariances, χ², steps, usable pixels and the weighted residual's
    autocorrelation at 1 px and over the lag window (mean over the views). Study instrumentation
    only: it wraps :func:`core.tracking.trial.track_frame` (the frame number),
    :func:`core.tracking.final_stage.final_stage` and
    :meth:`core.tracking.engine_likelihood.LikelihoodEngine.refine`."""

    def __init__(self) -> None:
        self.frame = None
        self.calls: dict = {}
        self._last = None

    def __enter__(self) -> _StageProbe:
        import core.tracking.final_stage as fst
        import core.tracking.trial as trial
        from core.tracking.engine_likelihood import LikelihoodEngine

        self._saved = (trial.track_frame, fst.final_stage, LikelihoodEngine.refine)
        real_tf, real_fs, real_refine = self._saved
        probe = self

        def track_frame(run, f, *a, **k):
            probe.frame = int(f)
            return real_tf(run, f, *a, **k)

        def refine(eng, *a, **k):
            out = real_refine(eng, *a, **k)
            rho = getattr(eng, "autocorrelation", None)
            d = {"x": np.asarray(out["x"], float), "covariance": np.asarray(out["covariance"], float),
                 "covariance_independent": np.asarray(out["covariance_independent"], float),
                 "chi2": float(out["chi2"]), "iterations": int(out["iterations"]),
                 "pixels": int(eng.n_pixels)}
            if rho is not None:
                c = rho.shape[1] // 2
                d["rho_1px"] = float(np.mean([rho[:, c, c - 1], rho[:, c, c + 1], rho[:, c - 1, c],
                                              rho[:, c + 1, c]]))
                d["rho_mean"] = float(np.mean(rho))
            probe._last = d
            return out

        def final_stage(renderer, frame, res, **k):
            probe._last = None
            got = real_fs(renderer, frame, res, **k)
            if probe._last is not None:
                probe.calls.setdefault((int(k["bone"]), probe.frame), []).append(
                    (np.asarray(got.pose, float).tobytes(), probe._last))
            return got

        trial.track_frame, fst.final_stage, LikelihoodEngine.refine = track_frame, final_stage, refine
        return self

    def __exit__(self, *exc) -> None:
        import core.tracking.final_stage as fst
        import core.tracking.trial as trial
        from core.tracking.engine_likelihood import LikelihoodEngine

        trial.track_frame, fst.final_stage, LikelihoodEngine.refine = self._saved

    def of(self, bone: int, fr) -> dict | None:
        """The stage's record behind result ``fr`` (a FrameResult of volume ``bone``): its last run
        in that frame that returned the pose ``fr`` holds, or None."""
        if fr is None or fr.pose is None:
            return None
        key = np.asarray(fr.pose, float).tobytes()
        hits = [d for p, d in self.calls.get((bone, fr.frame), []) if p == key]
        return hits[-1] if hits else None


def _stage_record(d: dict | None) -> dict | None:
    """A probe record as JSON: the move, the diagonals of both covariances, the χ², steps, pixels
    and autocorrelations."""
    if d is None:
        return None
    return {"move": np.round(d["x"], 5).tolist(), "var_sandwich": d["covariance"].diagonal().tolist(),
            "var_independent": d["covariance_independent"].diagonal().tolist(),
            **{k: d[k] for k in ("chi2", "iterations", "pixels", "rho_1px", "rho_mean") if k in d}}


def silent_failures(E, flagged, bound: dict, factor: float = 4.0) -> dict:
    """Frames whose translation or rotation error exceeds ``factor`` × the per-frame bound
    (``bound``: ``rms_mm``, ``rms_deg``; the benchmark's test), those of them not flagged
    (``silent``) and the flagged frames within it (``false_flags``); ``E`` (frames, 6), ``flagged``
    (frames,) bools. Frames without a pose count as flagged failures."""
    E = np.asarray(E, float)
    flagged = np.asarray(flagged, bool)
    ok = np.all(np.isfinite(E), axis=1)
    over = ~ok | (np.linalg.norm(np.nan_to_num(E[:, :3]), axis=1) > factor * bound["rms_mm"]) \
        | (np.linalg.norm(np.nan_to_num(E[:, 3:]), axis=1) > factor * bound["rms_deg"])
    return {"over": int(over.sum()), "over_frames": np.flatnonzero(over).tolist(),
            "flagged": int(flagged.sum()), "silent": int((over & ~flagged).sum()),
            "silent_frames": np.flatnonzero(over & ~flagged).tolist(),
            "false_flags": int((flagged & ~over).sum()), "good": int((~over).sum())}


def run_final(*, device: str | None = None, frames: int | None = None, cases=("one", "three"),
              pixels: int = 1024, voxel: float = 0.5, highpass_px: float = 4.0, workers: int = 0,
              checkpoint=None, variants=((None, None, None, False),), glare: bool = False,
              every_round: bool = False, keep_moves: bool = False, correction="model",
              erode_px: int | None = None) -> dict:
    """The trial tracked twice per case (``one``: the talus alone, ``three``: three bones jointly,
    or a bone's name: that bone alone) in the same process: as today (``search="newton"``) and
    with the final stage ``TrackingOptions.refine_likelihood`` (:mod:`core.tracking.final_stage`,
    high-pass ``highpass_px``): error / bound ratios, time per frame, the time the stage adds per
    bone-frame, how often its move was taken, 2σ coverage of each run's confidence. ``variants``:
    further final stages of every case, ``(high-pass σ px, lag window px, confidence, the
    neighbours' own gain)``
    (None: the default), each tracked in full as ``final_<σ>_<lag>_<confidence>``; ``every_round``:
    three bones once more with the stage after every joint round (``final_every_round``,
    :data:`core.tracking.frame_step.FINAL_EVERY_ROUND`, as before it ran after the last only);
    ``keep_moves``: once more with the flagged stage moves kept (``final_kept_moves``,
    ``TrackingOptions.stage_move_reject=False``, as before the rejection).
    Per bone and run: ``over_4x_bound`` (:func:`silent_failures`) and the flags per frame. Per frame
    (``per_frame``): the errors, σ and scores of the runs ``tracker``, ``final`` (and
    ``final_every_round``), and for the final stages what the stage saw (:class:`_StageProbe`).
    ``correction``: the frames' distortion correction
    (:class:`~core.studies.tracking.acceptance.TrackingScene`), or several in turn on the same raw
    frames and bound (each in ``by_correction[<correction>]``:
    its residual distortion and the cases; ``"exact"``: the true model, an oracle). ``erode_px``:
    the unusable pixels' band (``TrackingOptions.erode_px``, default 3) of every run."""
    from core.tracking.trial import TrackingOptions

    n = frames or 100
    corrs = [correction] if isinstance(correction, str) else list(correction)
    from core.studies.tracking.ml_cost_scene import _scene

    ts, out, bound = _scene(n, pixels, voxel, device, workers,
                     {"study": "core.studies.tracking.ml_cost (final stage)", "highpass_px": highpass_px,
                      "correction": correction if isinstance(correction, str) else corrs}, glare=glare,
                     correction=corrs[0], keep_raw=len(corrs) > 1)
    out["glare"] = [g.to_dict() for g in ts.glare] or None
    base = TrackingOptions(mode="joint")
    if erode_px is not None:
        out["erode_px"] = int(erode_px)
        base = replace(base, erode_px=int(erode_px))
    plain = replace(base, registration=replace(base.registration, search="newton"))
    final = replace(plain, registration=replace(plain.registration, final_highpass_px=highpass_px),
                    refine_likelihood=True)
    for k, corr in enumerate(corrs):
        dest = out
        if len(corrs) > 1:
            if k:
                ts.use_correction(corr)
            dest = out.setdefault("by_correction", {}).setdefault(corr, {})
            dest["residual_distortion_rms_mm"] = ts.residual_distortion_mm()
            if corr == "grid":
                dest["correction_fits"] = [c.summary() for c in ts.corrections]
        for case in cases:
            dest[case] = _final_case(ts, bound, n, case, plain, final, variants=variants,
                                     every_round=every_round, keep_moves=keep_moves, highpass_px=highpass_px)
            if checkpoint:
                checkpoint(out)
    return out


def _final_case(ts, bound: dict, n: int, case: str, plain, final, *, variants, every_round: bool,
                keep_moves: bool, highpass_px: float) -> dict:
    """One case of :func:`run_final` on ``ts``'s frames: its runs (tracker, final stage, variants)."""
    import core.tracking.frame_step as fs
    from core.render import DRRRenderer
    from core.studies.tracking.ml_cost_scene import _pose_errs, _summary
    from core.tracking.trial import track
    bones = {"one": [1], "three": [0, 1, 2]}.get(case) or [ts.names.index(case)]  # or a bone alone
    models = [ts.models[b] for b in bones]
    names = [ts.names[b] for b in bones]
    r = DRRRenderer(ts.scene.rig, [m.volume.to_attenuation(ts.scene.bone_transfer) for m in models],
                    device=ts.device)
    kf = {m.name: {0: ts.truth(0)[b]} for m, b in zip(models, bones, strict=True)}
    c = {}
    runs = [("warm_up", plain), ("tracker", plain), ("final", final)]
    if every_round and len(bones) > 1:
        runs.append(("final_every_round", final))
    if keep_moves:  # the stage's flagged moves kept, as before the rejection
        runs.append(("final_kept_moves", replace(final, stage_move_reject=False)))
    if variants:
        for hp, lag, conf, gain in variants:
            if (hp, lag, conf, gain) != (None, None, None, False):
                reg = replace(final.registration, final_lag_px=lag,
                              final_highpass_px=highpass_px if hp is None else float(hp),
                              final_confidence=conf or final.registration.final_confidence,
                              final_others_gain=bool(gain))
                label = f"final_{hp}_{lag}_{conf}" + ("_others_gain" if gain else "")
                runs.append((label, replace(final, registration=reg)))
    for label, o in runs:
        if label == "warm_up":  # the kernels compiled, the engines' buffers made (not timed)
            track(r, models, ts.frames, range(min(n, 3)), keyframes=kf, options=o)
            track(r, models, ts.frames, range(min(n, 3)), keyframes=kf, options=final)
            continue
        ends: dict = {}

        def progress(done, total, fr, ends=ends):
            ends[fr.frame] = time.perf_counter()

        fs.FINAL_EVERY_ROUND = label == "final_every_round"
        try:
            with _StageProbe() as probe:
                t0 = time.perf_counter()
                res = track(r, models, ts.frames, range(n), keyframes=kf, options=o, progress=progress)
                dt = time.perf_counter() - t0
        finally:
            fs.FINAL_EVERY_ROUND = False
        poses = {(nm, f): res.results[(nm, f)].pose for nm in names for f in range(n)}
        tim = [res.results[(nm, f)].timing or {} for nm in names for f in range(n)]
        after = (ends[n - 1] - ends[0]) / (n - 1) if n > 1 and 0 in ends and n - 1 in ends else None
        d = {"track_s": dt, "s_per_frame": dt / n, "ms_per_frame_after_first": None if after is None
             else 1e3 * after,
             "likelihood_s_per_bone_frame": float(np.mean([t.get("likelihood_s", 0.0) for t in tim])),
             "likelihood_setup_s_per_bone_frame": float(np.mean([t.get("likelihood_setup_s", 0.0)
                                                                 for t in tim])),
             "likelihood_steps_per_bone_frame": float(np.mean([t.get("likelihood_steps", 0)
                                                               for t in tim])),
             "likelihood_taken": int(sum(t.get("likelihood_taken", 0) for t in tim)),
             "likelihood_tried": int(sum("likelihood_s" in t for t in tim)),
             "likelihood_rejected": int(sum(t.get("likelihood_rejected", 0) for t in tim)),
             "likelihood_move_median": [float(np.median(v)) if (v := [t[k] for t in tim if np.isfinite(
                 t.get(k, np.nan))]) else None for k in ("likelihood_move_mm", "likelihood_move_deg")],
             "flagged": int(sum(bool(res.results[k].flags) for k in poses))}
        for i, nm in enumerate(names):
            E = np.array(_pose_errs(ts, nm, poses, range(n)))
            S = _sigmas(res, nm, range(n))
            frs = [res.results[(nm, f)] for f in range(n)]
            d[nm] = {**_summary(E, bound.get(nm)), "within_2_sigma": _coverage(E, S),
                     "median_sigma": np.nanmedian(np.array(S), axis=0).round(4).tolist()}
            if bound.get(nm):
                d[nm]["over_4x_bound"] = silent_failures(E, [bool(x.flags) for x in frs], bound[nm])
            d[nm]["flags"] = {str(x.frame): list(x.flags) for x in frs if x.flags}
            d[nm]["rejected_frames"] = [x.frame for x in frs
                                        if (x.timing or {}).get("likelihood_rejected")]
            if label in ("tracker", "final", "final_every_round", "final_kept_moves"):
                pf = {"error": np.round(E, 5).tolist(), "sigma": np.round(np.array(S), 5).tolist(),
                      "score": [float(x.score) for x in frs]}
                if label != "tracker":
                    pf["stage"] = [_stage_record(probe.of(i, x)) for x in frs]
                c.setdefault("per_frame", {})[f"{label}_{nm}"] = pf
        c[label] = d
    return c


def _variant(text: str) -> tuple:
    """``"σ:lag[:confidence[:gain]]"`` of ``--final-variants`` ("-" for a default; ``gain``: the
    neighbours' DRRs with a gain of their own)."""
    hp, lag, *rest = [*text.split(":"), "-", "-"]
    conf, gain = rest[0], rest[1]
    return (None if hp == "-" else float(hp), None if lag == "-" else int(lag), None if conf == "-" else conf,
            gain == "gain")


def _corrections(text: str) -> tuple[str, ...]:
    """``--correction``: one or more of :data:`core.studies.tracking.acceptance.CORRECTIONS`,
    comma-separated, each once."""
    from core.studies.tracking.acceptance import CORRECTIONS

    got = tuple(t.strip() for t in text.split(",") if t.strip())
    bad = [t for t in got if t not in CORRECTIONS]
    if not got or bad or len(set(got)) != len(got):
        raise argparse.ArgumentTypeError(f"expected distinct ones of {', '.join(CORRECTIONS)}, got {text!r}")
    return got
