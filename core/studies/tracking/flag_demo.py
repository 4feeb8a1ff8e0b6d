"""Review flags of the foot demo against its truth, frame by frame (``python -m
core.studies.tracking.flag_demo``).

Writes the foot demo (:func:`core.synthetic.make_demo_study`) and tracks its bones with
:func:`core.tracking.from_study.track_study`, as :func:`core.studies.tracking.jcs_check.run`
does (the generator's flatfield and distortion, the true rig), then reads every frame's journal
record back — flags, notes, score, confidence σ — next to its error against the demo's true poses
(:func:`core.studies.tracking.acceptance.pose_errors`, centroid at 200 HU). Per bone:
``large`` (frames over ``large``, 1 mm or 2°), ``silent_large`` (those unflagged),
``false_flags`` (flagged within it), the false-flag rate of the frames within it, and the
separation of the large frames from the others by what a user has
(:func:`core.studies.tracking.flag_study.separation`).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["main", "run"]


def run(*, pixels: int = 128, frames: int = 12, bones=("tibia", "talus", "calcaneus", "metatarsal2"),
        device: str = "cpu", search: str | None = "local", spacing: float = 1.0, large=(1.0, 2.0)) -> dict:
    from core.studies.tracking.acceptance import pose_errors
    from core.studies.tracking.flag_study import _features, separation
    from core.studies.tracking.jcs_check import run as jcs_run
    from core.study import Study
    from core.tracking.results import FrameResult

    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "demo"
        info = jcs_run(pixels=pixels, frames=frames, demo_frames=frames, bones=tuple(bones), device=device,
                       folder=folder, spacing=spacing, search=search)
        per = {}
        with Study.open(folder) as st:
            trial = st.trial("walk")
            for b in bones:
                truth = np.load(folder / "poses" / f"{b}.npy")
                centre = np.asarray(st.bone_volume(b).centroid(200.0), float)
                state = trial.results(b)
                rows = []
                for f in range(frames):
                    r = state.done.get(f)
                    if r is None or r.kind != "tracked":
                        continue
                    fr = FrameResult.from_journal(b, r)
                    e = pose_errors(fr.pose, truth[f], centre) if fr.pose is not None else np.full(6, np.nan)
                    et, er = float(np.linalg.norm(e[:3])), float(np.linalg.norm(e[3:]))
                    bad = not (et <= large[0] and er <= large[1])
                    sig = (fr.confidence or {}).get("sigma")
                    rows.append({"frame": f, "score": round(float(fr.score), 4), "error_mm": round(et, 4),
                                 "error_deg": round(er, 4), "kind": "large" if bad else "good",
                                 "flags": list(fr.flags), "notes": list(fr.notes),
                                 "sigma": None if sig is None else [None if v is None else round(v, 4)
                                                                   for v in sig],
                                 "pose": None if fr.pose is None else [
                                     round(float(v), 5) for v in np.asarray(fr.pose)[:3].ravel()]})
                _features(rows, centre, 10)
                good = [r for r in rows if r["kind"] == "good"]
                silent = [r["frame"] for r in rows if r["kind"] == "large" and not r["flags"]]
                per[b] = {"large": [r["frame"] for r in rows if r["kind"] == "large"],
                          "silent_large": silent,
                          "false_flags": [r["frame"] for r in good if r["flags"]],
                          "good_frames": len(good),
                          "false_flag_rate": sum(1 for r in good if r["flags"]) / len(good) if good else None,
                          "flagged": {r["frame"]: r["flags"] for r in rows if r["flags"]},
                          "rms_mm": float(np.sqrt(np.nanmean([r["error_mm"] ** 2 for r in rows]))),
                          "rms_deg": float(np.sqrt(np.nanmean([r["error_deg"] ** 2 for r in rows]))),
                          "separation": separation(rows), "frames": rows}
    return {"study": "core.studies.tracking.flag_demo", "pixels": pixels, "frames": frames,
            "spacing_mm": spacing,
            "device": device, "search": info.get("search"), "tracking_summary": info.get("tracking_summary"),
            "seconds": {**info.get("seconds", {}), "total": time.perf_counter() - t0}, "large": list(large),
            "bones": per}


def main(argv=None) -> int:
    from core.io.atomic import print_json

    ap = argparse.ArgumentParser(prog="python -m core.studies.tracking.flag_demo",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("--pixels", type=int, default=128)
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--bones", default="tibia,talus,calcaneus,metatarsal2")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--search", default="local")
    ap.add_argument("--voxel", type=float, default=1.0)
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    print_json(run(pixels=a.pixels, frames=a.frames, bones=tuple(a.bones.split(",")), device=a.device,
                   search=a.search, spacing=a.voxel), a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
