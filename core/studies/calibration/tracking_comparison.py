"""Tracking the demo trial with the estimated calibration against tracking it with the truth.

``python -m core.studies.calibration.tracking_comparison DEMO [--frames 0:20[:2]] [--bones a,b]
[--device cuda] [--out FILE]`` (a GPU job). ``DEMO`` is a folder written by
:func:`core.synthetic.make_demo_study` whose trial ``walk`` uses the calibration saved from its
session (``talus calibrate DEMO/calibration_session --study DEMO --trials all`` when it does not).
A second trial ``walk_truth`` over the same frames is added (once) with the true rig (the
study's calibration ``rig``) and corrected with the generator's true flatfield and distortion;
both start from the true frame-0 poses and are tracked by
:func:`core.tracking.from_study.track_study`. Per bone: RMS centroid (mm) and rotation (°) errors
against the true poses for each, and their differences (acceptance: ≤ 0.02 mm and ≤ 0.05°); per
trial the Grood–Suntay joint angles (ankle tibia–talus, subtalar talus–calcaneus) from the tracked
poses against those from the true poses (:func:`core.studies.tracking.jcs_check.joint_check`;
acceptance of the review issue: RMS ≤ 0.3°).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from core.studies.calibration.truth import true_correction

__all__ = ["main", "run", "true_correction"]


def _errors(study, trial: str, bone: str, frames, truth: np.ndarray) -> dict:
    from core.studies.tracking.acceptance import pose_errors

    P = study.trial(trial).poses(bone)
    vol = study.bone_volume(bone)
    centre = np.asarray(vol.centroid(200.0), float)
    e = np.array([pose_errors(P[f], truth[f], centre) for f in frames if np.all(np.isfinite(P[f]))])
    if not len(e):
        return {"frames": 0}
    return {"frames": len(e), "rms_mm": float(np.sqrt(np.mean(np.sum(e[:, :3] ** 2, axis=1)))),
            "rms_deg": float(np.sqrt(np.mean(np.sum(e[:, 3:] ** 2, axis=1))))}


def run(demo, *, frames=None, bones=None, device=None, progress=None) -> dict:
    from core.study import Study
    from core.tracking.from_study import track_study

    say = progress or (lambda m: None)
    folder = Path(demo)
    res: dict = {"demo": str(folder)}
    with Study.open(folder, mode="w") as st:
        walk = st.trial("walk")
        if walk.calibration == "rig":
            raise ValueError(f"{folder}: trial 'walk' still uses the true rig; run 'talus calibrate "
                             f"{folder / 'calibration_session'} --study {folder} --trials all' first")
        if "walk_truth" not in st.trials:
            st.add_trial("walk_truth", list(walk.view_paths), calibration="rig", bones=list(walk.bones),
                         bit_depth=st.manifest["trials"]["walk"]["views"][0].get("bit_depth"))
        names = list(bones or walk.bones)
        n = walk.n_frames
        order = list(range(n) if frames is None else frames)
        truths = {b: np.load(folder / "poses" / f"{b}.npy") for b in names}
        for b in names:
            for t in ("walk", "walk_truth"):
                st.trial(t).record_pose(b, 0, truths[b][0])
        cams = [c.name for c in st.trial("walk_truth").rig()]
        corr = {"walk": None, "walk_truth": true_correction(folder, cams)}
        for t in ("walk", "walk_truth"):
            say(f"tracking {t} ({st.trial(t).calibration})")
            t0 = time.perf_counter()
            _, rep = track_study(st, t, names, order, device=device, correction=corr[t])
            res[t] = {"calibration": st.trial(t).calibration, "normalisation": rep.get("normalisation"),
                      "seconds": time.perf_counter() - t0, "summary": rep.get("summary"),
                      "bones": {b: _errors(st, t, b, order, truths[b]) for b in names}}
            foot = [b for b in ("tibia", "talus", "calcaneus") if b in names]
            if len(foot) >= 2 and order[0] == 0:
                from core.studies.tracking.jcs_check import joint_check

                tr = st.trial(t)
                res[t]["jcs"] = joint_check({b: tr.poses(b)[order] for b in foot},
                                            {b: truths[b][order] for b in foot},
                                            {b: st.bone_volume(b) for b in foot})
    res["difference"] = {b: {"rms_mm": res["walk"]["bones"][b].get("rms_mm", np.nan)
                             - res["walk_truth"]["bones"][b].get("rms_mm", np.nan),
                             "rms_deg": res["walk"]["bones"][b].get("rms_deg", np.nan)
                             - res["walk_truth"]["bones"][b].get("rms_deg", np.nan)} for b in names}
    return res


def main(argv=None) -> int:
    from core.io.atomic import print_json

    ap = argparse.ArgumentParser(prog="python -m core.studies.calibration.tracking_comparison",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("demo")
    ap.add_argument("--frames", default=None,
                    help="START:STOP or START:STOP:STEP (every STEP-th frame: a faster walk)")
    ap.add_argument("--bones", default=None)
    ap.add_argument("--device", default=None)
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    frames = None
    if a.frames:
        frames = list(range(*(int(v) for v in a.frames.split(":"))))
    res = run(a.demo, frames=frames, bones=a.bones.split(",") if a.bones else None, device=a.device,
              progress=lambda m: print(f"[tracking comparison] {m}", file=sys.stderr, flush=True))
    print_json(res, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
