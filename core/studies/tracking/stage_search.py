"""The similarity search's tolerance before the likelihood final stage, on the acceptance trial:
``python -m core.studies.tracking.stage_search [--pixels 512] [--frames 20] [--seeds 0,4]
[--modes joint,sequential] [--tols full,0.25]``.

With a final stage (``--final likelihood`` of the acceptance study) the ``"newton"`` search's
full-resolution level stops at :data:`core.tracking.register_options.STAGE_SEARCH_TOL` (mm, degrees)
instead of its own 0.02: the stage refines the pose by its own cost and only needs a start inside
its basin. Each entry of ``--tols`` runs :func:`core.studies.tracking.acceptance.run` (``final=
"likelihood"``, no capture range) with that tolerance (``full``: None, the search to its own
tolerance as before) on the same scene and frames, mode after mode; per run and bone the error
over the Cramér–Rao bound (mm / degrees), the frames over 4× it and those of them not flagged
(silent), the converged fraction, and per bone-frame the search's 13-pose steps, the stage's steps
and the evaluations (search and stage). JSON on stdout (and ``--out``).
"""

from __future__ import annotations

import argparse
import json
import platform
import time

import numpy as np

__all__ = ["main", "run"]


def _tol(s: str) -> float | str | None:
    return None if s == "full" else s if s == "first" else float(s)


def _steps(res) -> dict:
    """Per bone-frame means of the search's steps (13-pose launches at every scale), the stage's
    steps and the evaluations of a tracking result (every frame but the first)."""
    rs = [r for r in res.results.values() if r.frame > 0 and r.timing]
    if not rs:
        return {}
    gn = [sum(v for k, v in r.timing.items() if k.startswith("engine_steps_x")) for r in rs]
    st = [r.timing.get("likelihood_steps", 0) for r in rs]
    return {"search_steps": float(np.mean(gn)), "stage_steps": float(np.mean(st)),
            "evaluations": float(np.mean([r.evaluations for r in rs])),
            "stage_taken": float(np.mean([r.timing.get("likelihood_taken", 0) for r in rs]))}


def _digest(out: dict) -> dict:
    """The acceptance run's figures this study compares, per bone."""
    d = {}
    for n, t in out["tracking"].items():
        ob = t.get("over_4x_bound") or {}
        d[n] = {"over_bound": t.get("rms_over_bound"), "rms_mm": t["rms_error_mm"],
                "rms_deg": t["rms_error_deg"],
                "over_4x": ob.get("frames"), "silent": ob.get("silent_frames"),
                "converged": t["converged_fraction"], "flagged": t.get("flagged_frames")}
    return d


def run(*, pixels: int = 512, voxel: float = 1.0, frames: int = 20, seeds=(0, 4),
        modes=("joint", "sequential"),
        tols=(None, 0.25), device: str | None = None, out_path: str | None = None,
        workers: int = 0) -> dict:
    """Every (seed, mode, tolerance) on the acceptance scene of each seed (module docs); ``out_path``:
    the JSON written there after each run too."""
    import core.tracking.register as reg
    import core.tracking.register_options as ro
    import core.tracking.trial as trial
    from core.studies.tracking.acceptance import DEFAULT_CORRECTION, TrackingScene
    from core.studies.tracking.acceptance import run as accept

    kept, kept_first = ro.STAGE_SEARCH_TOL, reg.STAGE_FIRST
    plain = trial.track
    got: list = []

    def track(*a, **k):  # the tracking result, for the steps the acceptance JSON does not keep
        r = plain(*a, **k)
        got.append(r)
        return r

    out = {"study": "core.studies.tracking.stage_search", "machine": platform.machine(),
           "processor": platform.processor() or platform.machine(), "pixels": pixels, "voxel_mm": voxel,
           "frames": frames, "runs": {}}
    try:
        trial.track = track
        for seed in seeds:
            ts = TrackingScene(n_frames=frames, pixels=pixels, spacing=voxel, seed=seed,
                               phase=(0.0, 0.6 * frames / 100.0), device=device,
                               correction=DEFAULT_CORRECTION)
            for mode in modes:
                for tol in tols:
                    # "first": the stage from the prediction, the search (to 0.5) only where its move is
                    # not taken (core.tracking.register.STAGE_FIRST; one bone's registrations, not
                    # joint tracking's side-by-side searches)
                    reg.STAGE_FIRST = tol == "first"
                    ro.STAGE_SEARCH_TOL = 0.5 if tol == "first" else tol
                    got.clear()
                    t0 = time.perf_counter()
                    a = accept(ts=ts, mode=mode, final="likelihood", capture_trials=0, workers=workers)
                    key = f"seed{seed}_{mode}_{'full' if tol is None else tol}"
                    out["runs"][key] = {"seed": seed, "mode": mode, "stage_search_tol": tol,
                                        "wall_s": time.perf_counter() - t0,
                                        "tracking_s_per_frame": a["summary"]["time_per_frame_s"],
                                        "per_bone_frame": _steps(got[-1]) if got else {},
                                        "bones": _digest(a)}
                    if out_path:  # each run kept as soon as it is done
                        from core.io.atomic import atomic_write

                        atomic_write(out_path, json.dumps(out, indent=2) + "\n")
    finally:
        ro.STAGE_SEARCH_TOL, reg.STAGE_FIRST = kept, kept_first
        trial.track = plain
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.stage_search",
                                description=__doc__.split("\n")[0])
    p.add_argument("--pixels", type=int, default=512)
    p.add_argument("--voxel", type=float, default=1.0)
    p.add_argument("--frames", type=int, default=20, help="at least 10 (the study low-passes the kinematics)")
    p.add_argument("--seeds", default="0,4")
    p.add_argument("--modes", default="joint,sequential")
    p.add_argument("--tols", default="full,0.25",
                   help="comma-separated: full (the search's own 0.02), a tolerance (mm, degrees) or first "
                   "(the stage from the prediction: register.STAGE_FIRST; sequential mode)")
    p.add_argument("--device", default=None)
    p.add_argument("--workers", type=int, default=0, help="processes for the frames' image chain")
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    res = run(pixels=a.pixels, voxel=a.voxel, frames=a.frames, seeds=[int(s) for s in a.seeds.split(",")],
              modes=[m.strip() for m in a.modes.split(",")],
              tols=[_tol(t.strip()) for t in a.tols.split(",")],
              device=a.device, out_path=a.out, workers=a.workers)
    from core.io.atomic import print_json

    print_json(res, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
