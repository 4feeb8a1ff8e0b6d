"""Real-data check: track the radius and ulna of the Autoscoper wrist sample over its three frames.

``python -m core.studies.tracking.wrist_check [--data DIR] [--device cuda:0] [--search global|global_newton]
[--out JSON] [--figure PNG]``

The sample (:mod:`core.samples`) has no ground truth, so the check reports what can be judged:
the final similarity per bone, frame and view, how far registration moved each bone from its
hand-placed start, the per-frame confidence, the review flags, and overlays of the registered
bones' outlines on both radiographs (look at them).

Starting poses (frame 0099)
---------------------------
* radius — :data:`core.samples.WRIST_RADIUS_POSE` (hand-found; the similarity study found the
  gradient metrics' optimum ≈ 1.2 mm / 2.5° from it);
* ulna — :data:`WRIST_ULNA_START`, found the same way: the ulna's shaft centre line was picked
  in both radiographs (its edges on rows 1500–1700 of camera 2 and 1440–1630 of camera 1,
  matched along epipolar lines) and triangulated; the CT's slice axis (the shaft axis of the
  bone's voxels, proximal two thirds) was laid along it, starting from the radius's rotation
  (both sub-volumes come from one CT, so their axes agree up to the forearm's pronation; the
  shaft needed a 10.8° turn); the roll about the shaft (nine tried, −60…60° in steps of 15°) and
  the position along it (±30 mm in 2 mm steps) were chosen by gradient correlation at quarter
  resolution, and the outline was checked by eye: the ulnar head sits under the carpus in both
  views. A start for tracking, not a registration result.

Tracking: frames in the order 0099, 0158, 0002 (the start's frame first; the frames are 59 and
97 camera frames apart, so each starts from the bone's previous pose with a global search),
each bone on its own (``mode="sequential"``: joint tracking subtracts the other bone's DRR from
the radiograph, which needs DRR intensities matched to the images — these 8-bit radiographs are
not flatfield-corrected, and a run with joint tracking pulled the radius onto the hole left where
the ulna was subtracted in camera 1), 8-bit grey / 255 as
relative fluence (the radiographs are not flatfield-corrected) with pixels below 0.12 (outside
the field) or above 0.995 (saturated air) and 5 px around them masked, bone above 300 HU,
0.5 mm ray steps, and ``final_scale`` 2 (0.29 mm DRR pixels at the bones; the radiographs'
0.15 mm pixels carry more noise than detail).

``--search global_newton`` runs the global search's Gauss–Newton form (CMA-ES, then Gauss–Newton
steps) in every frame instead. On one NVIDIA H100, same call as the quadratic form
(``resources/benchmarks/tracking_search_default_h100.json``): 1.9 s against 2.8 s of tracking, the
ulna within 0.11 mm / 0.62° of the quadratic form's poses in 0099 and 0158, but the radius in 0158
17 mm away at a much lower score (0.283 against 0.402) and unflagged (its frame 0099, flagged as not
converged, gave the score checks no history). With the flagged first frame's score as the reference
(:func:`core.tracking.checks.failures`; one H200,
``resources/benchmarks/tracking_flags2_h200.json``) that frame is flagged low, retried wider to
0.397 within 0.5 mm / 0.9° (pose origin) of the quadratic form's pose, and flagged ``"ambiguous
optimum"`` by the restart check; the radius in 0002 (0.382 before, unflagged) ends at 0.445, flagged
ambiguous as well.
"""

from __future__ import annotations

import argparse
import platform
import time
from pathlib import Path

import numpy as np

from core.studies import sample_data_dir

__all__ = ["WRIST_ULNA_START", "main", "run"]

WRIST_ULNA_START = np.array(
    [
        [-0.836974, -0.544629, -0.053104, 147.894100],
        [-0.069030, 0.008749, 0.997576, 125.427400],
        [-0.542837, 0.838662, -0.044934, 108.107900],
        [0.0, 0.0, 0.0, 1.0],
    ]
)
_u, _s, _vt = np.linalg.svd(WRIST_ULNA_START[:3, :3])
WRIST_ULNA_START[:3, :3] = _u @ _vt
WRIST_ULNA_START.setflags(write=False)

ORDER = (1, 2, 0)  # frame indices: 0099 (the start), 0158, 0002
BONES = ("radius", "ulna")


def _options(final_scale: float, first_widen: float = 1.0, search: str = "global"):
    from core.tracking.register import RegistrationOptions
    from core.tracking.trial import TrackingOptions

    reg = RegistrationOptions(bounds=(10.0, 10.0), sigma=(2.0, 2.0), search=search, final_scale=final_scale)
    return TrackingOptions(registration=reg, first=reg.widened(first_widen), guess="previous",
                           mode="sequential", max_jump=(15.0, 20.0), valid_range=(0.12, 0.995), erode_px=5)


def run(data_dir: str | Path, *, device: str | None = None, final_scale: float = 2.0,
        figure: str | None = None, first_widen: float = 1.0, search: str = "global") -> dict:
    """Track radius and ulna over the sample's frames; returns the JSON-ready report. ``search``:
    ``"global"`` (CMA-ES, then quadratic-model searches) or ``"global_newton"`` (CMA-ES, then
    Gauss–Newton steps) in every frame."""
    from core.geometry.transforms import params_from_pose
    from core.render import DRRRenderer, HUTransfer
    from core.samples import WRIST_RADIUS_POSE, load_wrist_sample
    from core.tracking.bones import bone_model
    from core.tracking.cost import RegistrationCost, prepare_frame, search_roi
    from core.tracking.trial import track

    t0 = time.perf_counter()
    sample = load_wrist_sample(data_dir)
    models = [bone_model(sample.volumes[b], name=b, threshold=300.0, mesh=False) for b in BONES]
    renderer = DRRRenderer(sample.rig, [m.volume for m in models], transfer=HUTransfer(threshold=300.0),
                           device=device, step_mm=0.5)
    starts = {"radius": np.array(WRIST_RADIUS_POSE), "ulna": np.array(WRIST_ULNA_START)}
    n_views = len(sample.rig)

    def fluence(i: int):
        return [sample.frame(v, i).astype(np.float32) / 255.0 for v in range(n_views)]

    o = _options(final_scale, first_widen, search)
    res = track(renderer, models, fluence, list(ORDER), keyframes={b: {ORDER[0]: starts[b]} for b in BONES},
                options=o)

    def score_at(bone: int, frame: int, pose) -> tuple[float, list[float]]:
        fr = prepare_frame(fluence(frame), valid_range=o.valid_range, erode_px=o.erode_px)
        m = models[bone]
        roi = search_roi(renderer, pose, bone, views=tuple(range(n_views)), center=m.centroid, reach_mm=0.0,
                         margin_px=8, points=m.outline)
        c = RegistrationCost(renderer, fr, bone=bone, base_pose=pose, center=m.centroid, roi=roi,
                             scale=final_scale)
        s, v = c.score_and_views(np.zeros(6))
        return s, v.tolist()

    frames_out = []
    for f in ORDER:
        for b, m in enumerate(models):
            fr = res.results[(m.name, f)]
            entry = {"frame": sample.frame_paths[0][f].name.split(".")[-2], "bone": m.name,
                     "score": fr.score, "flags": list(fr.flags), "notes": list(fr.notes),
                     "evaluations": fr.evaluations, "time_s": fr.time_s,
                     "confidence_sigma": fr.confidence["sigma"] if fr.confidence else None}
            if fr.pose is not None:
                entry["pose"] = np.asarray(fr.pose).tolist()
                entry["view_scores"] = score_at(b, f, fr.pose)[1]
                if f == ORDER[0]:
                    d = params_from_pose(fr.pose, center=m.centroid, base=starts[m.name])
                    s0, v0 = score_at(b, f, starts[m.name])
                    entry["start"] = {"score": s0, "view_scores": v0,
                                      "moved_mm": float(np.linalg.norm(d[:3])),
                                      "turned_deg": float(np.degrees(np.linalg.norm(d[3:])))}
            frames_out.append(entry)
    out = {"check": "core.studies.tracking.wrist_check", "machine": platform.machine(),
           "device": str(renderer.device),
           "data": str(data_dir), "final_scale": final_scale, "first_widen": first_widen, "metric": "gc",
           "options": o.registration.to_dict(), "mode": o.mode, "results": frames_out,
           "summary": res.summary(), "total_s": time.perf_counter() - t0}
    if figure:
        _figure(sample, renderer, res, models, starts, figure)
    return out


def _outline(renderer, pose, view: int, bone: int, crop):
    """Contour (list of (n, 2) arrays, crop pixels) of the bone's DRR above a quarter of its peak."""
    import cv2

    drr = renderer.render(np.asarray(pose)[None, None], views=[view], bones=[bone], roi="full", scale=2.0)
    img = drr.item(0, 0, 0)
    m = (img > 0.25 * img.max()).astype(np.uint8)
    cnt, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    x0, y0 = crop
    return [c[:, 0, :] * 2.0 + 0.5 - np.array([x0, y0]) for c in cnt if len(c) > 20]


def _figure(sample, renderer, res, models, starts, path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    crop = (430, 1000, 1130, 1760)  # x0, y0, x1, y1: the distal forearm in both views
    fig, axes = plt.subplots(len(ORDER), 2, figsize=(9.0, 4.9 * len(ORDER)))
    colours = {"radius": "tab:red", "ulna": "tab:green"}
    for row, f in enumerate(ORDER):
        for v in range(len(sample.rig)):
            ax = axes[row, v]
            img = sample.frame(v, f)[crop[1]:crop[3], crop[0]:crop[2]]
            ax.imshow(img, cmap="gray", vmin=0, vmax=255)
            for b, m in enumerate(models):
                fr = res.results[(m.name, f)]
                if f == ORDER[0]:
                    for c in _outline(renderer, starts[m.name], v, b, crop[:2]):
                        ax.plot(c[:, 0], c[:, 1], color=colours[m.name], lw=0.8, ls=":")
                if fr.pose is not None:
                    for c in _outline(renderer, fr.pose, v, b, crop[:2]):
                        ax.plot(c[:, 0], c[:, 1], color=colours[m.name], lw=1.1)
            name = sample.frame_paths[v][f].name
            scores = ", ".join(f"{m.name} {res.results[(m.name, f)].score:.3f}" for m in models)
            ax.set_title(f"{name}\nGC {scores}", fontsize=8)
            ax.set_axis_off()
    fig.suptitle("Wrist sample: registered radius (red) and ulna (green); dotted: hand-placed start "
                 "(frame 0099)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.wrist_check",
                                description=__doc__.split("\n")[0])
    p.add_argument("--data", default=str(sample_data_dir() / "autoscoper_wrist"),
                   help="the autoscoper_wrist folder")
    p.add_argument("--device", default=None, help="Warp device (cpu, cuda:0); default CUDA when present")
    p.add_argument("--final-scale", type=float, default=2.0, help="full-resolution pixels per DRR pixel")
    p.add_argument("--first-widen", type=float, default=1.0,
                   help="first-frame search box and steps relative to the tracking ones (10 mm, 10 deg)")
    p.add_argument("--search", choices=("global", "global_newton"), default="global",
                   help="every frame's search: CMA-ES, then quadratic models (global) or Gauss-Newton steps")
    p.add_argument("--out", default=None, help="also write the JSON here")
    p.add_argument("--figure", default=None, help="save the overlays as a PNG")
    a = p.parse_args(argv)
    res = run(a.data, device=a.device, final_scale=a.final_scale, figure=a.figure, first_widen=a.first_widen,
              search=a.search)
    from core.io.atomic import print_json

    print_json(res, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
