"""The final stage's band at the round field's rim from the true poses, every bone (``python -m
core.studies.tracking.rim_band``).

:mod:`core.studies.tracking.border_frames`' set-up (its frames: the trial's, the exact distortion
model, noisy by default; the tracker's preparation; the other bones at their TRUE poses
subtracted; the stage's model of the trial) with the band of the user's path
(:func:`core.tracking.likelihood_rim.apply_rim`, ``FinalModel.rim_sigmas``) off and on, per bone:
the RMS error over the frames' Cramér–Rao bound, the stage's sandwich σ over the bound, and the
region's pixels the band takes (0 where no black pixel is near: the stage is then the same to the
bit). Study only: it reads the truth. JSON on stdout (and ``--out``).
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np

__all__ = ["main", "run"]


def run(*, pixels: int = 512, voxel: float = 1.0, frames=(0, 20, 40, 60, 80),
        bones=("tibia", "talus", "calcaneus"), highpass: float = 4.0, rims=(None, 3.0), noise: bool = True,
        device: str | None = "cpu", checkpoint=None) -> dict:
    """The study (module docs); ``highpass``: the stage's σ in px at ``pixels`` (4 px at 512² is the
    trial's 8 px at 1024²)."""
    from core.studies.tracking.acceptance import TrackingScene, cramer_rao
    from core.studies.tracking.border_frames import _stage, frame_images, prepared

    t0 = time.perf_counter()
    ts = TrackingScene(n_frames=100, pixels=pixels, spacing=voxel, device=device, correction="exact")
    frames = [int(f) for f in frames]
    bound = cramer_rao(ts, frames)
    out = {"study": "core.studies.tracking.rim_band", "machine": platform.machine(), "pixels": pixels,
           "voxel_mm": voxel, "frames": frames, "noise": noise, "highpass_px": highpass,
           "rims": list(rims), "cramer_rao": {k: {"rms_mm": v["rms_mm"], "rms_deg": v["rms_deg"]}
                                              for k, v in bound.items()}}
    rec: dict = {}
    for f in frames:
        frame = prepared(frame_images(ts, f, "replicate", noise=noise), "trial", highpass)
        for nm in bones:
            for rim in rims:
                rec.setdefault((nm, rim), []).append(_stage(ts, frame, f, ts.names.index(nm), highpass, rim))
        res: dict = {}
        for (nm, rim), rows in rec.items():
            E = np.array([x[0] for x in rows])
            S = np.array([x[1] for x in rows])
            b = bound[nm]
            res.setdefault(nm, {})["off" if rim is None else f"rim{rim:g}"] = {
                "over_bound": [round(float(np.sqrt(np.mean(np.sum(E[:, :3] ** 2, 1)))) / b["rms_mm"], 3),
                               round(float(np.sqrt(np.mean(np.sum(E[:, 3:] ** 2, 1)))) / b["rms_deg"], 3)],
                "sandwich_sigma_over_bound": [
                    round(float(np.sqrt(np.nanmean(np.sum(S[:, :3] ** 2, 1)))) / b["rms_mm"], 3),
                    round(float(np.sqrt(np.nanmean(np.sum(S[:, 3:] ** 2, 1)))) / b["rms_deg"], 3)],
                "pixels_banded": [x[2] for x in rows], "per_frame_error": E.round(5).tolist()}
        out["results"] = res
        out["frames_done"] = f
        out["seconds"] = time.perf_counter() - t0
        print(f"frame {f} {out['seconds']:.0f} s: " + "; ".join(
            f"{nm} " + " ".join(f"{k} {v['over_bound'][0]:.2f}/{v['over_bound'][1]:.2f}"
                                for k, v in d.items()) for nm, d in res.items()), flush=True)
        if checkpoint:
            checkpoint(out)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.rim_band",
                                description=__doc__.split("\n")[0])
    p.add_argument("--pixels", type=int, default=512)
    p.add_argument("--voxel", type=float, default=1.0)
    p.add_argument("--frames", default="0,20,40,60,80")
    p.add_argument("--bones", default="tibia,talus,calcaneus")
    p.add_argument("--highpass", type=float, default=4.0, help="the stage's high-pass σ (px at --pixels)")
    p.add_argument("--noise-free", action="store_true")
    p.add_argument("--device", default="cpu")
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    from core.io.atomic import json_checkpoint, print_json

    checkpoint = json_checkpoint(a.out, indent=1)

    res = run(pixels=a.pixels, voxel=a.voxel, frames=[int(x) for x in a.frames.split(",") if x],
              bones=tuple(a.bones.split(",")), highpass=a.highpass, noise=not a.noise_free, device=a.device,
              checkpoint=checkpoint)
    print_json(res, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
