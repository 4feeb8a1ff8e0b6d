"""Sequential tracking's first-frame second pass with the final stage and without ``sequential_subtract``:
the whole first pass again (:data:`core.tracking.frame_step.SECOND_PASS_STAGE_ONLY` off) against the
stage alone from the first pass's pose (on), on the ideal 128² scene of
:func:`core.studies.tracking.first_frame_keyframes.scene` from keyframes ``--off`` mm and degrees off the
truth (``python -m core.studies.tracking.second_pass_stage``).

Per draw and bone: the first frame's error (mm, degrees), evaluations, flags and notes with the switch off
and on, and the two poses' distance (mm, degrees). Tracking: Gauss–Newton search, bounds 5 mm / 5°, the
likelihood stage (high-pass ``--highpass`` px), ``--restarts`` restart checks (the tracker's default 4).
Findings: :mod:`core.tracking.second_pass`'s docs and the JSON (``--json``).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np


def first_frame(built, keys: dict, *, restarts: int, highpass: float) -> dict:
    """Each bone's first-frame pose, error (mm, degrees), evaluations, flags and notes; the seconds."""
    from core.studies.tracking.first_frame_keyframes import tracked_first_frame
    from core.tracking.register import RegistrationOptions
    from core.tracking.trial import TrackingOptions

    reg = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton",
                              final_highpass_px=highpass)
    o = TrackingOptions(mode="sequential", sequential_subtract=False, verify_restarts=restarts,
                        registration=reg, refine_likelihood=True, trajectory_limit=None)
    return tracked_first_frame(built, keys, o, extra=True)


def main(argv=None) -> int:
    import core.tracking.frame_step as fs
    from core.studies.tracking.first_frame_keyframes import keyframes, scene
    from core.tracking.checks import pose_delta

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--off", type=float, default=5.0, help="keyframes this many mm and degrees off")
    ap.add_argument("--draws", default="0,1,2")
    ap.add_argument("--restarts", type=int, default=4)
    ap.add_argument("--highpass", type=float, default=2.0)
    ap.add_argument("--bones", default="talus,calcaneus", help="the scene's bones (tracked in this order)")
    ap.add_argument("--machine-name", default="this 2-core x86_64 machine (CPU)")
    ap.add_argument("--json", type=Path, default=None)
    a = ap.parse_args(argv)
    built = scene(a.bones.split(","))
    runs = []
    kept = fs.SECOND_PASS_STAGE_ONLY
    try:
        for draw in (int(x) for x in a.draws.split(",")):
            keys = keyframes(built[0], built[1], draw, a.off)
            row: dict = {"draw": draw}
            for on in (False, True):
                fs.SECOND_PASS_STAGE_ONLY = on
                row["on" if on else "off"] = first_frame(built, keys, restarts=a.restarts,
                                                         highpass=a.highpass)
            row["apart"] = {}
            for m in built[1]:
                P0, P1 = np.array(row["off"][m.name]["pose"]), np.array(row["on"][m.name]["pose"])
                d = pose_delta(P0, P1, m.centroid)
                row["apart"][m.name] = {"mm": float(np.linalg.norm(d[:3])),
                                        "deg": float(np.degrees(np.linalg.norm(d[3:]))),
                                        "equal": bool(np.array_equal(P0, P1))}
            runs.append(row)
            print(f"draw {draw}: " + "; ".join(
                f"{m.name} off {row['off'][m.name]['mm']:.4f} mm {row['off'][m.name]['deg']:.4f} deg "
                f"{row['off'][m.name]['evaluations']} evals {row['off'][m.name]['flags']}, on "
                f"{row['on'][m.name]['mm']:.4f} mm {row['on'][m.name]['deg']:.4f} deg "
                f"{row['on'][m.name]['evaluations']} evals {row['on'][m.name]['flags']}, apart "
                f"{row['apart'][m.name]['mm']:.2e} mm {row['apart'][m.name]['deg']:.2e} deg"
                for m in built[1])
                + f"; seconds {row['off']['seconds']:.1f} / {row['on']['seconds']:.1f}", flush=True)
    finally:  # (the switch as it was: main may run inside another program, a test)
        fs.SECOND_PASS_STAGE_ONLY = kept
    if a.json is not None:
        git = ["git", "rev-parse", "--short", "HEAD"]
        commit = subprocess.run(git, capture_output=True, text=True).stdout.strip()
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps({
            "command": " ".join(["python -m core.studies.tracking.second_pass_stage",
                                 *(argv or sys.argv[1:])]),
            "commit": commit, "machine": a.machine_name, "device": "Warp CPU", "bones": a.bones.split(","),
            "off_mm_deg": a.off, "restarts": a.restarts, "highpass_px": a.highpass, "runs": runs}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
