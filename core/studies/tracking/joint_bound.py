"""The acceptance trial's Cramér–Rao bound with the other bones unknown
(``python -m core.studies.tracking.joint_bound``).

The acceptance study (:mod:`core.studies.tracking.acceptance`, :func:`~.acceptance.cramer_rao`)
measures each bone's per-frame error against :func:`core.tracking.bound.pose_bound`: the bound of
the bone's pose with the other bones *known*. No tracker knows them — in joint mode all the frame's
``6 n`` parameters are estimated from the same images, in sequential mode too, one bone after the
other — so the bound of the problem the trackers solve is :func:`core.tracking.bound.joint_bound`'s:
the bone's block of the inverse of the ``(6 n, 6 n)`` information. This study computes both on the
frames the acceptance study samples for its bound (every tenth), on the same scene (seed 0, the
trial's bones, tissue, walkway and photon counts), averaged over the frames as the acceptance study
averages (mean covariance). Per bone: both bounds (mm, degrees), their ratio, per frame and over the
frames, and the bound with only one other bone unknown (``pairs``: which neighbour costs what).

The bound uses the scene's true line integrals and the bones' true volumes, not the corrected
frames, so the distortion correction does not enter: the scene is made with ``"exact"`` (no grid
fit to make; the poses, volumes and photon counts are those of every correction).

``--stored FILE`` (default the acceptance run ``tracking_acceptance_near_rule_h100.json``, which
keeps every per-frame error) re-expresses the stored runs' errors against both bounds, per mode:
the RMS error over the known-others bound (recomputed here; the stored one beside it) and over the
joint bound, and the frames over 4× each bound (flagged or silent, the stored flags). Where this run's
views or voxels differ from the stored run's the joint bound is not that run's: the ratios are then
against the stored known-others bound times this run's joint / known-others ratio (``scaled``).
``--seed N`` bounds another synthesis of the trial (the acceptance study's ``--seed``; the harder
trial's with ``--trial hard``), with no stored run unless ``--stored`` names one of that seed (e.g.
``tracking_acceptance_seed3_h100.json``; a run of another seed is refused: its errors are not this
scene's). Only the seed is compared, not the synthesis: the held-out runs are of 56350ae's scenes,
which a5fd412's motion (touching bones kept apart) changed for seeds 3 and 4.

``--quick``: 256² views, 1 mm voxels (this CPU); the full size 1024², 0.5 mm (a GPU). Both take the
trial's 100 frames (the poses of the full trial) and bound frames 0, 10, …, 90. ``--trial hard``
bounds the harder trial (:class:`core.studies.tracking.hard_trial.HardRun`: real bone shapes with
trabecular texture, the fibula and navicular in the known background; ``--pixels``, ``--spacing``,
``--frames``, default its CPU size 192², 1 mm, 6 frames) from the volumes its frames were rendered
from; no stored run is re-expressed there.

Measured (``resources/benchmarks/tracking_joint_bound_h100.json``, one NVIDIA H100, 1024²; commit
438a37f): the joint bound is 1.0004–1.0009× the known-others bound (tibia 0.01496 mm / 0.0954°,
talus 0.03796 mm / 0.1644°, calcaneus 0.02672 mm / 0.0887°; per frame at most 1.0022× in mm and
1.0024× in degrees); the known-others bound is the acceptance run's to every digit. Of the
neighbours, the talus costs the tibia and the calcaneus most; the talus loses a little more to the
calcaneus than to the tibia. At 256² (``tracking_joint_bound_cpu.json``, this 2-core x86_64 machine)
1.001–1.002×. The harder trial (``--trial hard``): at 1024², 0.5 mm, frames 0, 2, …, 18 of 20,
1.0001–1.0003× (``tracking_joint_bound_hard_h100.json``, one NVIDIA H100); at 192², 1 mm, 6 frames
1.0001–1.0006× (``tracking_joint_bound_hard_cpu.json``, this 2-core machine). The stored runs'
errors are 1.29–1.85× either bound in both modes, the ratios moving in the third digit, and the same
frames are over 4×. The likely reason the cross-information is so small: a bone's pose derivative
image is mostly its own edges; where two projections overlap their edges cross rather than run
together, except along the joint line, a few pixels of the thousands that carry each bone's
information. Two copies of the talus 1.5 mm apart, every edge doubled, give 1.58 / 1.36× at 80² (the
bound's test): the bound can move, this trial's bones do not move it.
"""

from __future__ import annotations

import json
import platform
import time

import numpy as np

from core.studies.tracking import _study_cli as cli

__all__ = ["bounds", "frame_bounds", "hard_bounds", "main", "restate", "run", "run_hard"]

STORED = "resources/benchmarks/tracking_acceptance_near_rule_h100.json"


def _summary(C: np.ndarray) -> dict:
    return {"rms_mm": float(np.sqrt(np.trace(C[:3, :3]))), "rms_deg": float(np.sqrt(np.trace(C[3:, 3:]))),
            "sigma": np.sqrt(np.diag(C)).round(5).tolist()}


def frame_bounds(renderer, names, centers, truth, line_integrals, quanta, frames) -> dict:
    """Per bone (``names``: ``renderer``'s first volumes, rotation ``centers``), the known-others
    and the joint bound on ``frames`` (``truth(f)``: the bones' poses, ``line_integrals(f)``: the
    frame's total line integrals, ``quanta``: per view at full fluence): the mean covariance over
    the frames the bone is seen in (``known``, ``joint``, each ``rms_mm``, ``rms_deg``, ``sigma``;
    its ``rms`` is the RMS of the per-frame bounds), their ratio, the per-frame values, and
    ``pairs``: the bound with one other bone unknown (the rest known)."""
    from core.tracking.bound import joint_bound

    if any(n is None for n in quanta):
        raise ValueError("the scene's frames are noise-free: no bound")
    centers = np.asarray(centers, dtype=float)
    names = tuple(names)
    known = {n: [] for n in names}
    joint = {n: [] for n in names}
    pairs = {n: {o: [] for o in names if o != n} for n in names}
    per_frame = {n: [] for n in names}
    for f in frames:
        jb = joint_bound(renderer, range(len(names)), np.asarray(truth(f))[:len(names)], centers,
                         line_integral=line_integrals(f), quanta_per_pixel=quanta)
        for k, b in enumerate(jb.bones):
            n = names[b]
            kb, jm = jb.known[k], jb.joint[k]
            if not (np.all(np.isfinite(kb.covariance)) and np.all(np.isfinite(jm.covariance))):
                continue
            known[n].append(kb.covariance)
            joint[n].append(jm.covariance)
            per_frame[n].append({"frame": int(f), "known_mm": kb.rms_mm, "known_deg": kb.rms_deg,
                                 "joint_mm": jm.rms_mm, "joint_deg": jm.rms_deg, "pixels": kb.pixels})
            for i, c in enumerate(jb.bones):
                if c == b:
                    continue
                s = np.r_[6 * k:6 * k + 6, 6 * i:6 * i + 6]
                Jp = jb.information[np.ix_(s, s)]
                # regions that never meet: the known-others bound (the other's block may be singular)
                pairs[n][names[c]].append(np.linalg.inv(Jp)[:6, :6] if np.any(Jp[:6, 6:]) else kb.covariance)
    out = {}
    for n in names:
        if not known[n]:
            continue
        K, J = _summary(np.mean(known[n], axis=0)), _summary(np.mean(joint[n], axis=0))
        out[n] = {"known": K, "joint": J, "ratio": {"mm": J["rms_mm"] / K["rms_mm"],
                                                    "deg": J["rms_deg"] / K["rms_deg"]},
                  "frames": [p["frame"] for p in per_frame[n]], "per_frame": per_frame[n],
                  "pairs": {o: {k: v for k, v in _summary(np.mean(cs, axis=0)).items() if k != "sigma"}
                            for o, cs in pairs[n].items() if cs}}
    return out


def bounds(ts, frames) -> dict:
    """:func:`frame_bounds` on the acceptance scene ``ts``
    (:class:`core.studies.tracking.acceptance.TrackingScene`): its renderer and bone models (the
    volumes its frames were rendered from), the scene's line integrals and quanta."""
    return frame_bounds(ts.renderer, ts.names, [m.centroid for m in ts.models], ts.truth,
                        lambda f: ts.scene.line_integrals(f, renderer=ts._scene_renderer),
                        [m.photons_per_pixel for m in ts.scene.imaging], frames)


def hard_bounds(hr, frames) -> dict:
    """:func:`frame_bounds` on the harder trial ``hr`` (:class:`core.studies.tracking.hard_trial.
    HardRun`), from the volumes its frames were rendered from (the scene's bones under its transfer,
    as :func:`~core.studies.tracking.hard_trial.truth_bounds`; the fibula and navicular, not
    tracked, are part of the known line integral), the rotation centres the tracker's centroids."""
    from core.render import DRRRenderer

    sc = hr.scene
    r = DRRRenderer(sc.rig, [v.to_attenuation(sc.bone_transfer) for v in sc.bones[:len(hr.names)]],
                    device=hr.device)
    return frame_bounds(r, hr.names, [m.centroid for m in hr.models], hr.truth, hr.line_integrals,
                        [m.photons_per_pixel for m in sc.imaging], frames)


def restate(stored: dict, bound: dict, *, same_size: bool) -> dict:
    """The stored acceptance runs' (``stored["runs"]`` per mode, or one run) errors against both
    bounds (module docs): per mode and bone the RMS error, × the stored known-others bound, and with
    ``same_size`` × this run's known-others and joint bounds (else × the stored bound times this
    run's joint / known-others ratio, ``joint_scaled``), and the frames over 4× each (flagged and
    silent)."""
    runs = stored.get("runs") or {stored.get("config", {}).get("mode", "run"): stored}
    out = {}
    for mode, r in runs.items():
        out[mode] = {}
        for n, t in r["tracking"].items():
            if n not in bound or not t.get("per_frame_error"):
                continue
            E = np.asarray(t["per_frame_error"], dtype=float)
            frames = t["frames_with_pose"]
            flagged = set(t.get("flagged_frames", []))
            em, ed = np.linalg.norm(E[:, :3], axis=1), np.linalg.norm(E[:, 3:], axis=1)
            rms = {"mm": float(np.sqrt(np.mean(em ** 2))), "deg": float(np.sqrt(np.mean(ed ** 2)))}
            b = bound[n]
            sk = t.get("cramer_rao") or {}
            ref = {"stored_known": {u: sk.get(f"rms_{u}") for u in ("mm", "deg")}}
            if same_size:  # this run's bounds are the stored run's problem's
                ref["known"] = {u: b["known"][f"rms_{u}"] for u in ("mm", "deg")}
                ref["joint"] = {u: b["joint"][f"rms_{u}"] for u in ("mm", "deg")}
            else:  # the stored run's bound times this run's joint / known-others ratio
                ref["joint_scaled"] = {u: None if sk.get(f"rms_{u}") is None
                                       else sk[f"rms_{u}"] * b["ratio"][u] for u in ("mm", "deg")}
            row = {"rms_error": rms}
            for k, v in ref.items():
                if v["mm"] is None:
                    continue
                row[f"over_{k}"] = {u: rms[u] / v[u] for u in ("mm", "deg")}
                over = [f for f, a, d in zip(frames, em, ed, strict=True)
                        if a > 4 * v["mm"] or d > 4 * v["deg"]]
                row[f"over_4x_{k}"] = {"frames": over, "silent": [f for f in over if f not in flagged]}
            out[mode][n] = row
    return out


def run(*, quick: bool, device: str | None = None, every: int = 10, n_frames: int = 100,
        stored: str | None = STORED, pixels: int | None = None, seed: int = 0) -> dict:
    """Both bounds on the acceptance trial (``seed``: the acceptance study's ``--seed``, 0 the
    trial itself) and the stored runs re-expressed (module docs); a stored run of another scene seed
    is refused (its errors are not this scene's)."""
    from core.studies.tracking.acceptance import tracking_scene

    s = None
    if stored:  # read first: a run of another synthesis is refused before the bounds are computed
        with open(stored) as fh:
            s = json.load(fh)
        r0 = next(iter(s["runs"].values())) if "runs" in s else s
        rc = r0["config"]
        if int(rc.get("seed", 0)) != seed:
            raise ValueError(f"stored: {stored} is a run of scene seed {rc.get('seed', 0)}, this one bounds "
                             f"seed {seed} (--seed)")
    t0 = time.perf_counter()
    ts = tracking_scene(quick=quick, device=device, n_frames=n_frames, pixels=pixels, correction="exact",
                        seed=seed)
    setup = time.perf_counter() - t0
    frames = list(range(0, n_frames, every))
    t1 = time.perf_counter()
    b = bounds(ts, frames)
    cfg = {"pixels": ts.scene.rig[0].width, "voxel_mm": float(ts.models[0].volume.spacing[0]),
           "frames": n_frames, "bound_frames": frames, "seed": seed, "bones": list(ts.names)}
    out = {"study": "core.studies.tracking.joint_bound", "quick": quick, "machine": platform.machine(),
           "processor": platform.processor() or platform.machine(), "device": str(ts.renderer.device),
           "config": cfg, "bound": b, "scene_s": setup, "bound_s": time.perf_counter() - t1}
    if s is not None:
        same = (rc["pixels"] == cfg["pixels"] and abs(rc["voxel_mm"] - cfg["voxel_mm"]) < 1e-9
                and rc["frames"] == n_frames)
        out["stored"] = {"file": stored, "commit": s.get("commit"), "card": s.get("card"), "same_size": same,
                         "runs": restate(s, b, same_size=same)}
    out["total_s"] = time.perf_counter() - t0
    return out


def run_hard(*, pixels: int = 192, spacing: float = 1.0, n_frames: int = 6, every: int = 1,
             device: str | None = None, seed: int = 0) -> dict:
    """Both bounds on the harder trial (:class:`core.studies.tracking.hard_trial.HardRun`, its
    CPU size by default) every ``every``-th of ``n_frames`` frames."""
    from core.studies.tracking.hard_trial import HardRun

    t0 = time.perf_counter()
    hr = HardRun(n_frames=n_frames, pixels=pixels, spacing=spacing, seed=seed, device=device)
    setup = time.perf_counter() - t0
    frames = list(range(0, n_frames, every))
    t1 = time.perf_counter()
    b = hard_bounds(hr, frames)
    cfg = {"trial": "hard", "pixels": hr.scene.rig[0].width, "voxel_mm": spacing, "frames": n_frames,
           "bound_frames": frames, "seed": seed, "bones": list(hr.names)}
    return {"study": "core.studies.tracking.joint_bound", "machine": platform.machine(),
            "processor": platform.processor() or platform.machine(), "device": str(hr.renderer.device),
            "config": cfg, "bound": b, "scene_s": setup, "bound_s": time.perf_counter() - t1,
            "total_s": time.perf_counter() - t0}


def main(argv=None) -> int:
    p = cli.parser("core.studies.tracking.joint_bound", __doc__)
    p.add_argument("--quick", action="store_true", help="256² views, 1 mm voxels (default 1024², 0.5 mm)")
    p.add_argument("--device", default=None, help="Warp device (cpu, cuda:0); default CUDA when present")
    p.add_argument("--trial", choices=("acceptance", "hard"), default="acceptance",
                   help="the acceptance trial (default) or the harder one (core.studies.tracking.hard_trial)")
    p.add_argument("--pixels", type=int, default=None,
                   help="views' size (default acceptance 256 quick / 1024, hard 192)")
    p.add_argument("--spacing", type=float, default=1.0, help="hard trial: voxel size, mm (default 1)")
    p.add_argument("--frames", type=int, default=6, help="hard trial: frames (default 6)")
    p.add_argument("--every", type=int, default=None,
                   help="bound every this many frames (default acceptance 10, hard 1)")
    p.add_argument("--stored", default=None,
                   help=f"acceptance result to re-express ('' for none; default {STORED} with seed 0, "
                   "none with another)")
    p.add_argument("--seed", type=int, default=0,
                   help="scene seed (the acceptance study's --seed, HardRun's; 0, the default: the trial)")
    cli.add_output(p)
    a = p.parse_args(argv)
    if a.trial == "hard":
        res = run_hard(pixels=a.pixels or 192, spacing=a.spacing, n_frames=a.frames, every=a.every or 1,
                       device=a.device, seed=a.seed)
    else:
        stored = a.stored if a.stored is not None else (STORED if a.seed == 0 else None)
        res = run(quick=a.quick, device=a.device, every=a.every or 10, stored=stored or None,
                  pixels=a.pixels, seed=a.seed)
    return cli.finish(res, a)


if __name__ == "__main__":
    raise SystemExit(main())
