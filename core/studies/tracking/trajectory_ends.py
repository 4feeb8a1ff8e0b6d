"""The trajectory check at a trial's first and last frames, on the stored runs and the tests' walking track
(``python -m core.studies.tracking.trajectory_ends``).

:mod:`core.tracking.flags_ends` (the ``ends`` and ``crowd`` keywords of
:func:`core.tracking.flags_post.trajectory_review`) fits a frame within ``HALF_WINDOW`` of a trial's end
through the window shifted inside the trial, and sends a good end frame to review only when two frames or
more near it are flagged. This study measures the check with it (the defaults) against the check before
(``ends=False``: the check of d262386 and the commits since, which gives d262386's stored flags exactly,
``reproduced``):

* :func:`counts`: on the stored acceptance runs (:mod:`core.studies.tracking.trajectory_silent`'s sets and
  ``d262386``: seeds 0, 3 and 4 with the final stage, ``tracking_acceptance_seed{0,3,4}_final_d262386_
  h100.json``; 1024², 100 frames, jointly and sequentially, tracked on one NVIDIA H100, their poses rebuilt
  from the kept errors and the seed's truth), per set: frames over 4x their bound left silent, good frames
  (under 2x) flagged, and the same for the frames within ``HALF_WINDOW`` of a trial's end (``ends``);
* :func:`scale_split`: the change split in two — the shifted windows with the bone's median as before, and
  with the median leaving the end frames out (the default);
* :func:`crowd_sweep`: those totals for ``crowd`` 2, 3, 4 and off;
* :func:`walking`: the review's repro of the bad end frame: the tests' walking track (60 frames,
  0.01 mm / 0.05° noise per axis, 6 draws), one frame turned 0.3-5° more about z — the first and last
  frames and frames 1-3 and 56-58 — caught, and good frames flagged over the draws.

The numbers are in ``resources/benchmarks/tracking_trajectory_ends_cpu.json`` and
:mod:`core.tracking.flags_ends`' docs.
"""

from __future__ import annotations

import numpy as np

from core.studies.tracking.trajectory_silent import SETS, _ok, _review, _tally

__all__ = ["BEFORE", "FRAMES", "SIZES", "TABLE", "counts", "crowd_sweep", "main", "scale_split", "walking"]

#: The stored runs: :mod:`core.studies.tracking.trajectory_silent`'s and d262386's (the check at it gives
#: their stored flags).
TABLE = {"d262386": [(s, s, True, f"tracking_acceptance_seed{s}_final_d262386_h100.json") for s in "034"],
         **SETS}
#: The check before :mod:`core.tracking.flags_ends`.
BEFORE = {"ends": False}
#: The walking track's frames turned, and by how much (degrees about z).
FRAMES = (0, 1, 2, 3, 56, 57, 58, 59)
SIZES = (0.3, 0.5, 1.0, 2.0, 5.0)


def _ends(r, half_window: int = 4) -> np.ndarray:
    """The frames within ``half_window`` of the run's first or last frame with a pose."""
    ok = _ok(r)
    idx = np.flatnonzero(ok)
    fr = np.arange(len(ok))
    if not len(idx):
        return np.zeros(len(ok), dtype=bool)
    return ok & ((fr - idx[0] < half_window) | (idx[-1] - fr < half_window))


def _totals(rs, flags) -> dict:
    """Per set: :func:`~core.studies.tracking.trajectory_silent._tally`'s counts, all frames and the end
    frames (``ends_*``), and the silent frames named."""
    out: dict = {}
    for part, mask in (("", None), ("ends_", True)):
        sub = []
        for r in rs:
            q = dict(r)
            if mask:
                keep = _ends(r)
                q["over"], q["good"] = r["over"] & keep, r["good"] & keep
            sub.append(q)
        for k, v in _tally(sub, flags).items():
            if "/" in k:
                continue
            s = out.setdefault(k, {})
            s.update({part + n: v[n] for n in ("over", "silent", "good", "good_flagged")})
    for r, fl in zip(rs, flags, strict=True):
        ok = _ok(r)
        s = out[r["set"]]
        s.setdefault("silent_frames", []).extend(
            f"{r['run']}/{r['bone']}/{f}" for f in np.flatnonzero(r["over"] & ok) if f not in fl)
    return out


def counts(rs, **kw) -> dict:
    """The check before (:data:`BEFORE`) and with the defaults (and ``kw``) on the runs ``rs``: per set
    (:func:`_totals`), each run's frames flagged or unflagged by the change (their error over the bound,
    the message), and whether the check before gives each d262386 run's stored flags."""
    before = [_review(r, **BEFORE) for r in rs]
    after = [_review(r, **kw) for r in rs]
    a, b = _totals(rs, before), _totals(rs, after)
    per = {k: {"before": a[k], "after": b[k]} for k in a}
    runs_out, reproduced = {}, []
    for r, fb, fa in zip(rs, before, after, strict=True):
        if r["set"] == "d262386":
            reproduced.append(sorted(fb) == r["stored"])
        ch = {}
        for f in sorted(set(fa) ^ set(fb)):
            ch[str(f)] = {"x_bound": [round(float(x), 2) for x in r["ratio"][f]],
                          "over_4x": bool(r["over"][f]), "good": bool(r["good"][f]),
                          "now": "flagged" if f in fa else "unflagged",
                          "message": fa.get(f) or fb.get(f)}
        if ch:
            runs_out.setdefault(f"{r['set']}/{r['run']}", {})[r["bone"]] = ch
    return {"per_set": per, "changed": runs_out, "d262386_reproduced": bool(reproduced) and all(reproduced)}


def scale_split(rs) -> dict:
    """The change split in two: per set, the check with the shifted windows and the bone's median as before
    (:data:`core.tracking.flags_ends.SCALE_WITHOUT_ENDS` False: every frame's residual with the window cut)
    — the end handling alone — next to the defaults (the median without the end frames)."""
    from core.tracking import flags_ends

    out = {}
    for name, v in (("windows_only", False), ("with_scale", True)):
        old, flags_ends.SCALE_WITHOUT_ENDS = flags_ends.SCALE_WITHOUT_ENDS, v
        try:
            t = _totals(rs, [_review(r) for r in rs])
        finally:
            flags_ends.SCALE_WITHOUT_ENDS = old
        out[name] = {k: {n: x[n] for n in ("silent", "good_flagged", "ends_silent", "ends_good_flagged")}
                     for k, x in t.items()}
    return out


def crowd_sweep(rs, crowds=(2, 3, 4, None)) -> dict:
    """Per ``crowd`` (None: off): silent frames and good frames flagged per set, the end frames' too."""
    out = {}
    for c in crowds:
        t = _totals(rs, [_review(r, crowd=c) for r in rs])
        out[str(c)] = {k: {n: v[n] for n in ("silent", "good_flagged", "ends_silent", "ends_good_flagged")}
                       for k, v in t.items()}
    return out


def walking(frames=FRAMES, sizes=SIZES, draws: int = 6, n: int = 60) -> dict:
    """The review's repro: per frame turned and size, over ``draws`` noise draws of the walking track, the
    draws that flag it and the good frames flagged (all the others), before and now; and without a frame
    turned, the good frames flagged (the noise's own)."""
    from core.studies.tracking.trajectory_gaps import CENTER, walking_track
    from core.tracking.flags_post import trajectory_review

    def track(seed, turns):
        def shift(k, p):
            p[5] += np.radians(turns.get(k, 0.0))

        return walking_track(n, (0.01, 0.05), seed, shift)

    fr = np.arange(n)
    out: dict = {"draws": draws, "n": n}
    for name, kw in (("before", BEFORE), ("now", {})):
        got = {"none": sum(len(trajectory_review(fr, track(s, {}), CENTER, **kw)[0]) for s in range(draws))}
        for f in frames:
            for deg in sizes:
                hit = good = 0
                for s in range(draws):
                    fl = trajectory_review(fr, track(s, {f: deg}), CENTER, **kw)[0]
                    hit, good = hit + (f in fl), good + len(set(fl) - {f})
                got[f"{f}/{deg:g}"] = {"caught": hit, "good_flagged": good}
        out[name] = got
    return out


def main(argv=None) -> int:
    from ._study_cli import stored_parser, write_stamped

    p = stored_parser("trajectory_ends", __doc__)
    p.add_argument("--draws", type=int, default=6, help="noise draws of the walking track (0: none)")
    a = p.parse_args(argv)
    from core.studies.tracking.trajectory_silent import runs

    rs = list(runs(table=TABLE))
    got = counts(rs)
    got["scale"] = scale_split(rs)
    got["crowd"] = crowd_sweep(rs)
    if a.draws:
        got["walking"] = walking(draws=a.draws)
    for k, v in got["per_set"].items():
        b, n = v["before"], v["after"]
        print(f"{k}: silent {b['silent']} -> {n['silent']} of {b['over']}, good flagged "
              f"{b['good_flagged']} -> {n['good_flagged']} of {b['good']}; at the ends silent "
              f"{b['ends_silent']} -> {n['ends_silent']} of {b['ends_over']}, good flagged "
              f"{b['ends_good_flagged']} -> {n['ends_good_flagged']} of "
              f"{b['ends_good']}")
    print("d262386's stored flags reproduced by the check before:", got["d262386_reproduced"])
    for name, v in got["scale"].items():
        print(f"{name}:", {k: (s["silent"], s["good_flagged"]) for k, s in v.items()})
    for c, v in got["crowd"].items():
        print(f"crowd {c}:", {k: (s["silent"], s["good_flagged"]) for k, s in v.items()})
    if a.draws:
        for name in ("before", "now"):
            w = got["walking"][name]
            print(name, "no frame off: good flagged", w["none"])
            for f in FRAMES:
                print(f"  frame {f}: " + "  ".join(f"{d:g}: {w[f'{f}/{d:g}']['caught']}/{a.draws} "
                                                  f"(+{w[f'{f}/{d:g}']['good_flagged']})" for d in SIZES))
    if a.out:
        write_stamped(a.out, "core.studies.tracking.trajectory_ends", argv, a.machine_name, got)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
