"""Whether the stage's switches keep every value (``python -m core.studies.tracking.stage_exact``): the
benchmark's kind of trial (:class:`~core.studies.tracking.acceptance.TrackingScene`, by default 128², 1.5 mm
voxels, 4 frames, frame 0 given) tracked with the likelihood stage under each variant
(:func:`core.studies.tracking.stage_one_bone._variant_of`'s names: ``stage_speed``'s variants and
``stage_one_bone``'s parts), in three cases — the talus alone, the three bones jointly, the talus and the
calcaneus sequentially — and every bone-frame's pose, confidence σ (the frame's ``confidence``: the stage's
covariance as the tracker reports it), flags (how many, and whether one is ``uncertain``), covariance,
independent-pixel covariance, stage steps and taken flag compared with the first variant's: ``identical``
where all are equal to the bit (else the largest differences). (Before 2026-11-28 only the fit's
covariances, which a tracked frame does not keep: NaN in every variant.) JSON on stdout (``--out``: also to
a file)."""

from __future__ import annotations

import argparse
import time

import numpy as np

__all__ = ["main", "run"]

#: the cases: (name, bones by index of the scene's, tracking mode)
CASES = (("one", (1,), "joint"), ("three", (0, 1, 2), "joint"), ("two", (1, 2), "sequential"))


def _flags(res) -> np.ndarray:
    """A frame's flags: how many, and whether one is ``uncertain`` (the move check's)."""
    flags = [str(f) for f in (getattr(res, "flags", ()) or ())]
    return np.asarray([len(flags), any("uncertain" in f for f in flags)], dtype=float)


def _record(res) -> dict:
    fit = getattr(res, "fit", None)
    t = res.timing or {}
    conf = getattr(res, "confidence", None) or {}  # (a tracked frame's: the stage's σ; its fit is not kept)
    return {"pose": np.asarray(res.pose, dtype=float),
            "sigma": np.asarray(conf.get("sigma", [np.nan] * 6), dtype=float),
            "flags": _flags(res),
            "cov": np.asarray(getattr(fit, "covariance", np.full((6, 6), np.nan)), dtype=float),
            "cov_ind": np.asarray(getattr(fit, "covariance_independent", np.full((6, 6), np.nan)),
                                  dtype=float),
            "steps": np.asarray([t.get("likelihood_steps", -1), t.get("likelihood_taken", -1)], dtype=float)}


def _compare(a: dict, b: dict) -> dict:
    """Bit equality and largest absolute differences of two runs' records (bone-frame -> record)."""
    same, worst = True, {}
    for k in a:
        for f, x in a[k].items():
            y = b[k][f]
            eq = np.array_equal(x, y, equal_nan=True)
            same = same and eq
            d = float(np.nanmax(np.abs(x - y))) if not eq and x.shape == y.shape else 0.0
            worst[f] = max(worst.get(f, 0.0), d)
    return {"identical": bool(same), "largest_differences": worst}


def run(*, device: str | None = "cpu", frames: int = 4, pixels: int = 128, voxel: float = 1.5,
        variants=("base",), cases=("one", "three", "two")) -> dict:
    """Run the study (module docs); returns the JSON-ready results."""
    from dataclasses import replace

    from core.render import DRRRenderer
    from core.studies.tracking.acceptance import TrackingScene
    from core.studies.tracking.benchmark import _search_tol
    from core.studies.tracking.stage_one_bone import _variant_of
    from core.studies.tracking.trial_frames import synthesise
    from core.tracking.trial import TrackingOptions, track

    t0 = time.perf_counter()
    n = int(frames)
    ts = TrackingScene(n_frames=max(n, 2), pixels=pixels, spacing=voxel,
                       phase=(0.0, 0.6 * max(n, 2) / 100.0), device=device)
    synthesise(ts, range(ts.scene.n_frames), 0)
    out: dict = {"study": "core.studies.tracking.stage_exact", "pixels": pixels, "voxel_mm": voxel,
                 "frames": n,
                 "variants": list(variants), "cases": {}}
    truth = ts.truth(0)
    for name, bones, mode in CASES:
        if name not in cases:
            continue
        base = TrackingOptions(mode=mode)
        o = replace(base, registration=replace(base.registration, search="newton"), refine_likelihood=True)
        ms = [ts.models[b] for b in bones]
        r = DRRRenderer(ts.scene.rig, [m.volume.to_attenuation(ts.scene.bone_transfer) for m in ms],
                        device=ts.device)
        kf = {m.name: {0: truth[b]} for m, b in zip(ms, bones, strict=True)}
        recs: dict = {}
        with _search_tol("likelihood"):
            for v in variants:
                t1 = time.perf_counter()
                with _variant_of(v, [0, 0]):
                    res = track(r, ms, ts.frames, range(n), keyframes=kf, options=o)
                recs[v] = {(m.name, f): _record(res.results[(m.name, f)]) for m in ms for f in range(1, n)}
                print(f"{name} {v}: {time.perf_counter() - t1:.1f} s", flush=True)
        first = variants[0]
        c = {"bones": [m.name for m in ms], "mode": mode,
             "stages_taken": int(sum(x["steps"][1] > 0 for x in recs[first].values())),
             "against_" + first: {v: _compare(recs[first], recs[v]) for v in variants[1:]}}
        out["cases"][name] = c
        print(name, c["against_" + first], flush=True)
    out["total_s"] = time.perf_counter() - t0
    return out


def main(argv=None) -> int:
    import json
    import pathlib

    p = argparse.ArgumentParser(prog="python -m core.studies.tracking.stage_exact",
                                description=__doc__.split("\n")[0])
    p.add_argument("--device", default="cpu")
    p.add_argument("--frames", type=int, default=4)
    p.add_argument("--pixels", type=int, default=128)
    p.add_argument("--voxel", type=float, default=1.5)
    p.add_argument("--variants", default="base", help="comma-separated: stage_one_bone's variant names")
    p.add_argument("--cases", default="one,three,two")
    p.add_argument("--out", default=None)
    a = p.parse_args(argv)
    out = run(device=a.device, frames=a.frames, pixels=a.pixels, voxel=a.voxel,
              variants=tuple(a.variants.split(",")), cases=tuple(a.cases.split(",")))
    text = json.dumps(out, indent=1, default=float)
    if a.out:
        pathlib.Path(a.out).write_text(text)
    print(json.dumps({k: v.get("against_" + out["variants"][0]) for k, v in out["cases"].items()}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
