"""Joint angles of the tracked demo against those of its ground-truth poses (Grood–Suntay JCS).

``python -m core.studies.tracking.jcs_check [--pixels 128] [--frames 6] [--demo-frames 60]
[--spacing 1] [--bones tibia,talus,calcaneus] [--fast] [--search local|newton] [--device cpu]
[--out JSON]``, or
``python -m core.studies.tracking.jcs_check --demo DIR [--trial walk]`` for a demo folder already
tracked (e.g. by :mod:`core.studies.calibration.tracking_comparison`, whose trials ``walk`` and
``walk_truth`` it reads back from the journal).

A foot demo (:func:`core.synthetic.make_demo_study`, the true rig, no calibration session) is
tracked from the true frame-0 poses (its keyframes) with
:func:`core.tracking.from_study.track_study` on frames corrected with the generator's own
flatfield and distortion (:func:`core.studies.calibration.truth.true_correction`:
a trial without a calibration has no correction of its own, and its frames would otherwise only
be divided by the full scale — still distorted, with the intensifier's roll-off). The joints of
:func:`core.tracking.jcs.default_joints` (ankle tibia–talus, subtalar talus–calcaneus), with
principal-axes anatomical frames from the CTs, give JCS angles from the tracked poses and from
the generator's true poses, compared by :func:`core.tracking.jcs.jcs_rms` (per angle and over
all three, degrees; frame 0 is the keyframe and left out). Per bone the RMS centroid (mm) and
rotation (°) errors say which bones were tracked well: a joint is only as good as its two bones,
so the JSON marks each joint whose bones both stayed within ``--lost-mm`` (default 2 mm) at every
frame. Only this study reads the truth (``poses/*.npy`` and ``imaging/`` of the demo folder).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

__all__ = ["joint_check", "main", "run"]


def joint_check(tracked: dict, truth: dict, volumes: dict, *, lost_mm: float = 2.0) -> dict:
    """Per-bone errors and per-joint JCS RMS of ``tracked`` poses against ``truth`` (both
    ``bone -> (n, 4, 4)`` over the same frames, the first of which — the keyframe — is left
    out; NaN poses are skipped) with principal-axes anatomical frames of ``volumes`` (CTs)."""
    from core.studies.tracking.acceptance import pose_errors
    from core.tracking.jcs import anatomical_frames, default_joints, jcs_rms, volume_points

    bones = list(tracked)
    n = len(next(iter(tracked.values())))
    per_bone = {}
    for b in bones:
        centre = np.asarray(volumes[b].centroid(200.0), float)
        e = np.array([pose_errors(tracked[b][f], truth[b][f], centre)
                      if np.all(np.isfinite(tracked[b][f])) else np.full(6, np.nan)
                      for f in range(1, n)]).reshape(-1, 6)
        mm = np.linalg.norm(e[:, :3], axis=1)
        deg = np.linalg.norm(e[:, 3:], axis=1)
        ok = np.isfinite(mm)
        per_bone[b] = {"rms_mm": float(np.sqrt(np.mean(mm[ok] ** 2))) if ok.any() else None,
                       "rms_deg": float(np.sqrt(np.mean(deg[ok] ** 2))) if ok.any() else None,
                       "max_mm": float(np.max(mm[ok])) if ok.any() else None,
                       "max_deg": float(np.max(deg[ok])) if ok.any() else None,
                       "frames": int(ok.sum()),
                       "lost": bool(not ok.all() or np.max(mm[ok], initial=0.0) > lost_mm)}
    joints = default_joints(bones)
    frames_anat = anatomical_frames({b: volume_points(volumes[b]) for b in bones})
    rms = jcs_rms({b: tracked[b][1:] for b in bones}, {b: truth[b][1:] for b in bones}, joints, frames_anat)
    for j in joints:
        well = not (per_bone[j.proximal]["lost"] or per_bone[j.distal]["lost"])
        rms[j.name].update(proximal=j.proximal, distal=j.distal, angle_names=list(j.angle_names),
                           bones_tracked_well=well)
    return {"per_bone": per_bone, "jcs_rms_deg": rms}


def _machine() -> dict:
    return {"platform": platform.platform(), "cpu_count": os.cpu_count(), "python": platform.python_version(),
            "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None}


def check_tracked(demo, *, trial: str = "walk", bones=None, frames=None, lost_mm: float = 2.0) -> dict:
    """:func:`joint_check` of a demo folder's trial as its journal holds it (frames ``frames``,
    default all; the first is taken as the keyframe)."""
    from core.study import Study

    folder = Path(demo)
    with Study.open(folder) as st:
        t = st.trial(trial)
        names = list(bones or [b for b in ("tibia", "talus", "calcaneus") if b in t.bones])
        order = list(range(t.n_frames) if frames is None else frames)
        tracked = {b: t.poses(b)[order] for b in names}
        vols = {b: st.bone_volume(b) for b in names}
        calibration = t.calibration
    truth = {b: np.load(folder / "poses" / f"{b}.npy")[order] for b in names}
    out = {"study": "jcs_check", "demo": str(folder), "trial": trial, "calibration": calibration,
           "frames": [order[0], order[-1]], "bones": names, "lost_mm": lost_mm}
    out.update(joint_check(tracked, truth, vols, lost_mm=lost_mm))
    return out


def run(*, pixels: int = 128, frames: int = 6, demo_frames: int = 60, bones=("tibia", "talus", "calcaneus"),
        fast: bool = False, device: str = "cpu", lost_mm: float = 2.0, folder=None, spacing: float = 1.0,
        correct: bool = True, options=None, search: str | None = None, progress=None) -> dict:
    """Write a demo, track ``bones`` over its first ``frames`` frames and compare joint angles
    (see the module docs). ``correct=False`` tracks the raw frames divided by the full scale
    (what a trial without a correction gets), for comparison only. ``search`` replaces the
    tracking search of the options (default: the tracker's, ``TrackingOptions().registration.search``)."""
    from core.studies.calibration.truth import true_correction
    from core.study import Study
    from core.synthetic import make_demo_study
    from core.tracking.from_study import track_study
    from core.tracking.register import RegistrationOptions
    from core.tracking.trial import TrackingOptions

    say = progress or (lambda m: None)
    bones = list(bones)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(folder) if folder else Path(tmp) / "demo"
        t0 = time.perf_counter()
        say(f"writing the demo ({demo_frames} frames, {pixels} px)")
        make_demo_study(out, n_frames=max(demo_frames, frames), pixels=pixels, seed=0, device=device,
                        spacing=spacing, tissue_spacing=4.0 * spacing, calibration_session=False)
        t_demo = time.perf_counter() - t0
        truth = {b: np.load(out / "poses" / f"{b}.npy")[:frames] for b in bones}
        if fast:  # the GUI tests' options: a narrower local search, no confidence
            options = TrackingOptions(registration=RegistrationOptions(bounds=(4.0, 4.0), sigma=(1.0, 1.0),
                                                                       refine=None), confidence=False)
        label = "fast (GUI tests')" if fast else ("given" if options else "default")
        if search is not None:  # track_study's default options (mode "auto") with this search
            o = options or TrackingOptions(mode="auto")
            options = replace(o, registration=replace(o.registration, search=search))
        with Study.open(out, mode="w") as st:
            trial = st.trial("walk")
            corr = true_correction(out, [c.name for c in trial.rig()]) if correct else None
            say(f"tracking {', '.join(bones)} over frames 0-{frames - 1} on {device}")
            t0 = time.perf_counter()
            _, report = track_study(st, "walk", bones, list(range(frames)), options=options, device=device,
                                    correction=corr)
            t_track = time.perf_counter() - t0
            tracked = {b: trial.poses(b)[:frames] for b in bones}
            vols = {b: st.bone_volume(b) for b in bones}
        checked = joint_check(tracked, truth, vols, lost_mm=lost_mm)
    return {"study": "jcs_check", "demo": {"pixels": pixels, "frames": max(demo_frames, frames),
                                           "tracked_frames": frames, "seed": 0, "spacing_mm": spacing,
                                           "calibration": "true rig",
                                           "correction": ("the generator's flatfield and distortion"
                                                          if correct else "none (full scale)")},
            "bones": bones, "options": label,
            "search": (options or TrackingOptions()).registration.search,
            "device": device, "seconds": {"demo": t_demo, "tracking": t_track},
            "normalisation": report.get("normalisation"),
            "tracking_summary": report.get("summary"), "lost_mm": lost_mm, **checked,
            "machine": _machine()}


def main(argv=None) -> int:
    from core.io.atomic import print_json

    ap = argparse.ArgumentParser(prog="python -m core.studies.tracking.jcs_check",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("--pixels", type=int, default=128)
    ap.add_argument("--frames", type=int, default=6, help="frames tracked, from frame 0")
    ap.add_argument("--demo-frames", type=int, default=60,
                    help="length of the demo's walk (its motion spans the whole walk: 6 frames of a "
                         "6-frame demo move the bones tens of mm apart)")
    ap.add_argument("--spacing", type=float, default=1.0, help="bone voxel size of the demo, mm")
    ap.add_argument("--bones", default="tibia,talus,calcaneus")
    ap.add_argument("--fast", action="store_true", help="the GUI tests' faster tracking options")
    ap.add_argument("--search", choices=("local", "newton"), default=None,
                    help="search of a tracked frame (default the tracker's)")
    ap.add_argument("--uncorrected", action="store_true",
                    help="track the frames divided by the full scale only (no flatfield, still distorted)")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--lost-mm", type=float, default=2.0)
    ap.add_argument("--folder", default=None, help="write the demo here and keep it")
    ap.add_argument("--demo", default=None, help="a demo folder already tracked: compare its trial only")
    ap.add_argument("--trial", default="walk", help="with --demo: the trial to read")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    if a.demo:
        res = check_tracked(a.demo, trial=a.trial, bones=a.bones.split(","), lost_mm=a.lost_mm)
        print_json(res, a.out)
        return 0
    if a.frames < 2 or a.pixels < 32:
        ap.error("--frames: at least 2; --pixels: at least 32")
    res = run(pixels=a.pixels, frames=a.frames, demo_frames=a.demo_frames, bones=a.bones.split(","),
              fast=a.fast, device=a.device, lost_mm=a.lost_mm, spacing=a.spacing, correct=not a.uncorrected,
              folder=a.folder, search=a.search,
              progress=lambda m: print(f"[jcs check] {m}", file=sys.stderr, flush=True))
    print_json(res, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
