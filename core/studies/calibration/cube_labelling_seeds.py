"""The static cube's labelling over RANSAC seeds, per view, on the rendered calibration sessions.

``python -m core.studies.calibration.cube_labelling_seeds [--seeds 20] [--out FILE] [--cache DIR]``

Each session is corrected and its beads detected as :func:`~core.calibration.session.calibrate_session`
does (flatfield, distortion, the spiral frames labelled for the epipolar geometry), then the cube
frame's detections of each view are labelled by :func:`~core.calibration.labelling.label_ransac`
with ``rng`` = 0 .. seeds-1 (the session itself uses 0), and both views together by
:func:`~core.calibration.matching.resolve_frame` (what the session keeps). A view is *right* when
at least 6 detections are labelled and every label is its bead (the detection within ``tol_px`` of
the generator's projection of that bead); the truth is read only here.

Sessions (the ones the tests and the demo use):

* ``demo512``: the 512² demo calibration session (seed 0, 16 spiral frames), the cube frame with
  ~25 spurious bead-sized detections per view (walkway plate, noise).
* ``wizard384``: the calibration wizard's session (384², seed 0, 11 spiral frames; the wizard walk
  refits the first camera's distortion with poly(4,4), the session is labelled with both models).
* ``memory384``: the in-memory session of the calibration tests (384², seed 3, 10 spiral frames).
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ["SESSIONS", "cube_case", "main", "right_labels"]

#: name -> how the session is made (writer arguments, or the memory session's) and the
#: distortion model of the first camera (None: the session's automatic choice)
SESSIONS = {
    "demo512": {"disk": dict(pixels=512, seed=0, n_spiral=16, n_grid=2, n_lattice=1, n_dark=2, n_flat=4)},
    "wizard384": {"disk": dict(pixels=384, seed=0, n_spiral=11, n_grid=1, n_lattice=1, n_dark=2, n_flat=3)},
    "wizard384_poly44": {"disk": dict(pixels=384, seed=0, n_spiral=11, n_grid=1, n_lattice=1, n_dark=2,
                                      n_flat=3), "model0": "poly(4,4)"},
    "memory384": {"memory": dict(pixels=384, n_spiral=10, n_grid=1, n_flat=4, n_dark=2, seed=3)},
}


def cube_case(name: str, cache: Path) -> dict:
    """The cube frame's detections of both views (``dets``), the spiral's epipolar geometry ``F``,
    the static target and the true image positions of its beads (``truth_uv``, (2, 15, 2)); cached
    in ``cache`` (a pickle per session)."""
    cache = Path(cache)
    cache.mkdir(parents=True, exist_ok=True)
    f = cache / f"{name}.pkl"
    if f.exists():
        return pickle.loads(f.read_bytes())
    from core.calibration import session as cs
    from core.calibration._session_frames import _beads
    from core.calibration.matching import label_sequence

    spec = SESSIONS[name]
    if "disk" in spec:
        from core.io import read_session
        from core.synthetic.session import write_calibration_session

        folder = cache / f"session_{name}"
        if not (folder / "session.json").exists():
            write_calibration_session(folder, **spec["disk"])
        sess = read_session(folder)
        truth_uv = np.load(folder / "truth" / "truth.npz")["cube_ideal_uv"]
    else:
        from core.studies.calibration.memory_session import make_memory_session

        sess = make_memory_session(**spec["memory"])
        t = sess.truth
        from core.calibration.objects import cube_target

        X = cube_target().centers_lab(t["cube_pose"])
        truth_uv = np.stack([c.project(X) for c in t["rig"]])
    setup = cs.prepare(sess)
    ff = cs.flatfield_step(setup)
    dist = cs.distortion_step(setup, ff)
    if spec.get("model0"):
        dist = cs.refit_distortion(setup, dist, 0, spec["model0"])
    say = cs._say(None)
    _, sp = _beads(setup.reader, setup.cameras, dist.cameras, "spiral", setup.target, say)
    _, _, F = label_sequence(setup.target, sp)
    _, sdets = _beads(setup.reader, setup.cameras, dist.cameras, "cube", setup.static, say)
    out = {"target": setup.static, "dets": sdets[0], "F": F, "truth_uv": np.asarray(truth_uv)}
    f.write_bytes(pickle.dumps(out))
    return out


def right_labels(lab, truth_uv: np.ndarray, *, tol_px: float = 2.0) -> tuple[int, int]:
    """(labelled, right) detections of one view's labelling: a label is right when the detection
    lies within ``tol_px`` of its bead's true image position."""
    k = np.flatnonzero(lab.labels >= 0)
    d = np.linalg.norm(lab.uv[k] - truth_uv[lab.labels[k]], axis=1)
    return len(k), int(np.sum(d <= tol_px))


def _view_ok(lab, truth_uv) -> bool:
    n, r = right_labels(lab, truth_uv)
    return bool(lab.ok and n >= 6 and r == n)


def labelling_at(rev: str):
    """The ``label_ransac`` of ``core/calibration/labelling.py`` at git revision ``rev`` (the
    code before a change, measured beside the working tree's)."""
    import importlib.util
    import subprocess

    root = Path(__file__).resolve().parents[3]
    src = subprocess.run(["git", "show", f"{rev}:core/calibration/labelling.py"], cwd=root, check=True,
                         capture_output=True, text=True).stdout
    src = src.replace("\nfrom .", "\nfrom core.calibration.")
    src = src.replace("    from .dlt import", "    from core.calibration.dlt import")
    name = f"core.calibration._labelling_{rev}"
    spec = importlib.util.spec_from_loader(name, loader=None)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    exec(compile(src, f"{rev}:core/calibration/labelling.py", "exec"), mod.__dict__)
    return mod.label_ransac


def _wrong(rows, key) -> int:
    return sum(1 for r in rows if not (r[key][0] >= 6 and r[key][0] == r[key][1]))


def run(names, seeds: int, cache: Path, label_ransac=None, **ransac) -> dict:
    """Per session: each rng's labelling of each view (labelled, right), the detections it
    explains, and the frame both views make together; the summary counts the rngs with a view
    that is not right."""
    from core.calibration.matching import resolve_frame

    if label_ransac is None:
        from core.calibration.labelling import label_ransac
    out = {}
    for name in names:
        case = cube_case(name, cache)
        tg, dets, F, truth = case["target"], case["dets"], case["F"], case["truth_uv"]
        rows, t0 = [], time.perf_counter()
        for s in range(seeds):
            labs = tuple(label_ransac(tg, d, rng=s, **ransac) for d in dets)
            fr = resolve_frame(labs, F, target=tg, detections=dets)
            row = {"rng": s}
            for v in (0, 1):
                row[f"view{v + 1}"] = list(right_labels(labs[v], truth[v]))
                row[f"view{v + 1}_explained"] = int(labs[v].n_explained)
            row["frame"] = [list(right_labels(lab, truth[v])) for v, lab in enumerate(fr.labellings)] \
                if fr.ok else None
            row["frame_right"] = bool(fr.ok and all(_view_ok(lab, truth[v])
                                                     for v, lab in enumerate(fr.labellings)))
            rows.append(row)
        summary = {"detections": [len(d) for d in dets],
                   "sized_detections": [int(np.sum(d.size_class >= 0)) for d in dets],
                   "view1_wrong": _wrong(rows, "view1"), "view2_wrong": _wrong(rows, "view2"),
                   "frame_not_right": sum(1 for r in rows if not r["frame_right"]),
                   "label_ransac_seconds_per_view": (time.perf_counter() - t0) / max(seeds, 1) / 2}
        out[name] = {"summary": summary, "per_rng": rows}
        print(name, json.dumps(summary), flush=True)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=20)
    p.add_argument("--sessions", nargs="*", default=list(SESSIONS))
    p.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "cube_labelling_seeds")
    p.add_argument("--before", default=None, help="git revision whose label_ransac is measured as well")
    p.add_argument("--out", type=Path, default=None)
    a = p.parse_args(argv)
    load = os.getloadavg()
    doc = {"machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                       "python": sys.version.split()[0], "numpy": np.__version__,
                       "load_average_at_start": list(load)},
           "seeds": a.seeds, "tol_px": 2.0}
    if a.before:
        print(f"before ({a.before})", flush=True)
        doc["before"] = {"code": a.before,
                         "sessions": run(a.sessions, a.seeds, a.cache, labelling_at(a.before))}
    print("after (working tree)", flush=True)
    doc["after"] = {"code": "working tree", "sessions": run(a.sessions, a.seeds, a.cache)}
    doc["load_average_at_end"] = list(os.getloadavg())
    if a.out:
        a.out.write_text(json.dumps(doc, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
