"""Crash/resume study of whole-trial tracking: SIGKILL at random moments, resume, compare.

A small synthetic case (the talus of the walking trial in ideal 96² views, CPU, frames 0–5,
frame 3 showing the images of frame 40 so that it fails its checks, is retried and is flagged
for review) is tracked once without interruption in a subprocess: the reference. Then, ``runs``
times, a fresh copy is tracked in a subprocess that is killed (SIGKILL) after a random delay,
resumed from its journal, killed again, … (at most ``max_kills`` times) until it finishes on
its own (a run that finished before its first kill is started again with a shorter window).
The worker resumes as :func:`core.tracking.from_study.track_study` does
(:func:`core.tracking.trial.journal_inputs` over the bone's pose journal, every result
journalled with its review state). Each finished copy's report (every frame's pose, score,
flags and their reasons, retry, evaluations, confidence, notes, and the summary; wall times
and timing breakdowns left out) and its journal (every pose, score and review state) are
compared with the reference's for exact equality.

    python -m core.studies.crash_resume --runs 20 [--frames 6] [--pixels 96] [--seed 0] [--out FILE]

prints JSON: the case, per run the kills and their delays, the runs identical to the
reference, and the first differences found, if any.

Measured on a shared 2-core CPU (``--runs 20 --max-kills 3 --seed 1``): 20/20 runs identical to
the uninterrupted run after 38 SIGKILLs — killed with 0, 3, 4, 5 and all 6 frames journalled
(during start-up, inside the flagged frame's retry, after it, and before the report was
written); with ``--seed 0``, 20/20 after 33 SIGKILLs.
"""

from __future__ import annotations

import argparse
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

__all__ = ["compare", "crash_and_resume", "make_case", "run_worker", "snapshot"]

BONE = "talus"
_VOLATILE = {"time_s", "timing", "time_per_frame_s"}


def _options():
    from core.tracking.register import Level, RegistrationOptions
    from core.tracking.trial import TrackingOptions

    reg = RegistrationOptions(bounds=(4.0, 4.0), refine="pattern", levels=(
        Level(1.0, "cmaes", (0.7, 0.7), popsize=10, max_generations=40, tol_x=0.02),))
    return TrackingOptions(registration=reg, verify_restarts=2, confidence=True)


def _scene(pixels: int):
    """The talus of the synthetic walking trial in ideal 2-view images, its model and a CPU
    renderer; frame 3 shows the images of frame 40 (the bone is elsewhere: a frame that fails
    its checks, is retried and is flagged for review)."""
    import numpy as np

    from core.geometry.transforms import pose_from_params
    from core.render import DRRRenderer
    from core.synthetic import make_foot_scene
    from core.tracking.bones import bone_model

    sc = make_foot_scene(n_frames=60, pixels=pixels, spacing=1.5, names=(BONE,), beads_per_bone=0,
                         soft_tissue=False, imaging="ideal", floor_thickness_mm=0)
    model = bone_model(sc.bones[0], mesh=False)
    renderer = DRRRenderer(sc.rig, [sc.bones[0].to_attenuation(sc.bone_transfer)], device="cpu")

    def frames(i):
        k = 40 if i == 3 else i
        return [m.to_float(f) for m, f in zip(sc.imaging, sc.render_frame(k), strict=True)]

    start = pose_from_params(np.r_[1.5, -1.0, 1.0, 0.02, -0.02, 0.01], center=model.centroid,
                             base=sc.poses(0)[0])
    return renderer, model, frames, start


def make_case(folder, *, pixels: int = 96) -> Path:
    """A fresh case folder: the bone's journal holding only its hand-placed start at frame 0."""
    from core.study.results import append_pose

    folder = Path(folder)
    (folder / "poses").mkdir(parents=True, exist_ok=True)
    _, _, _, start = _scene(pixels)
    append_pose(folder / "poses" / f"{BONE}.jsonl", 0, start)
    (folder / "case.json").write_text(f'{{"pixels": {pixels}}}\n')
    return folder


def run_worker(folder, n_frames: int) -> int:
    """Track frames ``0..n_frames-1`` of the case in ``folder``, resuming from its journal as
    :func:`core.tracking.from_study.track_study` does (``journal_inputs``, every result journalled
    with its review state), and write ``report.json`` (:meth:`TrackingResult.report`) at the end."""
    import json

    from core.io.atomic import atomic_write_json
    from core.study.results import append_pose, read_journal, repair_tail
    from core.tracking.trial import journal_inputs, track

    folder = Path(folder)
    pixels = json.loads((folder / "case.json").read_text())["pixels"]
    renderer, model, frames, _ = _scene(pixels)
    path = folder / "poses" / f"{BONE}.jsonl"
    repair_tail(path)
    order = list(range(n_frames))
    keyframes, skip = journal_inputs({BONE: read_journal(path)}, order, resume=True)
    res = track(renderer, [model], frames, order, keyframes=keyframes, skip=skip, options=_options(),
                record_result=lambda fr: append_pose(path, fr.frame, fr.pose, score=fr.score,
                                                     tracking=fr.journal_fields()))
    atomic_write_json(folder / "report.json", res.report())
    return 0 if res.status == "complete" else 3


def _strip(obj):
    if isinstance(obj, dict):
        return {k: _strip(v) for k, v in obj.items() if k not in _VOLATILE}
    if isinstance(obj, list):
        return [_strip(v) for v in obj]
    return obj


def snapshot(folder) -> dict:
    """The comparable content of a finished case: its report (times left out) and its journal's
    pose, score and review state per frame."""
    import json

    from core.study.results import read_journal

    folder = Path(folder)
    rep = _strip(json.loads((folder / "report.json").read_text()))
    s = read_journal(folder / "poses" / f"{BONE}.jsonl")
    journal = {str(f): {"pose": None if r.pose is None else r.pose.ravel().tolist(),
                        "score": None if r.score != r.score else r.score,
                        "kind": r.kind, "tracking": _strip(r.tracking)}
               for f, r in s.records.items()}
    return {"report": rep, "journal": journal}


def compare(a, b, path: str = "") -> list[str]:
    """Differences between two snapshots (exact), as ``path: a != b`` strings."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b), key=str):
            if k not in a or k not in b:
                out.append(f"{path}.{k}: only in {'reference' if k in a else 'resumed'}")
            else:
                out += compare(a[k], b[k], f"{path}.{k}")
        return out
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{path}: {len(a)} items != {len(b)}"]
        return [d for i, (x, y) in enumerate(zip(a, b, strict=True)) for d in compare(x, y, f"{path}[{i}]")]
    return [] if a == b else [f"{path}: {a!r} != {b!r}"]


def _spawn(folder, n_frames: int) -> subprocess.Popen:
    env = dict(os.environ)
    env.setdefault("PYTHONHASHSEED", "0")
    root = Path(__file__).resolve().parents[2]
    cmd = [sys.executable, "-m", "core.studies.crash_resume", "--worker", str(folder),
           "--frames", str(n_frames)]
    return subprocess.Popen(cmd, cwd=root, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


def crash_and_resume(folder, n_frames: int, *, rng: random.Random, kill_within_s: float,
                     max_kills: int = 6, timeout_s: float = 900.0) -> dict:
    """Run the worker on ``folder``, SIGKILL it after a random delay in ``[0,
    kill_within_s)``, restart it (resume), … up to ``max_kills`` kills, then let it finish.
    Returns the kills, their delays, the journal's state after each (frames done, torn bytes)
    and the wall time."""
    from core.study.results import read_journal

    kills, delays, at = 0, [], []
    t0 = time.monotonic()
    while True:
        proc = _spawn(folder, n_frames)
        delay = rng.uniform(0.0, kill_within_s) if kills < max_kills else None
        try:
            proc.wait(timeout=delay if delay is not None else timeout_s)
        except subprocess.TimeoutExpired:
            if delay is None:
                proc.kill()
                raise RuntimeError(f"{folder}: a worker ran past {timeout_s} s") from None
            proc.send_signal(signal.SIGKILL)
            proc.wait()
            proc.stderr.close()
            kills += 1
            delays.append(round(delay, 2))
            st = read_journal(Path(folder) / "poses" / f"{BONE}.jsonl")
            at.append({"frames_done": len(st.done), "torn_bytes": st.torn_bytes})
            continue
        err = proc.stderr.read().decode(errors="replace")
        proc.stderr.close()
        if proc.returncode != 0:
            raise RuntimeError(f"{folder}: worker exited {proc.returncode}: {err[-2000:]}")
        return {"kills": kills, "kill_delays_s": delays, "journal_at_kills": at,
                "wall_s": round(time.monotonic() - t0, 1)}


def study(*, runs: int = 20, n_frames: int = 6, pixels: int = 96, seed: int = 0, max_kills: int = 6,
          workdir=None) -> dict:
    """The whole study (see the module docs); returns the JSON-ready result."""
    rng = random.Random(seed)
    tmp = Path(workdir) if workdir else Path(tempfile.mkdtemp(prefix="crash_resume_"))
    pristine = make_case(tmp / "pristine", pixels=pixels)
    ref = tmp / "reference"
    shutil.copytree(pristine, ref)
    t0 = time.monotonic()
    crash_and_resume(ref, n_frames, rng=rng, kill_within_s=0.0, max_kills=0)
    ref_s = time.monotonic() - t0
    reference = snapshot(ref)
    flagged = [f for f in reference["report"]["frames"] if f["flags"]]
    out = {"machine": {"cpus": os.cpu_count(), "python": sys.version.split()[0]},
           "case": {"frames": n_frames, "pixels": pixels, "bone": BONE, "device": "cpu",
                    "flagged_in_reference": [(f["bone"], f["frame"], f["flags"]) for f in flagged],
                    "reference_wall_s": round(ref_s, 1)},
           "runs": [], "identical": 0, "differences": []}
    for r in range(runs):
        folder = tmp / f"run{r:02d}"
        window = ref_s
        for _ in range(6):  # a run that finished before its first kill tests nothing: again, sooner
            shutil.rmtree(folder, ignore_errors=True)
            shutil.copytree(pristine, folder)
            info = crash_and_resume(folder, n_frames, rng=rng, kill_within_s=window, max_kills=max_kills)
            if info["kills"]:
                break
            window *= 0.7
        diff = compare(reference, snapshot(folder))
        info["identical"] = not diff
        out["runs"].append(info)
        out["identical"] += not diff
        if diff:
            out["differences"].append({"run": r, "first": diff[:10], "count": len(diff)})
        shutil.rmtree(folder, ignore_errors=True)
    out["kills_total"] = sum(r["kills"] for r in out["runs"])
    out["summary"] = (f"{out['identical']}/{runs} runs identical to the uninterrupted run after "
                      f"{out['kills_total']} SIGKILLs")
    if not workdir:
        shutil.rmtree(tmp, ignore_errors=True)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m core.studies.crash_resume",
                                description=__doc__.split("\n")[0])
    p.add_argument("--runs", type=int, default=20)
    p.add_argument("--frames", type=int, default=6)
    p.add_argument("--pixels", type=int, default=96)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--max-kills", type=int, default=6)
    p.add_argument("--out", default=None, help="also write the JSON here")
    p.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.worker:
        return run_worker(a.worker, a.frames)
    if a.runs < 1:
        p.error("--runs: expected at least 1")
    from core.io.atomic import print_json

    res = study(runs=a.runs, n_frames=a.frames, pixels=a.pixels, seed=a.seed, max_kills=a.max_kills)
    print_json(res, a.out)
    return 0 if res["identical"] == a.runs else 1


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
