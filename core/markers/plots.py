"""Figures of the marker study (matplotlib, Agg backend only) and the real-data detection overlay.

* ``markers_convergence.png`` — thesis Fig. 4.4: mean (± SD) final error vs initial-guess
  perturbation for the seven localizers.
* ``markers_drift.png`` — thesis Table 4.1 as bars: frame-to-frame drift (mean, RMS).
* ``markers_intermarker.png`` — thesis Fig. 4.5: histograms of inter-marker distance errors.
* :func:`detection_overlay` — detections drawn on a radiograph (RGB array).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["detection_overlay", "study_figures"]


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def study_figures(res: dict, out_dir) -> list[Path]:
    """Write the three study figures for a :func:`core.markers.study.run_study` result."""
    plt = _plt()
    out = Path(out_dir)
    methods = list(res["methods"])
    colors = plt.cm.tab10(np.arange(len(methods)))
    paths = []
    # Fig. 4.4
    fig, ax = plt.subplots(figsize=(8, 5), constrained_layout=True)
    for k, m in enumerate(methods):
        c = res["convergence"][m]
        x = np.array([e["level_percent"] for e in c]) + (k - 3) * 2.0
        y = np.array([e["mean"] for e in c], dtype=float)
        s = np.array([e["sd"] for e in c], dtype=float)
        lw = 2.5 if m == res["recommended"] else 1.2
        ax.errorbar(x, y, yerr=s, marker="o", ms=3, lw=lw, capsize=2, color=colors[k], label=m)
    r = min(res["scene"]["bead_diameters_px"]) / 2
    ax.axhline(r, color="tab:blue", ls=":", lw=1)
    ax.text(2, r * 1.08, f"smallest bead radius ({r:.1f} px)", color="tab:blue", fontsize=8)
    ax.axhline(0.1, color="k", ls="--", lw=1)
    ax.text(2, 0.108, "0.1 px", fontsize=8)
    ax.set_yscale("log")
    ax.set_xlabel("initial-guess perturbation (% of bead radius)")
    ax.set_ylabel("final centroid error (px), mean ± SD")
    n = res["convergence"][methods[0]][0]["n"]
    ax.set_title(f"Robustness to the initial guess (21-bead lattice, n = {n} per level)")
    ax.legend(fontsize=8, ncol=2)
    paths.append(out / "markers_convergence.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    # Table 4.1
    fig, ax = plt.subplots(figsize=(8, 4.2), constrained_layout=True)
    mean = [res["drift"][m]["mean"] for m in methods]
    rms = [res["drift"][m]["rms"] for m in methods]
    xs = np.arange(len(methods))
    ax.bar(xs - 0.2, mean, 0.4, label="mean", color="tab:gray")
    ax.bar(xs + 0.2, rms, 0.4, label="RMS", color=colors[:, :3])
    for x, v in zip(xs, rms, strict=True):
        ax.text(x + 0.2, v * 1.05, f"{v:.3f}", ha="center", fontsize=7)
    ax.axhline(0.05, color="k", ls="--", lw=1)
    ax.set_yscale("log")
    ax.set_xticks(xs, [m.replace("_", "\n") for m in methods], fontsize=8)
    ax.set_ylabel("frame-to-frame drift (px)")
    ax.set_title(f"Stability over {res['config']['n_frames']} static frames (dashed: 0.05 px)")
    ax.legend(fontsize=8)
    paths.append(out / "markers_drift.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    # Fig. 4.5
    fig, axes = plt.subplots(2, 4, figsize=(12, 5.5), constrained_layout=True, sharex=True)
    for ax, m, c in zip(axes.ravel(), methods, colors, strict=False):
        d = res["intermarker"][m]
        e = np.array(d["edges"])
        h = np.array(d["hist"], float)
        w = e[1] - e[0]
        ax.bar(e[:-1], h / max(h.sum() * w, 1), w, align="edge", color=c, alpha=0.7)
        x = np.linspace(e[0], e[-1], 300)
        if d["sigma"]:
            pdf = np.exp(-0.5 * ((x - d["mu"]) / d["sigma"]) ** 2) / (d["sigma"] * np.sqrt(2 * np.pi))
            ax.plot(x, pdf, "r", lw=1)
        ax.set_title(f"{m}\nμ={d['mu'] * 1e3:.1f} µm σ={d['sigma'] * 1e3:.1f} µm", fontsize=9)
        ax.set_xlabel("distance error (mm)", fontsize=8)
    axes.ravel()[-1].axis("off")
    n = res["intermarker"][methods[0]]["n"]
    fig.suptitle(f"Inter-marker distance errors of grid neighbours (n = {n})")
    paths.append(out / "markers_intermarker.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    return paths


def detection_overlay(image: np.ndarray, uv: np.ndarray, radius: np.ndarray, *, crop=None,
                      label: str = "") -> np.ndarray:
    """RGB (uint8) copy of a grey image with a red ring (3 radii) around each detection.

    ``crop = (u0, v0, w, h)`` cuts a region first (pixels); ``label`` is written top-left.
    """
    import cv2

    img = np.asarray(image)
    if img.dtype != np.uint8:
        lo, hi = np.percentile(img, (0.5, 99.5))
        img = (255 * np.clip((img - lo) / max(hi - lo, 1e-12), 0, 1)).astype(np.uint8)
    rgb = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    for (u, v), r in zip(np.asarray(uv), np.asarray(radius), strict=True):
        cv2.circle(rgb, (round(float(u)), round(float(v))), max(4, round(3 * float(r))), (0, 0, 255), 2,
                   cv2.LINE_AA)
    if crop is not None:
        u0, v0, w, h = (int(x) for x in crop)
        rgb = rgb[v0 : v0 + h, u0 : u0 + w].copy()
    if label:
        cv2.putText(rgb, label, (8, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (0, 160, 255), 2, cv2.LINE_AA)
    return rgb[..., ::-1].copy()
