"""The trajectory check's frames whose neighbours are all flagged, on stored runs
(``python -m core.studies.tracking.trajectory_gaps``).

:mod:`core.tracking.flags_post` judges a frame against the fit through its good neighbours within
±4 frames; a frame whose neighbours are flagged has no such fit. Since ``flags_post.REACH`` such a
frame is judged against the line through its nearest frames judged good further away, scaled by the
bone's nearest frames fitted alike (module docs of :mod:`core.tracking.flags_post`, *A frame whose
neighbours are flagged*); one it cannot judge gets the ``trajectory unchecked`` note. This study runs
the check with and without that (``reach=None``) on the stored per-frame results of the tracker and
counts, per run and bone, the frames left without a fit, which of them are over 4× the bone's
Cramér–Rao bound, and which the new judgement flags or notes.

Runs (all 1024², 100 frames, tracked on one NVIDIA H100, the check run here on the CPU):

* seeds 0-2, joint and sequential: the poses kept in
  ``resources/benchmarks/tracking_silent_checks_per_frame_h100.json`` (ea76c8b);
* seed 3 and seed 4 (the synthesis with interpenetrating bones), 56350ae, and seed 4 with the bones
  kept apart, a5fd412: these keep each frame's error against the truth, not its pose
  (``tracking_acceptance_seed3_h100.json``, ``..._seed4_interpenetrating_h100.json``,
  ``..._seed4_h100.json``). Their poses are rebuilt as those errors applied to the seed's true poses,
  made again by :func:`core.synthetic.motion.stance_trajectories` with the study's motion seed
  (``min_space_mm=None`` for the two runs before the bones were kept apart): the truth is exact
  (seed 0's as the study's scene gives it, to 1e-5 mm), the errors rounded to 1e-5 mm / degree.
  Rebuilt so, seeds 0-2 give their kept poses within 2e-5 mm (:func:`rebuild_check`). The rotation
  centre (the bone model's centroid, which the errors are about) is seed 0's: each seed's phantoms
  differ a little (seeds 1 and 2's centroids are within 0.15 mm of seed 0's), which moves a pose by
  that times its rotation error, at most 0.003 mm here, smoothly over frames.

The per-frame checks' flags of each run are kept (those frames are neither judged nor neighbours); a
frame is *over* when its translation or rotation error exceeds 4× the bone's RMS bound, as the
acceptance study counts.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

__all__ = ["BONES", "CENTER", "INSIDE", "SEEDS", "counts", "main", "rebuild_check", "runs", "synthetic",
           "truth", "walking_track"]

BONES = ("tibia", "talus", "calcaneus")

BENCH = Path(__file__).resolve().parents[3] / "resources" / "benchmarks"
KEPT = "tracking_silent_checks_per_frame_h100.json"
#: Run label -> the acceptance study's JSON that keeps its per-frame errors.
SEEDS = {"3": "tracking_acceptance_seed3_h100.json",
         "4i": "tracking_acceptance_seed4_interpenetrating_h100.json",
         "4": "tracking_acceptance_seed4_h100.json"}


def truth(seed: int, *, apart: bool = True, n_frames: int = 100) -> np.ndarray:
    """``(3, n, 4, 4)`` true poses of the acceptance trial's tibia, talus and calcaneus for scene seed
    ``seed`` (as :func:`core.studies.tracking.acceptance.tracking_scene` makes them: the motion
    sub-seed of :func:`core.synthetic.make_foot_scene`, the first 0.6 of stance); ``apart`` False: the
    bones moving independently, as before the synthesis kept them apart (a5fd412)."""
    from core.synthetic.motion import MIN_SPACE_MM, stance_trajectories

    g = np.random.default_rng(np.random.SeedSequence(int(seed)).spawn(4)[1])
    return stance_trajectories(n_frames, names=BONES, seed=g, phase=(0.0, 0.6 * n_frames / 100.0),
                               min_space_mm=MIN_SPACE_MM if apart else None)


def _rebuilt(E: np.ndarray, T: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Poses with errors ``E`` (mm, degrees: the acceptance study's pose_errors) about true poses ``T``
    (NaN where no error)."""
    from core.geometry.transforms import pose_from_params

    P = np.full((len(E), 4, 4), np.nan)
    for i, e in enumerate(E):
        if np.all(np.isfinite(e)):
            P[i] = pose_from_params(np.r_[e[:3], np.radians(e[3:])], center=c, base=T[i])
    return P


def rebuild_check(bench: Path = BENCH, seeds=(0, 1, 2), apart: bool = True) -> float:
    """The largest distance (mm) over the kept runs of ``seeds`` (of 0-2) between a kept pose and the
    pose rebuilt from its error and the seed's truth (:func:`truth`'s ``apart``), at the bone's
    centroid and 50 mm from it along each axis."""
    from core.studies.tracking.silent_checks import load

    worst = 0.0
    for run in [f"{s}_{m}" for s in seeds for m in ("joint", "sequential")]:
        T = truth(int(run[0]), apart=apart)
        for k, (_, g) in enumerate(load(f"{bench / KEPT}#{run}").items()):
            P = _rebuilt(g["err"], T[k], g["center"])
            pts = g["center"] + 50.0 * np.vstack([np.zeros(3), np.eye(3), -np.eye(3)])
            for a, b in zip(P, g["pose"], strict=True):
                d = (a[:3, :3] - b[:3, :3]) @ pts.T + (a[:3, 3] - b[:3, 3])[:, None]
                worst = max(worst, float(np.abs(d).max()))
    return worst


def runs(bench: Path = BENCH, labels=None):
    """``(run, bone, poses, own, over, centre)`` of every stored run and bone (``labels``: only the
    seeds' labels given, "0"-"2", "3", "4i", "4"): ``own`` the frames its per-frame checks flagged,
    ``over`` those over 4× the bone's bound (module docs)."""
    from core.studies.tracking.silent_checks import load

    want = set(labels) if labels is not None else {"0", "1", "2", *SEEDS}
    center = {b: g["center"] for b, g in load(f"{bench / KEPT}#0_joint").items()}  # module docs
    for run in [f"{s}_{m}" for s in range(3) for m in ("joint", "sequential") if str(s) in want]:
        for b, g in load(f"{bench / KEPT}#{run}").items():
            yield run, b, g["pose"], g["own"], g["over"], g["center"]
    for label, name in SEEDS.items():
        if label not in want:
            continue
        d = json.loads((bench / name).read_text())
        T = truth(int(label[0]), apart=label == "4")
        for mode, r in d["runs"].items():
            for b, t in r["tracking"].items():
                n = T.shape[1]
                E = np.full((n, 6), np.nan)
                E[t["frames_with_pose"]] = t["per_frame_error"]
                trajectory = set(t["flagged_off_trajectory_only"])
                own = np.zeros(n, dtype=bool)
                own[[f for f in t["flagged_frames"] if f not in trajectory]] = True
                over = np.zeros(n, dtype=bool)
                over[t["over_4x_bound"]["frames"]] = True
                yield f"{label}_{mode}", b, _rebuilt(E, T[BONES.index(b)], center[b]), own, over, center[b]


def counts(bench: Path = BENCH, labels=None, **kw) -> dict:
    """Per run and bone, and per seed: the frames left without a fit (``unfitted``; the check with
    ``reach=0``), the frames over 4× among them, what the check (``kw``: its keywords) flags and
    notes beyond the check without the judgement (``reach=None``), and the silent frames over 4× and
    good frames flagged before and after (``labels``: :func:`runs`'s). The rules made after this one
    (``along``, ``one_sided``, ``ends``; :mod:`core.studies.tracking.trajectory_silent` measures them) are
    off unless ``kw`` gives them."""
    from core.tracking.flags_post import trajectory_review

    kw = {"along": None, "one_sided": False, "ends": False, **kw}
    per_run, per_seed = {}, {}
    for run, b, P, own, over, c in runs(bench, labels):
        Q = P.copy()
        Q[own] = np.nan  # the per-frame checks' flags: neither judged nor neighbours
        fr = np.arange(len(Q))
        ok = np.all(np.isfinite(Q.reshape(len(Q), -1)), axis=1)
        before, _ = trajectory_review(fr, Q, c, **{**kw, "reach": None})
        _, unfitted = trajectory_review(fr, Q, c, **{**kw, "reach": 0})
        after, unchecked = trajectory_review(fr, Q, c, **kw)
        new = sorted(set(after) - set(before))
        row = {"unfitted": sorted(unfitted), "unfitted_over": [f for f in sorted(unfitted) if over[f]],
               "flagged": new, "flagged_over": [f for f in new if over[f]], "unchecked": sorted(unchecked),
               "messages": {str(f): after[f] for f in new}}
        for k, fl in (("before", before), ("after", after)):
            row[f"silent_{k}"] = int(np.sum(over & ok & ~np.isin(fr, list(fl))))
            row[f"good_flagged_{k}"] = int(np.sum(~over & ok & np.isin(fr, list(fl))))
        per_run.setdefault(run, {})[b] = row
        s = per_seed.setdefault(run.split("_")[0], {})
        for k, v in row.items():
            if k != "messages":
                s[k] = s.get(k, 0) + (len(v) if isinstance(v, list) else v)
        s["good"] = s.get("good", 0) + int(np.sum(~over & ok))
        s["over"] = s.get("over", 0) + int(np.sum(over & ok))
    return {"per_seed": per_seed, "runs": per_run}


def walking_track(n: int = 40, noise=(0.01, 0.05), seed: int = 1, shift=None, center=None) -> np.ndarray:
    """``(n, 4, 4)`` poses of a bone in smooth, walking-like motion (the trajectory check's tests' track):
    translation (mm) and rotation (degrees) smooth in time plus Gaussian noise ``noise`` (mm, degrees);
    ``shift(k, p)`` may change frame ``k``'s parameters ``p`` (mm, radians) in place before the pose is
    made; about ``center`` (default :data:`CENTER`)."""
    from core.geometry.transforms import pose_from_params

    g = np.random.default_rng(seed)
    t = np.arange(n) / n
    P = []
    for k in range(n):
        p = np.r_[20 * t[k] + 5 * t[k] ** 2, 3 * np.sin(2 * t[k]), -4 * t[k],
                  np.radians([10 * t[k], -6 * t[k] ** 2, 4 * np.sin(3 * t[k])])]
        p[:3] += g.normal(0, noise[0], 3)
        p[3:] += np.radians(g.normal(0, noise[1], 3))
        if shift is not None:
            shift(k, p)
        P.append(pose_from_params(p, center=CENTER if center is None else center, base=np.eye(4)))
    return np.array(P)


def _walking(n: int, seed: int, shift: dict) -> np.ndarray:
    """:func:`walking_track` with noise 0.01 mm / 0.05° per axis, frame ``k`` turned by ``shift[k]``
    degrees more about z."""

    def turn(k, p):
        p[5] += np.radians(shift.get(k, 0.0))

    return walking_track(n, (0.01, 0.05), seed, turn)


#: The tests' rotation centre (mm).
CENTER = np.array([5.0, -3.0, 40.0])
#: Frames 16-19 and 21-24 off by ±0.6° about z in turn (12× the noise), frame 20 among them.
INSIDE = {16: 0.6, 17: -0.6, 18: 0.6, 19: -0.6, 21: 0.6, 22: -0.6, 23: 0.6, 24: -0.6}


def synthetic(tracks: int = 200, offs=(0.0, 0.15, 0.3, 0.5)) -> dict:
    """Over ``tracks`` noise draws of a 100-frame walking track with :data:`INSIDE`'s spikes: for frame
    20 turned ``off`` degrees more, how often it is left without a fit by the other flags, and of
    those how often the check flags or notes it. ``"main"``: for comparison, the good frames the
    check's own fits flag on the same draws without spikes (every frame good), its false-flag rate
    where a frame has a fit. The rules made after this one off, as :func:`counts`."""
    from core.tracking.flags_post import trajectory_review

    out = {}
    fr = np.arange(100)
    kw = {"along": None, "one_sided": False, "ends": False}  # as counts
    for off in offs:
        unfitted = flagged = noted = 0
        for s in range(tracks):
            P = _walking(100, s, {**INSIDE, 20: off})
            if 20 not in trajectory_review(fr, P, CENTER, reach=0, **kw)[1]:
                continue
            got, notes = trajectory_review(fr, P, CENTER, **kw)
            unfitted, flagged, noted = unfitted + 1, flagged + (20 in got), noted + (20 in notes)
        out[f"{off:g}"] = {"tracks": tracks, "unfitted": unfitted, "flagged": flagged, "noted": noted}
    flagged = sum(len(trajectory_review(fr, _walking(100, s, {}), CENTER, **kw)[0]) for s in range(tracks))
    out["main"] = {"tracks": tracks, "good_frames": tracks * len(fr), "flagged": int(flagged)}
    return out


def main(argv=None) -> int:
    from ._study_cli import stored_parser, write_stamped

    p = stored_parser("trajectory_gaps", __doc__, "the counts")
    p.add_argument("--tracks", type=int, default=200, help="noise draws of the synthetic track (0: none)")
    a = p.parse_args(argv)
    got = counts()
    got["rebuild_max_mm"] = rebuild_check()
    if a.tracks:
        got["synthetic"] = synthetic(a.tracks)
        main_ = got["synthetic"]["main"]
        print(f"without spikes, good frames flagged by their own fits: {main_['flagged']} of "
              f"{main_['good_frames']}")
        for off, r in [kv for kv in got["synthetic"].items() if kv[0] != "main"]:
            print(f"frame 20 {off} deg off among flagged ones: without a fit in {r['unfitted']} of "
                  f"{r['tracks']}, flagged {r['flagged']}, noted {r['noted']}")
    for seed, s in got["per_seed"].items():
        print(f"seed {seed}: unfitted {s['unfitted']} ({s['unfitted_over']} over 4x), flagged now "
              f"{s['flagged']} ({s['flagged_over']} over 4x), unchecked {s['unchecked']}; silent "
              f"{s['silent_before']} -> {s['silent_after']} of {s['over']}, good flagged "
              f"{s['good_flagged_before']} -> {s['good_flagged_after']} of {s['good']}")
    if a.out:
        write_stamped(a.out, "core.studies.tracking.trajectory_gaps", argv, a.machine_name, got)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
