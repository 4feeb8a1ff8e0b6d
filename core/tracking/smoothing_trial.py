"""Smoothed poses of a study trial's tracked bones, stored beside the tracked ones
(:func:`smooth_trial`; ``talus track --smooth``), or exported in their place
(:func:`smoothed_poses`; the window's *File → Export…*, *Smoothed poses*).

The journal's poses stay the results: each bone's smoothed poses
(:func:`core.tracking.smoothing.smooth_poses`, from the journal's poses, each frame's confidence σ
and flags as tracking recorded them) and their covariance go to the report
``results/reports/smoothing/<trial>.json``. They pool neighbouring frames, so the single-frame
Cramér–Rao bound does not bound them: a separate figure from the per-frame one.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .smoothing import smooth_poses

__all__ = ["REPORT_KIND", "bone_series", "smooth_trial", "smoothed_poses"]

#: the report's kind: ``results/reports/<kind>/<trial>.json``
REPORT_KIND = "smoothing"


def bone_series(records: dict, frames: Sequence[int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A journal's records (frame -> :class:`~core.study.results.PoseRecord`) over ``frames``:
    ``(n, 4, 4)`` poses (NaN where none), ``(n, 6)`` σ (NaN where the record has no confidence, a
    hand-set pose; ``inf`` on an unbounded axis) and ``(n,)`` flagged."""
    n = len(frames)
    P, S, fl = np.full((n, 4, 4), np.nan), np.full((n, 6), np.nan), np.zeros(n, bool)
    for k, f in enumerate(frames):
        rec = records.get(f)
        if rec is None or rec.pose is None:
            continue
        P[k] = rec.pose
        t = rec.tracking or {}
        fl[k] = bool(t.get("flags"))
        sg = (t.get("confidence") or {}).get("sigma")
        if sg is not None:
            S[k] = [np.inf if v is None else v for v in sg]
    return P, S, fl


def _smooth_bones(study, trial_name: str, bones, threshold_hu: float, options: dict):
    """Per bone ``(first frame, centre, SmoothedPoses)`` and the bones skipped with why."""
    from .bones import bone_model

    trial = study.trial(trial_name)
    done, skipped = {}, {}
    for b in list(trial.bones if bones is None else bones):
        recs = trial.results(b).records
        posed = sorted(f for f, r in recs.items() if r.pose is not None)
        if not posed:
            skipped[b] = "no pose"
            continue
        frames = list(range(posed[0], posed[-1] + 1))
        P, S, fl = bone_series(recs, frames)
        c = bone_model(study.bone_volume(b), name=b, threshold=threshold_hu, mesh=False).centroid
        try:
            done[b] = (frames[0], c, smooth_poses(P, S, center=c, flagged=fl, **options))
        except ValueError as exc:  # too few measured frames
            skipped[b] = str(exc)
    return done, skipped


def smooth_trial(study, trial_name: str, bones: Sequence[str] | None = None, *, threshold_hu: float = 200.0,
                 write: bool = True, **options) -> dict:
    """Smooth each bone of trial ``trial_name`` (``bones``, default the trial's) over the frames
    from its first to its last pose; ``options``: :func:`~core.tracking.smoothing.smooth_poses`'
    keywords. The rotation centre is the bone model's centroid at ``threshold_hu`` (tracking's,
    about which its σ is). Returns the report (per bone its first and last frame, centre and
    :meth:`~core.tracking.smoothing.SmoothedPoses.to_dict`; a bone with too few poses under
    ``skipped`` with why), written to ``results/reports/smoothing/<trial>.json`` when ``write`` (the
    study open for writing). Written, it keeps the bones of an earlier report of the trial that
    this call did not smooth (a run of other bones adds to it; each bone's entry names its options)."""
    done, skipped = _smooth_bones(study, trial_name, bones, threshold_hu, options)
    opts = {k: v for k, v in options.items()}
    out: dict = {"trial": trial_name, "options": opts,
                 "note": "smoothed over neighbouring frames: not the tracked results (the journal keeps "
                         "those), and not bounded by the single-frame Cramer-Rao bound",
                 "bones": {b: {"frames": [lo, lo + len(sm.poses) - 1], "center": np.round(c, 5).tolist(),
                               "options": opts, "journal": _journal_stamp(study, trial_name, b),
                               **sm.to_dict()} for b, (lo, c, sm) in done.items()},
                 "skipped": skipped}
    if write:
        study.write_report(REPORT_KIND, trial_name, _merged(study, trial_name, out))
    return out


def _journal_stamp(study, trial_name: str, bone: str) -> str:
    """A digest of ``bone``'s journal in the trial (each recorded pose's frame, pose and flags): what its
    smoothing was made from (:func:`_merged` keeps an earlier entry only while it is the same)."""
    import hashlib

    recs = study.trial(trial_name).results(bone).records
    h = hashlib.sha1()
    for f in sorted(recs):
        r = recs[f]
        if r.pose is not None:
            h.update(np.int64(f).tobytes())
            h.update(np.asarray(r.pose, dtype=float).tobytes())
            h.update(repr((r.tracking or {}).get("flags")).encode())
    return h.hexdigest()


def _merged(study, trial_name: str, out: dict) -> dict:
    """``out`` with the bones of the trial's earlier report that ``out`` neither smoothed nor skipped, each
    while its journal is the one it was smoothed from (a bone re-tracked since is dropped, said in
    ``skipped``: its smoothed poses would no longer describe the journal)."""
    if trial_name not in study.report_names(REPORT_KIND):
        return out
    try:
        old = study.read_report(REPORT_KIND, trial_name)
    except Exception:  # an unreadable earlier report is replaced
        return out
    new = set(out["bones"]) | set(out["skipped"])
    kept, stale = {}, {}
    for b, e in (old.get("bones") or {}).items():
        if b in new:
            continue
        try:
            same = e.get("journal") == _journal_stamp(study, trial_name, b)
        except Exception:  # (a bone no longer in the trial)
            same = False
        if same:
            kept[b] = e
        else:
            stale[b] = "its journal changed since it was smoothed (re-tracked): smooth it again"
    kept_skipped = {b: w for b, w in (old.get("skipped") or {}).items() if b not in new and b not in kept}
    return {**out, "bones": {**kept, **out["bones"]}, "skipped": {**kept_skipped, **stale, **out["skipped"]}}


def smoothed_poses(study, trial_name: str, bones: Sequence[str] | None = None, *, threshold_hu: float = 200.0,
                   **options) -> dict[str, np.ndarray]:
    """Bone -> ``(n_frames, 4, 4)`` smoothed poses of trial ``trial_name`` (as :func:`smooth_trial`'s,
    computed afresh, not written; NaN outside a bone's first and last pose, at a frame without a pose of
    its own — the smoother's prediction there is in the report, not written as if tracked, as the tracked
    export and :meth:`~core.tracking.results.TrackingResult.filtered_poses` leave such a frame — and for
    a bone too short to smooth), to export in place of the tracked ones
    (:func:`core.study.exports.export_poses`' ``poses``)."""
    trial = study.trial(trial_name)
    done, _ = _smooth_bones(study, trial_name, bones, threshold_hu, options)
    out = {}
    for b in (trial.bones if bones is None else bones):
        P = np.full((trial.n_frames, 4, 4), np.nan)
        if b in done:
            lo, _, sm = done[b]
            P[lo:lo + len(sm.poses)] = sm.poses
            recs = trial.results(b).records
            none = [f for f in range(lo, lo + len(sm.poses)) if getattr(recs.get(f), "pose", None) is None]
            P[none] = np.nan  # (no pose of its own: not tracked there)
        out[b] = P
    return out
