"""Edge-operator comparison of thesis §6.4: line pairs and a foot frame, with ground truth.

Line pairs (``python -m core.studies.similarity.edge_study``)
----------------------------------------------------
A lead bar pattern (0.1 mm Pb on 40 mm of water, 60 keV) with groups of five line pairs at
0.5, 0.75 and 1.5 lp/mm in the detector plane is area-sampled (8 × 8 sub-pixels) on the pixels of
a :func:`core.synthetic.foot_rig` camera (1024 px, 0.293 mm; Nyquist 1.71 lp/mm) and passed
through that camera's realistic :meth:`core.synthetic.ImagingModel.fluoroscope` chain (quantum
noise, PSF with the lab's MTF50 of 0.5 cycles/mm, veiling glare, 12-bit camera; no distortion,
no roll-off) and flatfield-normalised. Per operator and frequency, on the edge magnitude:

* ``edge_to_background`` — mean magnitude on the true bar edges over the mean on the flat
  background (thesis Fig. 6.11's "magnitude relative to the background");
* ``cnr`` — (mean on edges − mean on background) / SD on background;
* ``resolved`` — fraction of the bar edges where the magnitude profile (averaged along the bars)
  has a local maximum within ±1 px.

Foot frame
----------
A :func:`core.synthetic.make_foot_scene` frame (512 px, realistic chain without distortion),
view 0. Truth: the outlines of every bone's own projection (pixels where a bone's DRR support
changes, dilated by 1 px), so edges of overlapping bones count too. Per operator: the ROC area
(AUC) of the magnitude as a detector of outline pixels among all foot pixels, and the CNR of
outline against other foot pixels.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from scipy import ndimage

from core.imaging.edges import OPERATORS, detect_edges

__all__ = ["FREQUENCIES_LP_MM", "VARIANTS", "foot_comparison", "line_pair_comparison", "line_pair_image"]

FREQUENCIES_LP_MM = (0.5, 0.75, 1.5)
#: operators compared: name -> (operator, sigma); the thesis' 3 x 3 set plus Abdou, Frei-Chen,
#: derivative of Gaussian and Sobel on a pre-smoothed image
VARIANTS = {op: (op, 1.0 if op == "gaussian" else 0.0) for op in OPERATORS}
VARIANTS["sobel~1"] = ("sobel", 1.0)


def _camera(pixels: int = 1024):
    from core.synthetic import foot_rig

    return foot_rig(pixels=pixels)[0]


def line_pair_image(*, pixels: int = 1024, size: int = 384, seed: int = 0, lead_mm: float = 0.1,
                    water_mm: float = 40.0, energy_kev: float = 60.0):
    """``(image, truth)``: a flatfield-normalised line-pair frame and its ground truth.

    ``truth`` holds per frequency the row span ``(r0, r1)`` of the group, the true edge columns
    (float, pixel centres at integers), and the background span of columns.
    """
    from core.synthetic import ImagingModel, attenuation_per_mm

    cam = _camera(pixels)
    px = float(cam.pixel_size)
    mu_pb = attenuation_per_mm("lead", energy_kev)
    mu_w = attenuation_per_mm("water", energy_kev)
    sub = 8
    L = np.full((size, size), mu_w * water_mm)
    truth = {}
    band = size // len(FREQUENCIES_LP_MM)
    x0 = size * 0.3  # pattern starts here (pixels); left of it: flat background
    for g, f in enumerate(FREQUENCIES_LP_MM):
        r0, r1 = g * band + band // 4, (g + 1) * band - band // 4
        half = 0.5 / f / px  # bar width in pixels
        edges = x0 + half * np.arange(10 + 1)
        # area-sampled bars: fraction of each pixel covered by lead
        u = (np.arange(size * sub) + 0.5) / sub - 0.5
        inside = np.zeros_like(u, dtype=bool)
        for k in range(0, 10, 2):
            inside |= (u >= edges[k]) & (u < edges[k + 1])
        cover = inside.reshape(size, sub).mean(axis=1)
        L[r0:r1] += mu_pb * lead_mm * cover[None, :]
        truth[f] = {"rows": (r0, r1), "edges": edges - 0.5, "background": (8, int(x0) - 8)}
    model = ImagingModel.fluoroscope(cam, distortion=None, rolloff_edge=1.0)
    img = model.to_float(model.apply(L, rng=seed))
    return img.astype(np.float64), truth


def _local_max(profile: np.ndarray, col: float) -> bool:
    lo, hi = int(np.floor(col - 1)), int(np.ceil(col + 1))
    for c in range(max(lo, 1), min(hi, len(profile) - 2) + 1):
        if profile[c] >= profile[c - 1] and profile[c] >= profile[c + 1] and profile[c] > 0:
            return True
    return False


def line_pair_comparison(*, seed: int = 0, variants: dict | None = None) -> dict:
    """Statistics per variant and frequency (see the module docs) plus the mean profiles."""
    img, truth = line_pair_image(seed=seed)
    out = {"frequencies_lp_mm": list(FREQUENCIES_LP_MM), "variants": {}, "profiles": {}, "intensity": {}}
    for name, (op, sigma) in (variants or VARIANTS).items():
        mag = detect_edges(img, op, sigma=sigma).magnitude
        stats = {}
        for f, t in truth.items():
            r0, r1 = t["rows"]
            prof = mag[r0:r1].mean(axis=0)
            cols = np.rint(t["edges"]).astype(int)
            on = mag[r0:r1][:, cols]
            b0, b1 = t["background"]
            bg = mag[r0:r1, b0:b1]
            sd = float(bg.std())
            stats[str(f)] = {
                "edge_to_background": float(on.mean() / bg.mean()) if bg.mean() > 0 else float("inf"),
                "cnr": float((on.mean() - bg.mean()) / sd) if sd > 0 else float("inf"),
                "resolved": float(np.mean([_local_max(prof, c) for c in t["edges"]])),
            }
            out["profiles"].setdefault(str(f), {})[name] = (prof / max(bg.mean(), 1e-12)).tolist()
            out["intensity"][str(f)] = img[r0:r1].mean(axis=0).tolist()
        out["variants"][name] = stats
    out["truth_edges"] = {str(f): t["edges"].tolist() for f, t in truth.items()}
    return out


def _auc(score: np.ndarray, positive: np.ndarray) -> float:
    """ROC area: probability that a random positive scores above a random negative (ties 1/2)."""
    s = score.ravel()
    p = positive.ravel()
    order = np.argsort(s, kind="mergesort")
    r = np.empty(len(s))
    r[order] = np.arange(1, len(s) + 1)
    # average ranks of ties
    _, inv, counts = np.unique(s, return_inverse=True, return_counts=True)
    sums = np.bincount(inv, weights=r)
    r = (sums / counts)[inv]
    n_pos, n_neg = int(p.sum()), int((~p).sum())
    if n_pos == 0 or n_neg == 0:
        return float("nan")
    return float((r[p].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))


def foot_image(*, pixels: int = 512, seed: int = 0, view: int = 0, spacing: float = 0.5,
               device: str | None = None):
    """``(image, outline, foot)``: flatfield-normalised frame, true bone outlines, foot region
    (``spacing``: voxel size of the phantoms, mm)."""
    from dataclasses import replace

    from core.render import DRRRenderer
    from core.synthetic import ImagingModel, make_foot_scene

    scene = make_foot_scene(n_frames=1, pixels=pixels, seed=seed, imaging="ideal", spacing=spacing,
                            tissue_spacing=max(2.0, spacing))
    models = tuple(ImagingModel.fluoroscope(c, distortion=None) for c in scene.rig)
    scene = replace(scene, imaging=models)
    frame = scene.render_frame(0)[view]
    img = scene.imaging[view].to_float(frame).astype(np.float64)
    mus = [b.to_attenuation(scene.bone_transfer) for b in scene.bones]
    r = DRRRenderer(scene.rig, mus, device=device)
    per_bone = r.render(scene.poses(0)[None], views=[view], roi="full").numpy()[0, 0]  # (nb, H, W)
    outline = np.zeros(img.shape, bool)
    for d in per_bone:
        m = d > 1e-3
        outline |= m ^ ndimage.binary_erosion(m)
    outline = ndimage.binary_dilation(outline)
    foot = ndimage.binary_dilation(per_bone.sum(axis=0) > 1e-3, iterations=10)
    return img, outline, foot


def foot_comparison(*, pixels: int = 512, seed: int = 0, spacing: float = 0.5, device: str | None = None,
                    variants: dict | None = None) -> tuple[dict, np.ndarray, dict]:
    """``(stats, image, magnitudes)``: AUC and CNR per variant on a synthetic foot frame."""
    img, outline, foot = foot_image(pixels=pixels, seed=seed, spacing=spacing, device=device)
    stats, mags = {}, {}
    pos = outline[foot]
    for name, (op, sigma) in (variants or VARIANTS).items():
        mag = detect_edges(img, op, sigma=sigma).magnitude
        mags[name] = mag
        v = mag[foot]
        neg = v[~pos]
        stats[name] = {"auc": _auc(v, pos),
                       "cnr": float((v[pos].mean() - neg.mean()) / neg.std()) if neg.std() > 0 else 0.0}
    return stats, img, mags


def write_report(out: Path, figures: Path, *, device: str | None = None) -> dict:
    """Run both comparisons, write ``edge_study.json`` into ``out`` and two PNGs into ``figures``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lp = line_pair_comparison()
    foot, img, mags = foot_comparison(device=device)
    doc = {"line_pairs": {k: v for k, v in lp.items() if k != "profiles" and k != "intensity"},
           "foot": foot}
    out.mkdir(parents=True, exist_ok=True)
    figures.mkdir(parents=True, exist_ok=True)
    (out / "edge_study.json").write_text(json.dumps(doc, indent=1))
    names = list(lp["variants"])
    fig, axes = plt.subplots(len(FREQUENCIES_LP_MM), 1, figsize=(11, 9), squeeze=False)
    for ax, f in zip(axes[:, 0], FREQUENCIES_LP_MM, strict=True):
        edges = np.array(lp["truth_edges"][str(f)])
        lo, hi = int(edges[0]) - 6, int(edges[-1]) + 6
        x = np.arange(lo, hi)
        for n in names:
            ax.plot(x, np.array(lp["profiles"][str(f)][n])[lo:hi], lw=1,
                    label=f"{n} ({lp['variants'][n][str(f)]['resolved']:.0%})")
        for e in edges:
            ax.axvline(e, color="k", lw=0.4, ls=":")
        ax.set_title(f"{f} lp/mm: edge magnitude / background mean along the profile "
                     "(dotted: true edges; % resolved)", fontsize=8)
        ax.tick_params(labelsize=7)
    axes[0, 0].legend(fontsize=6, ncol=4)
    fig.tight_layout()
    fig.savefig(figures / "similarity_edges_linepairs.png", dpi=110)
    plt.close(fig)
    # foot: a hindfoot crop of each magnitude, titled with AUC / CNR
    h, w = img.shape
    crop = (slice(h // 4, h // 4 + h // 2), slice(w // 4, w // 4 + w // 2))
    fig, axes = plt.subplots(3, 4, figsize=(12, 9.5))
    axes.flat[0].imshow(img[crop], cmap="gray")
    axes.flat[0].set_title("synthetic foot frame (view 0)", fontsize=8)
    for ax, n in zip(axes.flat[1:], names, strict=False):
        m = mags[n][crop]
        ax.imshow(m, cmap="gray", vmax=np.percentile(m, 99.5))
        ax.set_title(f"{n}: AUC {foot[n]['auc']:.3f}, CNR {foot[n]['cnr']:.2f}", fontsize=8)
    for ax in axes.flat:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    fig.savefig(figures / "similarity_edges_foot.png", dpi=100)
    plt.close(fig)
    return doc


def main() -> None:  # pragma: no cover - command line
    import argparse

    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", default="similarity_study_out")
    ap.add_argument("--figures", default=None)
    ap.add_argument("--device", default=None)
    a = ap.parse_args()
    doc = write_report(Path(a.out), Path(a.figures or a.out), device=a.device)
    print(json.dumps(doc, indent=1))


if __name__ == "__main__":  # pragma: no cover
    main()
