"""Figures of the marker study (matplotlib, Agg backend only) and the real-data detection overlay.

* ``markers_convergence.png`` — thesis Fig. 4.4: mean (± SD) final error vs initial-guess
  perturbation for the seven localizers.
* ``markers_drift.png`` — thesis Table 4.1 as bars: frame-to-frame drift (mean, RMS).
* ``markers_intermarker.png`` — thesis Fig. 4.5: histograms of inter-marker distance errors.
* ``markers_dose.png`` — drift RMS and inter-marker σ vs dose for three localizers.
* :func:`detection_overlay` — detections drawn on a radiograph (RGB array).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["detection_overlay", "study_figures", "wrist_detection_figure"]


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def study_figures(res: dict, out_dir) -> list[Path]:
    """Write the three study figures for a :func:`core.studies.markers.study.run_study` result."""
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
    fig, axes = plt.subplots(2, 4, figsize=(12, 5.5), constrained_layout=True)
    for ax, m, c in zip(axes.ravel(), methods, colors, strict=False):
        d = res["intermarker"][m]
        e = np.array(d["edges"])
        h = np.array(d["hist"], float)
        # about 40 bars over ±5 σ around the mean
        half = 5.0 * (d["sigma"] or 0.05) + abs(d["mu"] or 0.0)
        k = max(1, round(2 * half / (e[1] - e[0]) / 40))
        n = (len(h) // k) * k
        h, e = h[:n].reshape(-1, k).sum(axis=1), e[: n + 1 : k]
        w = e[1] - e[0]
        ax.set_xlim(-half, half)
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
    if res.get("dose_sweep"):
        paths.append(_dose_figure(plt, res, out / "markers_dose.png"))
    return paths


def _dose_figure(plt, res: dict, path: Path) -> Path:
    sweep = res["dose_sweep"]
    ppp = [d["photons_per_pixel"] for d in sweep]
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4), constrained_layout=True)
    for m in sweep[0]["drift_rms_px"]:
        lw = 2.5 if m == res["recommended"] else 1.2
        a.plot(ppp, [d["drift_rms_px"][m] for d in sweep], "o-", lw=lw, label=m)
        b.plot(ppp, [d["intermarker_sigma_mm"][m] * 1e3 for d in sweep], "o-", lw=lw, label=m)
    a.axhline(0.05, color="k", ls="--", lw=1)
    b.axhline(35.0, color="k", ls="--", lw=1)
    thesis = res["scene"]["photons_per_pixel"]
    for ax, lab in ((a, "drift RMS (px)"), (b, "inter-marker σ (µm)")):
        ax.axvline(thesis, color="tab:gray", ls=":", lw=1)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xticks(ppp, [f"{q:.0f}" for q in ppp])
        ax.xaxis.set_minor_locator(plt.NullLocator())
        ax.set_xlabel("detected quanta per pixel at full fluence (dotted: thesis-like)")
        ax.set_ylabel(lab)
        ax.legend(fontsize=8)
    fig.suptitle(f"Precision vs dose ({res['config']['dose_frames']} frames per dose)")
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def detection_overlay(image: np.ndarray, uv: np.ndarray, radius: np.ndarray, *, crop=None,
                      label: str = "", matched=None) -> np.ndarray:
    """RGB (uint8) copy of a grey image with a ring (3 radii) around each detection.

    ``crop = (u0, v0, w, h)`` cuts a region first (pixels); ``label`` is written top-left;
    ``matched (N,)`` bool draws matched detections green and the others red.
    """
    import cv2

    img = np.asarray(image)
    if img.dtype != np.uint8:
        lo, hi = np.percentile(img, (0.5, 99.5))
        img = (255 * np.clip((img - lo) / max(hi - lo, 1e-12), 0, 1)).astype(np.uint8)
    rgb = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    ok = np.zeros(len(uv), bool) if matched is None else np.asarray(matched, bool)
    for (u, v), r, m in zip(np.asarray(uv), np.asarray(radius), ok, strict=True):
        colour = (0, 200, 0) if m else (0, 0, 255)
        cv2.circle(rgb, (round(float(u)), round(float(v))), max(4, round(3 * float(r))), colour, 2,
                   cv2.LINE_AA)
    if crop is not None:
        u0, v0, w, h = (int(x) for x in crop)
        rgb = rgb[v0 : v0 + h, u0 : u0 + w].copy()
    if label:
        cv2.putText(rgb, label, (8, 24), cv2.FONT_HERSHEY_SIMPLEX, 0.7, (0, 160, 255), 2, cv2.LINE_AA)
    return rgb[..., ::-1].copy()


def wrist_detection_figure(sample, out_path, *, frame: int = 1, diameter_px: float = 7.0,
                           min_snr: float = 10.0) -> dict:
    """Detect the steel beads in both wrist radiographs, match them epipolarly, save an overlay.

    ``sample`` is a :class:`core.samples.WristSample`. The PNG shows the forearm region of each
    view, matched beads green and unmatched red. Returns counts and match statistics.
    """
    import cv2

    from core.markers.detect import detect_beads, field_mask
    from core.markers.pose import match_epipolar, triangulate_beads

    dets = []
    for v in range(2):
        img = sample.frame(v, frame)
        dets.append(detect_beads(img, diameter_px=diameter_px, min_snr=min_snr, mask=field_mask(img)))
    m = match_epipolar(sample.rig[0], sample.rig[1], dets[0].uv, dets[1].uv, max_distance=3.0)
    tri = triangulate_beads(sample.rig, np.stack([dets[0].uv[m.pairs[:, 0]], dets[1].uv[m.pairs[:, 1]]]))
    panels = []
    for v, det in enumerate(dets):
        matched = np.isin(np.arange(len(det)), m.pairs[:, v])
        u0, v0 = (det.uv.min(axis=0) - 120).clip(0).astype(int)
        u1, v1 = (det.uv.max(axis=0) + 120).astype(int)
        img = sample.frame(v, frame)
        crop = (u0, v0, min(u1, img.shape[1]) - u0, min(v1, img.shape[0]) - v0)
        panel = detection_overlay(img, det.uv, det.radius, crop=crop, matched=matched,
                                  label=f"cam{v + 1}: {len(det)} beads, {matched.sum()} matched")
        scale = 900 / panel.shape[0]
        panels.append(cv2.resize(panel, (round(panel.shape[1] * scale), 900), interpolation=cv2.INTER_AREA))
    fig = np.hstack([panels[0], np.full((900, 8, 3), 255, np.uint8), panels[1]])
    cv2.imwrite(str(out_path), fig[..., ::-1])
    return {"detections": [len(d) for d in dets], "matched": len(m.pairs),
            "ambiguous": int(m.ambiguous.sum()), "median_epipolar_px": float(np.median(m.distance)),
            "median_reprojection_px": float(np.median(tri.rms_error))}
