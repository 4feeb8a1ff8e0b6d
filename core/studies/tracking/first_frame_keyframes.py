"""A run's first frame from keyframes off the truth, on the ideal 128² talus-calcaneus scene (Warp's CPU
device): each bone's first-frame error and the frame's evaluations per draw, with a switch of
:mod:`core.tracking.frame_step` off and on (``python -m core.studies.tracking.first_frame_keyframes``).

The scene is ``tests/core/tracking/conftest.py``'s ``talus_calcaneus_128`` (1.5 mm voxels, no soft
tissue, noise-free); the keyframes are the true frame-0 poses moved ``--off`` mm and degrees in random
directions (draw ``d``: ``numpy.random.default_rng(d)``, the talus's translation and rotation directions,
then the calcaneus's). Tracking: Gauss–Newton search, bounds 5 mm / 5°, ``--restarts`` restart checks
(default 0), sequential with ``sequential_subtract`` or joint with one round (``--mode``). The switch
(``--switch``) is set off, then on, for every draw: ``SEQUENTIAL_SECOND_PASS`` (sequential's second pass
in a first frame), ``FIRST_FRAME_CHECK_FROM_ROUND0`` (a first frame's second round or pass checked from
round 0's poses), or any other boolean of the module.

Findings (this 2-core x86_64 machine, shared;
``resources/benchmarks/first_frame_keyframes_sequential_cpu.json``, ``…_joint_cpu.json``) are in
:data:`core.tracking.frame_step.SEQUENTIAL_SECOND_PASS`'s and
:data:`~core.tracking.frame_step.FIRST_FRAME_CHECK_FROM_ROUND0`'s docs.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def scene(names=("talus", "calcaneus")):
    """``(scene, models, renderer, frames)`` of the ideal 128² scene of bones ``names`` (frame 0)."""
    from core.render import DRRRenderer
    from core.synthetic import make_foot_scene
    from core.tracking.bones import bone_model

    sc = make_foot_scene(n_frames=2, pixels=128, spacing=1.5, names=tuple(names), beads_per_bone=0,
                         phase=(0.0, 0.03), soft_tissue=False, imaging="ideal", floor_thickness_mm=0)
    models = [bone_model(b, mesh=False) for b in sc.bones]
    r = DRRRenderer(sc.rig, [b.to_attenuation(sc.bone_transfer) for b in sc.bones], device="cpu")
    frames = {0: [m.to_float(f) for m, f in zip(sc.imaging, sc.render_frame(0), strict=True)]}
    return sc, models, r, frames


def keyframes(sc, models, draw: int, off: float) -> dict:
    """Frame-0 keyframes ``off`` mm and degrees from the truth in random directions (draw ``draw``)."""
    from core.geometry.transforms import pose_from_params

    g = np.random.default_rng(draw)
    out = {}
    for k, m in enumerate(models):
        d, a = g.normal(size=3), g.normal(size=3)
        p = np.r_[d / np.linalg.norm(d) * off, a / np.linalg.norm(a) * np.radians(off)]
        out[m.name] = {0: pose_from_params(p, center=m.centroid, base=sc.poses(0)[k])}
    return out


def first_frame(built, keys: dict, *, mode: str, restarts: int = 0) -> dict:
    """Each bone's first-frame error (mm, degrees), evaluations and flags, and the seconds taken."""
    from core.tracking.register import RegistrationOptions
    from core.tracking.trial import TrackingOptions

    reg = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")
    o = TrackingOptions(mode=mode, joint_rounds=1, sequential_subtract=mode == "sequential",
                        verify_restarts=restarts, registration=reg, trajectory_limit=None)
    return tracked_first_frame(built, keys, o)


def tracked_first_frame(built, keys: dict, options, *, extra: bool = False) -> dict:
    """Frame 0 of ``built`` tracked from ``keys`` with the tracking ``options``: each bone's error (mm,
    degrees), evaluations and flags (``extra``: also its notes, whether its final stage was taken and its
    pose), and the seconds taken."""
    from core.tracking.checks import pose_delta
    from core.tracking.trial import track

    sc, models, r, frames = built
    t0 = time.perf_counter()
    res = track(r, models, frames.__getitem__, [0], keyframes=keys, options=options)
    out = {"seconds": time.perf_counter() - t0}
    for k, m in enumerate(models):
        fr = res.results[(m.name, 0)]
        d = pose_delta(sc.poses(0)[k], fr.pose, m.centroid)
        out[m.name] = {"mm": float(np.linalg.norm(d[:3])), "deg": float(np.degrees(np.linalg.norm(d[3:]))),
                       "evaluations": int(fr.evaluations), "flags": list(fr.flags)}
        if extra:
            out[m.name].update(notes=list(fr.notes), stage_taken=(fr.timing or {}).get("likelihood_taken"),
                               pose=fr.pose.tolist())
    return out


def main(argv=None) -> int:
    import core.tracking.frame_step as fs

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mode", choices=("sequential", "joint"), default="sequential")
    ap.add_argument("--switch", default="SEQUENTIAL_SECOND_PASS")
    ap.add_argument("--off", type=float, default=5.0, help="keyframes this many mm and degrees off")
    ap.add_argument("--draws", default="0,1,2,3,4,5")
    ap.add_argument("--restarts", type=int, default=0)
    ap.add_argument("--bones", default="talus,calcaneus", help="the scene's bones (tracked in this order)")
    ap.add_argument("--machine-name", default="this 2-core x86_64 machine (CPU)")
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args(argv)
    if not isinstance(getattr(fs, a.switch, None), bool):
        ap.error(f"--switch: {a.switch} is not a boolean switch of core.tracking.frame_step")
    built = scene(a.bones.split(","))
    runs = []
    kept = getattr(fs, a.switch)
    try:
        for draw in (int(x) for x in a.draws.split(",")):
            keys = keyframes(built[0], built[1], draw, a.off)
            row = {"draw": draw}
            for on in (False, True):
                setattr(fs, a.switch, on)
                row["on" if on else "off"] = got = first_frame(built, keys, mode=a.mode, restarts=a.restarts)
                print(f"draw {draw} {a.switch}={'on' if on else 'off'}: " + "; ".join(
                    f"{m.name} {got[m.name]['mm']:.4f} mm {got[m.name]['deg']:.4f} deg "
                    f"{got[m.name]['evaluations']} evals" for m in built[1]), flush=True)
            runs.append(row)
    finally:  # (the switch as it was: main may run inside another program, a test)
        setattr(fs, a.switch, kept)
    if a.json is not None:
        git = ["git", "rev-parse", "--short", "HEAD"]
        commit = subprocess.run(git, capture_output=True, text=True).stdout.strip()
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps({
            "command": " ".join(["python -m core.studies.tracking.first_frame_keyframes",
                                 *(argv or sys.argv[1:])]),
            "commit": commit, "machine": a.machine_name, "device": "Warp CPU", "mode": a.mode,
            "bones": a.bones.split(","), "switch": a.switch, "off_mm_deg": a.off, "restarts": a.restarts,
            "runs": runs}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
