"""Joint angles of the tracked demo against those of its ground-truth poses (Grood–Suntay JCS).

``python -m core.studies.tracking.jcs_check [--pixels 128] [--frames 6] [--demo-frames 60]
[--bones tibia,talus,calcaneus] [--fast] [--device cpu] [--out JSON]``

A small foot demo (:func:`core.synthetic.make_demo_study`, the true rig, no calibration session)
is tracked from the true frame-0 poses (its keyframes) with
:func:`core.tracking.from_study.track_study`; the joints of :func:`core.tracking.jcs.default_joints`
(ankle tibia–talus, subtalar talus–calcaneus), with principal-axes anatomical frames from the
CTs, give JCS angles from the tracked poses and from the generator's true poses, compared by
:func:`core.tracking.jcs.jcs_rms` (per angle and over all three, degrees; frame 0 is the
keyframe and left out). Per bone the RMS centroid (mm) and rotation (°) errors say which bones
were tracked well: a joint is only as good as its two bones, so the JSON marks each joint whose
bones both stayed within ``--lost-mm`` (default 2 mm) at every frame. Only this study reads the
truth (``poses/*.npy`` of the demo folder).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["main", "run"]


def run(*, pixels: int = 128, frames: int = 6, demo_frames: int = 60, bones=("tibia", "talus", "calcaneus"),
        fast: bool = False, device: str = "cpu", lost_mm: float = 2.0, folder=None, progress=None) -> dict:
    from core.studies.tracking.acceptance import pose_errors
    from core.study import Study
    from core.synthetic import make_demo_study
    from core.tracking.from_study import track_study
    from core.tracking.jcs import anatomical_frames, default_joints, jcs_rms, volume_points
    from core.tracking.register import RegistrationOptions
    from core.tracking.trial import TrackingOptions

    say = progress or (lambda m: None)
    bones = list(bones)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(folder) if folder else Path(tmp) / "demo"
        t0 = time.perf_counter()
        say(f"writing the demo ({demo_frames} frames, {pixels} px)")
        make_demo_study(out, n_frames=max(demo_frames, frames), pixels=pixels, seed=0, device=device,
                        spacing=1.0, tissue_spacing=4.0, calibration_session=False)
        t_demo = time.perf_counter() - t0
        truth = {b: np.load(out / "poses" / f"{b}.npy")[:frames] for b in bones}
        options = None
        if fast:  # the GUI tests' options: a narrower local search, no confidence
            options = TrackingOptions(registration=RegistrationOptions(bounds=(4.0, 4.0), sigma=(1.0, 1.0),
                                                                       refine=None), confidence=False)
        with Study.open(out, mode="w") as st:
            say(f"tracking {', '.join(bones)} over frames 0-{frames - 1} on {device}")
            t0 = time.perf_counter()
            _, report = track_study(st, "walk", bones, list(range(frames)), options=options, device=device)
            t_track = time.perf_counter() - t0
            trial = st.trial("walk")
            tracked = {b: trial.poses(b)[:frames] for b in bones}
            vols = {b: st.bone_volume(b) for b in bones}
        per_bone = {}
        for b in bones:
            centre = np.asarray(vols[b].centroid(200.0), float)
            e = np.array([pose_errors(tracked[b][f], truth[b][f], centre)
                          if np.all(np.isfinite(tracked[b][f])) else np.full(6, np.nan)
                          for f in range(1, frames)])
            mm = np.linalg.norm(e[:, :3], axis=1)
            deg = np.linalg.norm(e[:, 3:], axis=1)
            per_bone[b] = {"rms_mm": float(np.sqrt(np.nanmean(mm ** 2))),
                           "rms_deg": float(np.sqrt(np.nanmean(deg ** 2))),
                           "max_mm": float(np.nanmax(mm)), "frames": int(np.isfinite(mm).sum()),
                           "lost": bool(not np.all(np.isfinite(mm)) or np.nanmax(mm) > lost_mm)}
        joints = default_joints(bones)
        frames_anat = anatomical_frames({b: volume_points(vols[b]) for b in bones})
        later = {b: tracked[b][1:] for b in bones}
        ref = {b: truth[b][1:] for b in bones}
        rms = jcs_rms(later, ref, joints, frames_anat)
        for j in joints:
            well = not (per_bone[j.proximal]["lost"] or per_bone[j.distal]["lost"])
            rms[j.name].update(proximal=j.proximal, distal=j.distal, angle_names=list(j.angle_names),
                               bones_tracked_well=well)
    return {"study": "jcs_check", "demo": {"pixels": pixels, "frames": max(demo_frames, frames),
                                           "tracked_frames": frames, "seed": 0, "spacing_mm": 1.0,
                                           "calibration": "true rig"},
            "bones": bones, "options": "fast (GUI tests')" if fast else "default",
            "device": device, "seconds": {"demo": t_demo, "tracking": t_track},
            "tracking_summary": report.get("summary"), "lost_mm": lost_mm, "per_bone": per_bone,
            "jcs_rms_deg": rms,
            "machine": {"platform": platform.platform(), "cpu_count": os.cpu_count(),
                        "python": platform.python_version(),
                        "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None}}


def main(argv=None) -> int:
    from core.io.atomic import print_json

    ap = argparse.ArgumentParser(prog="python -m core.studies.tracking.jcs_check",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("--pixels", type=int, default=128)
    ap.add_argument("--frames", type=int, default=6, help="frames tracked, from frame 0")
    ap.add_argument("--demo-frames", type=int, default=60,
                    help="length of the demo's walk (its motion spans the whole walk: 6 frames of a "
                         "6-frame demo move the bones tens of mm apart)")
    ap.add_argument("--bones", default="tibia,talus,calcaneus")
    ap.add_argument("--fast", action="store_true", help="the GUI tests' faster tracking options")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--lost-mm", type=float, default=2.0)
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    if a.frames < 2 or a.pixels < 32:
        ap.error("--frames: at least 2; --pixels: at least 32")
    res = run(pixels=a.pixels, frames=a.frames, demo_frames=a.demo_frames, bones=a.bones.split(","),
              fast=a.fast, device=a.device, lost_mm=a.lost_mm,
              progress=lambda m: print(f"[jcs check] {m}", file=sys.stderr, flush=True))
    print_json(res, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
