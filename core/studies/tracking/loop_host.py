"""Host time of the frame loop's parts outside the registrations: ``python -m core.studies.tracking.loop_host
[--tracks 12] [--frames 100] [--rounds 8] [--acceptance] [--loop-frames 12] [--loop-rounds 3] [--note TEXT]
[--out FILE]``.

Two measurements, each of the loop's exact trims switched off (``before``) and on (``after``, the defaults),
the two alternated round by round (the host's drift shared), JSON on stdout:

* ``after_last``: the host work after a one-bone run's last frame that is not a registration: the
  backward check's trajectory scale (:func:`core.tracking.backward_check._scale`, the bone's median
  trajectory residual) and the trajectory post-pass (:func:`core.tracking.flags_post.apply_trajectory_flags`)
  on ``tracks`` synthetic tracks of ``frames`` frames (the walking motion of the trajectory check's tests,
  0.02 mm / 0.1° noise per axis, a few frames turned 0.3-0.8° off, the search's poses beside); the thread's
  CPU time per bone (median of the rounds), and whether the flags and notes were the same; with
  ``--acceptance`` the same on the stored acceptance runs' 18 bones (``after_last_acceptance``: seeds 0-2,
  both modes, the poses rebuilt from their kept errors, :func:`stored`);
* ``loop`` (``--loop-frames`` > 0): :func:`core.tracking.trial.track` on Warp's CPU device (the talus in
  ideal 64² views, the walk of the tracking tests' 60 frames, the likelihood stage, one bone as ``talus bench
  track`` runs it) with the frame clock of :mod:`core.studies.tracking.loop_clock`: first frame, the run
  after the last frame (the backward check and the post-pass apart), the frames' medians of ``loop_ms``
  (outside the registrations) and ``other_ms`` (the registrations' ``other_s``). On the CPU the kernels
  dominate the registrations: the post-pass's and the loop's parts are the host's.

The switches (:data:`TRIMS`): :data:`core.tracking.flags_fit.MEMO`, :data:`core.tracking.flags_fit.BATCHED`,
:data:`core.tracking.flags_post.SHARE_TABLE`.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

__all__ = ["TRIMS", "after_last", "loop", "main", "stored", "tracks"]

#: (module, switch) of the trims compared: all off (``before``) against all on (``after``).
TRIMS = (("core.tracking.flags_fit", "MEMO"), ("core.tracking.flags_fit", "BATCHED"),
         ("core.tracking.flags_post", "SHARE_TABLE"))


def _set(on: bool) -> None:
    import importlib

    for mod, attr in TRIMS:
        setattr(importlib.import_module(mod), attr, bool(on))


def tracks(n_tracks: int, frames: int, seed: int = 3) -> list:
    """``n_tracks`` one-bone :class:`~core.tracking.results.TrackingResult` of ``frames`` frames (module
    docs), with each frame's search pose."""
    from core.geometry.transforms import pose_from_params
    from core.studies.tracking.trajectory_gaps import CENTER, walking_track
    from core.tracking.results import FrameResult, TrackingResult

    g = np.random.default_rng(seed)
    out = []
    for k in range(n_tracks):
        turned = {int(f): float(g.choice([-1, 1]) * g.uniform(0.3, 0.8))
                  for f in g.choice(frames, size=4, replace=False)}

        def shift(i, p, turned=turned):
            if i in turned:
                p[3:] += np.radians(turned[i])

        P = walking_track(frames, noise=(0.02, 0.1), seed=1000 + k, shift=shift)
        res = {}
        for f in range(frames):
            S = pose_from_params(np.r_[g.normal(0, 0.02, 3), np.radians(g.normal(0, 0.1, 3))], center=CENTER,
                                 base=P[f])
            res[("talus", f)] = FrameResult("talus", f, P[f], 0.9, 52, 0.005, True, (), False, None, None, (),
                                            S)
        out.append(TrackingResult(("talus",), tuple(range(frames)), res, "complete", 1.0))
    return out


def stored(labels=("0", "1", "2")) -> list:
    """The stored acceptance runs' bones (:func:`core.studies.tracking.trajectory_gaps.runs`: seeds 0-2,
    1024², 100 frames, both modes, tracked on one NVIDIA H100; the frames their per-frame checks flagged
    kept flagged) as one-bone :class:`~core.tracking.results.TrackingResult` with their centres."""
    from core.studies.tracking.trajectory_gaps import runs
    from core.tracking.results import FrameResult, TrackingResult

    out = []
    for _, b, P, own, _, c in runs(labels=labels):
        res = {(b, f): FrameResult(b, f, P[f], 0.9, 52, 0.005, not own[f], ("score drop",) if own[f] else ())
               for f in range(len(P)) if np.all(np.isfinite(P[f]))}
        out.append((TrackingResult((b,), tuple(range(len(P))), res, "complete", 1.0), np.asarray(c, float)))
    return out


def _after_last_once(r, center=None) -> tuple[float, list]:
    from core.studies.tracking.trajectory_gaps import CENTER
    from core.tracking.backward_check import _scale
    from core.tracking.flags_post import apply_trajectory_flags

    b, c = r.bones[0], CENTER if center is None else center
    t = time.thread_time()
    _scale(r.results, list(r.frames), b, c)
    _, changed = apply_trajectory_flags(r, {b: c})
    dt = time.thread_time() - t
    return dt, [(x.frame, x.flags, x.notes) for x in changed]


def after_last(n_tracks: int = 12, frames: int = 100, rounds: int = 8, acceptance: bool = False) -> dict:
    """The ``after_last`` measurement (module docs); ``acceptance``: on :func:`stored`'s bones instead of
    synthetic tracks."""
    rs = stored() if acceptance else [(r, None) for r in tracks(n_tracks, frames)]
    got, ms = {}, {"before": [], "after": []}
    for name in ("before", "after"):  # (a first pass each: caches, and the flags compared)
        _set(name == "after")
        got[name] = [_after_last_once(*r)[1] for r in rs]
    for i in range(int(rounds)):
        for name in (("before", "after") if i % 2 == 0 else ("after", "before")):
            _set(name == "after")
            ms[name].append(1e3 * float(np.median([_after_last_once(*r)[0] for r in rs])))
    _set(True)
    flagged = sum(len(x) for x in got["after"])
    return {"tracks": len(rs), "frames": frames if not acceptance else 100, "rounds": rounds,
            "source": "stored acceptance runs (seeds 0-2, both modes)" if acceptance else "synthetic tracks",
            "flags_and_notes_same": got["before"] == got["after"], "frames_flagged_or_noted": flagged,
            "ms_per_bone": {k: {"median": float(np.median(v)), "rounds": v} for k, v in ms.items()}}


def loop(frames: int = 12, rounds: int = 3) -> dict:
    """The ``loop`` measurement (module docs)."""
    from dataclasses import replace

    from core.render import DRRRenderer
    from core.studies.tracking.frame_profile import _timed_track
    from core.synthetic import make_foot_scene
    from core.tracking.bones import bone_model
    from core.tracking.trial import TrackingOptions, track

    sc = make_foot_scene(n_frames=max(frames, 60), pixels=64, spacing=1.5, names=("talus",), beads_per_bone=0,
                         soft_tissue=False, imaging="ideal", floor_thickness_mm=0)
    model = bone_model(sc.bones[0], mesh=False)
    r = DRRRenderer(sc.rig, [sc.bones[0].to_attenuation(sc.bone_transfer)], device="cpu")
    imgs = {i: [m.to_float(f) for m, f in zip(sc.imaging, sc.render_frame(i), strict=True)]
            for i in range(frames)}
    kf = {model.name: {0: sc.poses(0)[0]}}
    o = replace(TrackingOptions(mode="joint"), refine_likelihood=True)
    track(r, [model], imgs.__getitem__, [0, 1], keyframes=kf, options=o)  # warm-up: kernels, buffers
    runs: dict = {"before": [], "after": []}
    for i in range(int(rounds)):
        for name in (("before", "after") if i % 2 == 0 else ("after", "before")):
            _set(name == "after")
            got = _timed_track(track, r, [model], imgs.__getitem__, list(range(frames)), kf, o)
            fr = got["frames"]
            runs[name].append({"first_frame_ms": got["first_frame_ms"], "after_last": fr.get("after_last"),
                               "loop_ms": fr.get("typical", {}).get("loop_ms"),
                               "other_ms": fr.get("typical", {}).get("other_ms"),
                               "median_frame_ms": fr.get("median_ms")})
    _set(True)

    def med(name, key, sub=None):
        v = [x[key] if sub is None else (x[key] or {}).get(sub) for x in runs[name]]
        v = [a for a in v if a is not None]
        return float(np.median(v)) if v else None

    summary = {k: {"first_frame_ms": med(k, "first_frame_ms"), "after_last_ms": med(k, "after_last", "ms"),
                   "backward_ms": med(k, "after_last", "backward_ms"),
                   "post_pass_ms": med(k, "after_last", "post_pass_ms"),
                   "post_pass_cpu_ms": med(k, "after_last", "post_pass_cpu_ms"),
                   "loop_ms_per_frame": med(k, "loop_ms"), "other_ms_per_frame": med(k, "other_ms")}
               for k in runs}
    return {"scene": "the talus, ideal 64^2 views, 1.5 mm voxels, Warp's CPU device", "frames": frames,
            "rounds": rounds, "median": summary, "runs": runs}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.loop_host",
                                description=__doc__.split("\n")[0])
    p.add_argument("--tracks", type=int, default=12)
    p.add_argument("--frames", type=int, default=100)
    p.add_argument("--rounds", type=int, default=8)
    p.add_argument("--loop-frames", type=int, default=12)
    p.add_argument("--loop-rounds", type=int, default=3)
    p.add_argument("--acceptance", action="store_true",
                   help="also time the after-last work on the stored acceptance runs' 18 bones")
    p.add_argument("--note", default=None, help="a note kept in the JSON (the machine, its load)")
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    import os
    import platform
    import sys

    cmd = " ".join(["python -m core.studies.tracking.loop_host", *(argv or sys.argv[1:])])
    out = {"study": "core.studies.tracking.loop_host", "command": cmd, "note": a.note,
           "machine": platform.machine(), "cpu_count": os.cpu_count(),
           "load_average_before": list(os.getloadavg()), "trims": [f"{m}.{s}" for m, s in TRIMS],
           "after_last": after_last(a.tracks, a.frames, a.rounds)}
    if a.acceptance:
        out["after_last_acceptance"] = after_last(rounds=a.rounds, acceptance=True)
    if a.loop_frames > 0:
        out["loop"] = loop(a.loop_frames, a.loop_rounds)
    out["load_average_after"] = list(os.getloadavg())
    from core.io.atomic import print_json

    print_json(out, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
