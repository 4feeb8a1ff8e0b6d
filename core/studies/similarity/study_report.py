"""JSON and figures of the metric response study (``python -m core.studies.similarity.study_report``).

Runs :func:`core.studies.similarity.study.response_study` on the synthetic cases (talus, calcaneus and
second metatarsal of a :func:`core.synthetic.make_foot_scene` frame: ground truth) and on the
real wrist sample (radius at the hand-found pose; skipped with a message when the data folder is
absent), adds weighted combinations of metrics, and writes

* ``<out>/similarity_study.json`` — configuration, per case and metric the reference score,
  noise response, binned perturbation responses, Spearman ρ, false-optimum fraction, the 1-D
  sweeps with their statistics, and a cross-case ranking table;
* ``<figures>/similarity_sweeps_<case>.png``, ``similarity_perturbations_<case>.png``,
  ``similarity_noise.png`` and ``similarity_ranking.png``.

Matplotlib runs on the Agg backend (no window).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from core.studies.similarity.study import (
    PARTS,
    SWEEP_AXES,
    StudyConfig,
    StudyResult,
    combine,
    merge,
    response_study,
    summarize,
)

__all__ = ["COMBINATIONS", "ranking", "report", "run_study", "study_case", "write_figures"]

#: weighted combinations evaluated from the stored scores (no extra renders)
COMBINATIONS = {
    "gc+go~1.5": {"gc~1.5": 1.0, "go~1.5": 1.0},
    "gc+gi~1.5": {"gc~1.5": 1.0, "gi~1.5": 1.0},
    "gc~1.5+pi": {"gc~1.5": 1.0, "pi": 1.0},
    "gc~1.5+ncc": {"gc~1.5": 1.0, "ncc": 1.0},
}


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def ranking(summaries: dict[str, dict]) -> dict[str, dict]:
    """Cross-case averages per metric of the statistics that decide a default cost.

    ``summaries`` maps case name -> :func:`summarize` output. Columns: Spearman ρ of score vs
    translation / rotation magnitude (more negative = more monotonic), false-optimum fractions,
    mean capture ranges (px, deg), the worst sweep-peak offsets, sweep local extrema, and the
    fraction of the reference score kept at noise level 0.1.
    """
    names = list(next(iter(summaries.values())))
    out = {}
    for n in names:
        rows = [s[n] for s in summaries.values()]
        out[n] = {
            "spearman_translation": float(np.mean([r["translation"]["spearman"] for r in rows])),
            "spearman_rotation": float(np.mean([r["rotation"]["spearman"] for r in rows])),
            "false_optimum_translation": float(np.mean(
                [r["translation"]["false_optimum_fraction"] for r in rows])),
            "false_optimum_rotation": float(np.mean([r["rotation"]["false_optimum_fraction"] for r in rows])),
            "capture_translation_px": float(np.mean([r["capture_translation_px_mean"] for r in rows])),
            "capture_rotation_deg": float(np.mean([r["capture_rotation_deg_mean"] for r in rows])),
            "peak_offset_translation_px_worst": float(max(r["peak_offset_translation_px_max"] for r in rows)),
            "peak_offset_rotation_deg_worst": float(max(r["peak_offset_rotation_deg_max"] for r in rows)),
            "sweep_local_extrema": float(np.mean([r["sweep_local_extrema_mean"] for r in rows])),
            "noise_retained_at_0.1": float(np.mean([r["noise_retained_at_0.1"] for r in rows])),
            "reference_score": float(np.mean([r["reference"] for r in rows])),
        }
    return out


def _grid(n: int):
    cols = 4
    rows = int(np.ceil(n / cols))
    return rows, cols


def write_figures(results: Sequence[StudyResult], summaries: dict[str, dict], rank: dict[str, dict],
                  figures: Path) -> list[Path]:
    """Write the study figures into ``figures``; returns their paths."""
    plt = _plt()
    figures.mkdir(parents=True, exist_ok=True)
    paths = []
    for res in results:
        names = list(res.reference)
        tag = res.case.replace("synthetic-", "").replace("wrist-", "wrist_")
        # sweeps
        r, c = _grid(len(names))
        fig, axes = plt.subplots(r, c, figsize=(3.2 * c, 2.4 * r), squeeze=False)
        for ax, n in zip(axes.flat, names, strict=False):
            for a in SWEEP_AXES:
                ax.plot(res.sweep_offsets[a], res.sweeps[n][a], "-" if a[0] == "t" else "--", lw=1, label=a)
            ax.axvline(0, color="k", lw=0.5)
            st = summaries[res.case][n]
            ax.set_title(f"{n}  extrema {st['sweep_local_extrema_mean']:.1f}", fontsize=8)
            ax.tick_params(labelsize=6)
        for ax in axes.flat[len(names):]:
            ax.axis("off")
        axes.flat[0].legend(fontsize=5, ncol=2)
        fig.suptitle(f"{res.case}: 1-D sweeps (translation px, solid; rotation deg, dashed)", fontsize=10)
        fig.tight_layout()
        p = figures / f"similarity_sweeps_{tag}.png"
        fig.savefig(p, dpi=110)
        plt.close(fig)
        paths.append(p)
        # random perturbations, binned
        fig, axes = plt.subplots(r, c, figsize=(3.2 * c, 2.4 * r), squeeze=False)
        for ax, n in zip(axes.flat, names, strict=False):
            st = summaries[res.case][n]
            for key, col in (("translation", "tab:green"), ("rotation", "tab:purple")):
                e = np.array(st[key]["bin_edges"])
                mid = (e[1:] + e[:-1]) / 2
                ax.errorbar(mid, st[key]["mean"], yerr=st[key]["sd"], color=col, capsize=2, lw=1,
                            label=f"{key[:5]} ρ={st[key]['spearman']:.2f}")
            ax.axhline(res.reference[n], color="k", lw=0.6, ls=":")
            ax.set_title(n, fontsize=8)
            ax.legend(fontsize=5)
            ax.tick_params(labelsize=6)
        for ax in axes.flat[len(names):]:
            ax.axis("off")
        fig.suptitle(f"{res.case}: score vs random displacement (n = {res.config.n_random} each; "
                     "px / deg; dotted: reference pose)", fontsize=10)
        fig.tight_layout()
        p = figures / f"similarity_perturbations_{tag}.png"
        fig.savefig(p, dpi=110)
        plt.close(fig)
        paths.append(p)
    # noise, all cases
    names = list(results[0].reference)
    r, c = _grid(len(names))
    fig, axes = plt.subplots(r, c, figsize=(3.2 * c, 2.4 * r), squeeze=False)
    for ax, n in zip(axes.flat, names, strict=False):
        for res in results:
            lev = np.array(res.config.noise_levels)
            m, s = res.noise[n].mean(axis=1), res.noise[n].std(axis=1)
            ax.errorbar(lev, m, yerr=s, lw=1, capsize=2, label=res.case.split("-")[-1])
        ax.set_title(n, fontsize=8)
        ax.set_xscale("symlog", linthresh=0.02)
        ax.tick_params(labelsize=6)
    axes.flat[0].legend(fontsize=6)
    for ax in axes.flat[len(names):]:
        ax.axis("off")
    fig.suptitle("score at the reference pose vs added Gaussian noise (σ / mean fluence of the ROI)",
                 fontsize=10)
    fig.tight_layout()
    p = figures / "similarity_noise.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    paths.append(p)
    # ranking
    cols = [("spearman_translation", "Spearman ρ, translation"),
            ("spearman_rotation", "Spearman ρ, rotation"),
            ("false_optimum_translation", "false optima, translation"),
            ("capture_translation_px", "capture range, px"), ("capture_rotation_deg", "capture range, deg"),
            ("noise_retained_at_0.1", "score kept at noise 0.1")]
    order = sorted(rank, key=lambda n: rank[n]["spearman_translation"] + rank[n]["spearman_rotation"])
    fig, axes = plt.subplots(1, len(cols), figsize=(3.0 * len(cols), 0.28 * len(order) + 1.2), sharey=True)
    for ax, (key, title) in zip(axes, cols, strict=True):
        ax.barh(range(len(order)), [rank[n][key] for n in order], color="tab:blue")
        ax.set_title(title, fontsize=8)
        ax.tick_params(labelsize=7)
        ax.axvline(0, color="k", lw=0.5)
    axes[0].set_yticks(range(len(order)))
    axes[0].set_yticklabels(order)
    axes[0].invert_yaxis()
    used = [r.case for r in results if r.truth] or [r.case for r in results]
    fig.suptitle("metric ranking, mean over the ground-truth cases (" + ", ".join(used) + ")", fontsize=9)
    fig.tight_layout()
    p = figures / "similarity_ranking.png"
    fig.savefig(p, dpi=110)
    plt.close(fig)
    paths.append(p)
    return paths


def _jsonable(o):
    if isinstance(o, dict):
        return {str(k): _jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_jsonable(v) for v in o]
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    return o


def study_case(name: str, *, quick: bool = False, pixels: int = 512, data_dir: Path | None = None,
               device: str | None = None, parts: Sequence[str] = PARTS, save_raw: Path | None = None,
               progress=print) -> StudyResult | None:
    """Build one case (``"talus"``, ``"calcaneus"``, ``"metatarsal2"`` or ``"wrist"``) and run the
    study ``parts`` on it; None (with a message) when the wrist data is absent. With ``save_raw``
    (a folder) the result is also pickled there as ``<name>_<parts>.pkl``."""
    from core.studies.similarity.cases import synthetic_case, wrist_case

    cfg = StudyConfig(n_random=60, sweep_steps=21, noise_repeats=2) if quick else StudyConfig()
    if name == "wrist":
        from core.studies import sample_data_dir

        folder = Path(data_dir) if data_dir else sample_data_dir() / "autoscoper_wrist"
        if not folder.is_dir():
            progress(f"wrist: sample not found at {folder}; skipped")
            return None
        case = wrist_case(folder, device=device, scale=2.0 if not quick else 4.0)
    else:
        case = synthetic_case(bone=name, pixels=pixels if not quick else 192, device=device,
                              spacing=0.5 if not quick else 1.0)
    res = response_study(case, cfg, parts=parts, progress=progress)
    if save_raw is not None:
        import pickle

        Path(save_raw).mkdir(parents=True, exist_ok=True)
        (Path(save_raw) / f"{name}_{'-'.join(parts)}.pkl").write_bytes(pickle.dumps([res]))
    return res


def report(results: Sequence[StudyResult], out: Path, figures: Path | None = None) -> dict:
    """Add :data:`COMBINATIONS`, summarise, rank (ground-truth cases only; the wrist case — a
    hand-found reference pose, not a registration — is reported beside them), write
    ``out/similarity_study.json`` and, when ``figures`` is given, the PNGs. Returns the JSON."""
    by_case: dict[str, list[StudyResult]] = {}
    for r in results:
        by_case.setdefault(r.case, []).append(r)
    done = []
    for res in (merge(v) for v in by_case.values()):
        for cname, w in COMBINATIONS.items():
            if all(k in res.reference for k in w):
                res = combine(res, w, cname)
        done.append(res)
    summaries = {r.case: summarize(r) for r in done}
    truth = {r.case: summaries[r.case] for r in done if r.truth}
    rank = ranking(truth or summaries)
    cfg = done[0].config
    doc = {
        "study": "similarity response (thesis 6.3)",
        "config": dict(vars(cfg)),
        "combinations": COMBINATIONS,
        "cases": {r.case: {"truth": r.truth, "mm_per_px": r.mm_per_px, "metrics": summaries[r.case],
                           "sweep_offsets": r.sweep_offsets} for r in done},
        "ranking": rank,
        "ranking_cases": list(truth or summaries),
    }
    out.mkdir(parents=True, exist_ok=True)
    (out / "similarity_study.json").write_text(json.dumps(_jsonable(doc), indent=1))
    if figures is not None:
        write_figures(done, summaries, rank, figures)
    return doc


def run_study(*, cases: Sequence[str] = ("talus", "calcaneus", "metatarsal2", "wrist"), jobs: int = 1,
              progress=print, **kwargs) -> list[StudyResult]:
    """:func:`study_case` for each of ``cases``; with ``jobs`` > 1 each case's experiments run in
    separate processes (noise + sweeps, translations, rotations), ``jobs`` at a time."""
    if jobs <= 1:
        res = [study_case(c, progress=progress, **kwargs) for c in cases]
    else:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        split = (("noise", "sweeps"), ("translation",), ("rotation",))
        with ProcessPoolExecutor(max_workers=jobs, mp_context=mp.get_context("spawn")) as ex:
            futs = [ex.submit(study_case, c, parts=p, progress=print, **kwargs) for c in cases for p in split]
            res = [f.result() for f in futs]
    return [r for r in res if r is not None]


def main() -> None:  # pragma: no cover - command line
    import argparse
    import pickle

    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", default="similarity_study_out", help="folder of the JSON")
    ap.add_argument("--figures", default=None, help="folder of the PNGs (default: --out)")
    ap.add_argument("--no-figures", action="store_true")
    ap.add_argument("--case", action="append", choices=("talus", "calcaneus", "metatarsal2", "wrist"))
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--pixels", type=int, default=512)
    ap.add_argument("--data", default=None, help="autoscoper_wrist folder")
    ap.add_argument("--device", default=None)
    ap.add_argument("--jobs", type=int, default=1, help="cases run in parallel processes")
    ap.add_argument("--save-raw", default=None, help="also pickle the raw results into this folder")
    ap.add_argument("--from-raw", action="append", default=None,
                    help="report pickled raw results instead of running (repeatable)")
    a = ap.parse_args()
    out = Path(a.out)
    if a.from_raw:
        results = [r for p in a.from_raw for r in pickle.loads(Path(p).read_bytes())]
    else:
        results = run_study(cases=tuple(a.case or ("talus", "calcaneus", "metatarsal2", "wrist")),
                            jobs=a.jobs, quick=a.quick, pixels=a.pixels,
                            data_dir=Path(a.data) if a.data else None, device=a.device,
                            save_raw=Path(a.save_raw) if a.save_raw else None,
                            progress=lambda m: print(m, flush=True))
    report(results, out, None if a.no_figures else Path(a.figures or a.out))


if __name__ == "__main__":  # pragma: no cover
    main()
