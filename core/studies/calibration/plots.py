"""Figures of the calibration study and the real-data epipolar check (matplotlib, Agg only)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from core.calibration.epipolar_check import EpipolarCheck
from core.calibration.sensitivity import PARAMETERS

__all__ = ["epipolar_figure", "error_map_figure", "instability_figure", "labelling_figure",
           "sensitivity_figure", "sobol_figure"]


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _line_ends(l: np.ndarray, box) -> np.ndarray | None:
    """End points of the line ``a u + b v + c = 0`` inside ``box = (u0, v0, u1, v1)``."""
    a, b, c = l
    u0, v0, u1, v1 = box
    pts = []
    if abs(b) > 1e-12:
        for u in (u0, u1):
            v = -(a * u + c) / b
            if v0 <= v <= v1:
                pts.append((u, v))
    if abs(a) > 1e-12:
        for v in (v0, v1):
            u = -(b * v + c) / a
            if u0 <= u <= u1:
                pts.append((u, v))
    return np.array(pts[:2]) if len(pts) >= 2 else None


def epipolar_figure(images, check: EpipolarCheck, path, *, names=("cam01", "cam02"),
                    margin: int = 90) -> Path:
    """Both radiographs (cropped to the beads) with the epipolar lines of the other view's
    matched beads (one colour per bead, dashed) and the beads (circles; unmatched in red)."""
    plt = _plt()
    cmap = plt.get_cmap("tab20")
    fig, axes = plt.subplots(1, 2, figsize=(11, 7.5))
    for v, ax in enumerate(axes):
        img = np.asarray(images[v])
        uv = check.uv[v]
        lo = np.maximum(uv.min(axis=0) - margin, 0) if len(uv) else np.zeros(2)
        hi = np.minimum(uv.max(axis=0) + margin, [img.shape[1] - 1, img.shape[0] - 1]) if len(uv) \
            else np.array(img.shape[::-1]) - 1
        box = (lo[0], lo[1], hi[0], hi[1])
        ax.imshow(img, cmap="gray", extent=(-0.5, img.shape[1] - 0.5, img.shape[0] - 0.5, -0.5))
        other = check.uv[1 - v]
        for k, (i1, i2) in enumerate(check.pairs):
            src = other[i2] if v == 0 else other[i1]
            h = np.append(src, 1.0)
            line = check.F.T @ h if v == 0 else check.F @ h
            ends = _line_ends(line, box)
            col = cmap(k % 20)
            if ends is not None:
                ax.plot(ends[:, 0], ends[:, 1], "--", color=col, lw=0.9)
            me = uv[i1] if v == 0 else uv[i2]
            ax.plot(*me, "o", mfc="none", mec=col, ms=9, mew=1.4)
        matched = set(check.pairs[:, v].tolist())
        for i, p in enumerate(uv):
            if i not in matched:
                ax.plot(*p, "x", color="red", ms=8, mew=1.5)
        d = check.d_view1 if v == 0 else check.d_view2
        ax.set_xlim(box[0], box[2])
        ax.set_ylim(box[3], box[1])
        txt = (f"{names[v]}: {len(uv)} beads, {len(check.pairs)} matched\ndistance to the other "
               f"view's lines: median {np.median(d):.2f} px, max {d.max():.2f} px" if len(d) else
               f"{names[v]}: {len(uv)} beads, none matched")
        ax.set_title(txt, fontsize=9)
        ax.set_xlabel("u (column, px)")
        ax.set_ylabel("v (row, px)")
    fig.suptitle("Epipolar lines of the other view's beads\n(dashed, same colour = matched pair; "
                 "red x = unmatched)", fontsize=10)
    fig.tight_layout()
    out = Path(path)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def instability_figure(dlt: dict, ba: dict, path) -> Path:
    """Spread of the SID and source position: single-frame cube DLT vs bundle adjustment.

    ``dlt``/``ba`` hold per-draw deviations ``sid (D, V)`` mm and ``source (D, V, 3)`` mm.
    """
    plt = _plt()
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    sids = [np.abs(np.asarray(d["sid"])).ravel() for d in (dlt, ba)]
    srcs = [np.linalg.norm(np.asarray(d["source"]), axis=-1).ravel() for d in (dlt, ba)]
    bins = [np.geomspace(max(min(v.min() for v in vals), 1e-4), max(v.max() for v in vals), 50)
            for vals in (sids, srcs)]
    for k, (lab, d, col) in enumerate((("cube DLT, 1 frame", dlt, "tab:red"), ("spiral BA", ba, "tab:blue"))):
        axes[0].hist(sids[k], bins=bins[0], alpha=0.6, color=col, label=lab)
        axes[1].hist(srcs[k], bins=bins[1], alpha=0.6, color=col, label=lab)
        s = np.asarray(d["source"]).reshape(-1, 3)
        axes[2].scatter(s[:, 0], s[:, 2], s=6, alpha=0.5, color=col, label=lab)
    axes[0].set_xscale("log")
    axes[1].set_xscale("log")
    axes[0].set_xlabel("|SID error| (mm)")
    axes[1].set_xlabel("source position error |ΔC| (mm)")
    axes[2].set_xlabel("ΔX (mm)")
    axes[2].set_ylabel("ΔZ (mm)")
    for ax in axes:
        ax.legend(fontsize=8)
    axes[0].set_ylabel("draws x cameras")
    fig.suptitle("Camera parameters under 0.05 px localisation noise (thesis §5.2.1)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def error_map_figure(points: np.ndarray, maps: dict, sources: np.ndarray, path, *,
                     what: str = "mean") -> Path:
    """Per-lattice-point reconstruction error (``maps``: name -> (N,) mm) in two central slices
    of the cone intersection (one lattice layer each: x-z through the middle y, y-z through the
    middle x), coloured by error (Fig. 5.6)."""
    plt = _plt()
    names = list(maps)
    fig, axes = plt.subplots(len(names), 2, figsize=(12, 4.6 * len(names)), squeeze=False)
    cen = np.median(points, axis=0)
    step = np.min(np.diff(np.unique(points[:, 0]))) if len(np.unique(points[:, 0])) > 1 else 10.0
    for r, name in enumerate(names):
        e = np.asarray(maps[name])
        vmax = float(np.percentile(e, 99.5))
        for c, (i, j, k) in enumerate(((0, 2, 1), (1, 2, 0))):
            ax = axes[r, c]
            sl = np.abs(points[:, k] - cen[k]) <= step / 2
            sc = ax.scatter(points[sl, i], points[sl, j], c=e[sl], s=14, marker="s", cmap="inferno",
                            vmin=0, vmax=vmax)
            for s_ in sources:  # direction to each source (they lie far outside the plot)
                d = (s_ - cen)[[i, j]]
                d = d / np.linalg.norm(d) * 0.35 * np.ptp(points[:, [i, j]], axis=0).max()
                ax.annotate("", xy=cen[[i, j]] + d, xytext=cen[[i, j]],
                            arrowprops={"arrowstyle": "->", "color": "c", "lw": 1.5})
            lab = "xyz"
            ax.set_xlabel(f"{lab[i]} (mm)")
            ax.set_ylabel(f"{lab[j]} (mm)")
            ax.set_aspect("equal")
            fig.colorbar(sc, ax=ax, label=f"{what} error (mm)")
            ax.set_title(f"{name}: slice {lab[k]} = {cen[k]:.0f} mm\nwhole volume: RMS "
                         f"{np.sqrt(np.mean(e**2)):.3f} mm, worst point {e.max():.3f} mm", fontsize=9)
    fig.suptitle(f"3-D reconstruction error ({what} over calibrations) in the intersection of the "
                 "X-ray cones, 10 mm lattice\narrows point to the sources; note the different colour "
                 "scales of the rows", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return Path(path)


def error_histogram_figure(levels: dict, path) -> Path:
    """Histograms of the per-point mean and max reconstruction error per noise level (Fig. 5.7);
    ``levels``: label -> (mean (N,), max (N,))."""
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
    allv = np.concatenate([np.concatenate(v) for v in levels.values()])
    allv = allv[allv > 0]
    bins = np.geomspace(allv.min(), allv.max(), 60)
    for lab, (mean, mx) in levels.items():
        axes[0].hist(mean, bins=bins, histtype="step", lw=1.5, label=lab)
        axes[1].hist(mx, bins=bins, histtype="step", lw=1.5, label=lab)
    axes[0].set_xlabel("mean reconstruction error per lattice point (mm)")
    axes[1].set_xlabel("max reconstruction error per lattice point (mm)")
    for ax in axes:
        ax.set_ylabel("lattice points")
        ax.legend(fontsize=8)
        ax.set_xscale("log")
    fig.suptitle("Reconstruction error vs localisation noise: single-frame cube DLT and spiral BA")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


_LONG = {"sid": "SID (source-image distance)", "cu": "principal point u", "cv": "principal point v",
         "X": "source X", "Y": "source Y", "Z": "source Z", "rx": "rotation rx", "ry": "rotation ry",
         "rz": "rotation rz"}


def sensitivity_figure(study, path, *, camera: str = "") -> Path:
    """Deviation of each camera parameter vs perturbation amplitude (Figs. 5.3-5.5)."""
    plt = _plt()
    names = ["sid", "cu", "cv", "X", "Y", "Z", "rx", "ry", "rz"]
    fig, axes = plt.subplots(2, 5, figsize=(17, 6.5))
    for ax, name in zip(axes.ravel(), [*names, "rms"], strict=True):
        if name == "rms":
            y, unit = study.reprojection_rms, "px"
            ax.set_title("reprojection RMS", fontsize=9)
        else:
            y, unit = study.parameter(name), PARAMETERS[name]
            if unit == "rad":
                y, unit = np.degrees(y), "deg"
            ax.set_title(_LONG.get(name, name), fontsize=9)
        ax.scatter(study.amplitude, y, s=2, alpha=0.3, c=study.marker, cmap="tab20")
        ax.set_xlabel("perturbation (px)", fontsize=8)
        ax.set_ylabel(unit, fontsize=8)
    cam = f" ({camera})" if camera else ""
    fig.suptitle(f"Cube DLT{cam}: deviation of each camera parameter from the noise-free DLT when one "
                 f"bead at a time is moved by the given amplitude ({len(study.amplitude)} Latin-hypercube "
                 "samples; colour = bead)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return Path(path)


def sobol_figure(sobol, path, *, camera: str = "") -> Path:
    """Sobol indices of every DLT camera parameter w.r.t. every bead image coordinate (Table 5.1
    analogue): heat maps of the first-order and total indices (rows: parameters, columns: ``u`` and
    ``v`` of each bead) and the sum of the first-order indices per parameter (≈ 1: additive)."""
    plt = _plt()
    names = list(PARAMETERS)
    s1, st = np.clip(sobol.first_order, 0, None), np.clip(sobol.total, 0, None)
    vmax = float(max(s1.max(), st.max()))
    fig, axes = plt.subplots(1, 3, figsize=(17, 4.6), gridspec_kw={"width_ratios": [6, 6, 1.3]})
    for ax, m, title in ((axes[0], s1, "first-order index"), (axes[1], st, "total index")):
        im = ax.imshow(m, aspect="auto", cmap="viridis", vmin=0, vmax=vmax)
        ax.set_yticks(range(len(names)), names)
        ax.set_xticks(range(len(sobol.inputs)), sobol.inputs, rotation=90, fontsize=7)
        ax.set_xlabel("input: image coordinate of a bead")
        ax.set_title(title, fontsize=10)
        fig.colorbar(im, ax=ax, fraction=0.04)
    tot = sobol.first_order.sum(axis=1)
    axes[2].barh(range(len(names)), tot, color="tab:blue")
    axes[2].axvline(1.0, color="k", lw=0.8, ls="--")
    axes[2].set_yticks(range(len(names)), names)
    axes[2].invert_yaxis()
    axes[2].set_xlabel("sum of first-order")
    axes[2].set_title("additivity", fontsize=10)
    cam = f", {camera}" if camera else ""
    fig.suptitle(f"Sobol indices of the cube DLT parameters{cam}: inputs uniform in ±0.25 px, "
                 f"{sobol.n_evaluations} DLT evaluations", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return Path(path)


def labelling_figure(images, labellings, bead_ids, path, *, titles=("view 1", "view 2")) -> Path:
    """Rendered frames (cropped to the detections) with every labelled bead annotated with its id."""
    plt = _plt()
    fig, axes = plt.subplots(1, len(images), figsize=(6.5 * len(images), 6.9), layout="constrained")
    for ax, img, lab, t in zip(np.atleast_1d(axes), images, labellings, titles, strict=True):
        ax.imshow(img, cmap="gray")
        for (u, v), k in zip(lab.uv, lab.labels, strict=True):
            if k >= 0:
                ax.plot(u, v, "o", mfc="none", mec="lime", ms=7)
                ax.text(u + 4, v - 4, bead_ids[k], color="yellow", fontsize=7)
            else:
                ax.plot(u, v, "x", color="red", ms=7, mew=1.5)
        if len(lab.uv):
            m = 0.12 * np.ptp(lab.uv, axis=0).max() + 10
            lo, hi = lab.uv.min(axis=0) - m, lab.uv.max(axis=0) + m
            ax.set_xlim(max(lo[0], -0.5), min(hi[0], img.shape[1] - 0.5))
            ax.set_ylim(min(hi[1], img.shape[0] - 0.5), max(lo[1], -0.5))
        ax.set_title(f"{t}: {lab.n_labelled} of {len(lab.uv)} detections labelled", fontsize=10)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle("Automatic labelling: green circle + id = labelled detection, red x = detection left "
                 "unlabelled;\nbeads without a mark = detections removed on purpose (simulated missed "
                 "or occluded beads)", fontsize=10)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)
