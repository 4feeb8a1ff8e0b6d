"""Real-data check of Autoscoper's volume frame: wrist radius and ulna poses from a ``.tra`` file.

``python -m core.studies.io.autoscoper_wrist [--data DIR] [--out PNG] [--tra PATH]``

The Autoscoper wrist sample comes without tracking results, so the ``.tra`` is made here from
Talus's registration of radius and ulna at frame 0099 (``core.studies.tracking.wrist_check``,
saved in ``resources/benchmarks/tracking_wrist_h100.json``): written in
Autoscoper's volume frame (:mod:`core.io.autoscoper_pose`), as Autoscoper writes it (16 values a
volume, row order, commas), then read back and rendered two ways — the TIFF stacks read in
Autoscoper's own volume frame and posed with the file's matrices unchanged, and read in Talus's
default frame and posed with the converted ``T_lab_from_bone``. Both must put the bones on the
radiograph: the check scores how strongly the radiograph has edges on the DRR's silhouette
(:func:`edge_agreement`) at the pose and at 3 mm / 5° perturbations.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

__all__ = ["edge_agreement", "gradient_correlation", "main", "overlay", "render_pair", "wrist_tra_poses"]

BONES = ("radius", "ulna")
FRAME = 1  # index of frame 0099 among the sample's three frames


TRACKED = Path(__file__).resolve().parents[3] / "resources" / "benchmarks" / "tracking_wrist_h100.json"


def wrist_tra_poses(results: Path = TRACKED) -> np.ndarray:
    """``T_lab_from_bone`` (Talus default frame) of radius and ulna at frame 0099, as registered
    by ``core.studies.tracking.wrist_check`` (its saved H100 run)."""
    import json

    rows = json.loads(Path(results).read_text())["results"]
    found = {r["bone"]: np.array(r["pose"], dtype=float) for r in rows if r["frame"] == "0099"}
    out = []
    for b in BONES:
        T = np.eye(4)
        T[:3] = found[b][:3]
        u, _, vt = np.linalg.svd(T[:3, :3])
        T[:3, :3] = u @ vt
        out.append(T)
    return np.stack(out)


def _sample_radiograph(sample, view: int, roi, scale: float, shape) -> np.ndarray:
    u0, v0 = roi[:2]
    rr, cc = np.mgrid[0 : shape[0], 0 : shape[1]].astype(np.float32)
    map_u = (u0 + (cc + 0.5) * scale - 0.5).astype(np.float32)
    map_v = (v0 + (rr + 0.5) * scale - 0.5).astype(np.float32)
    return cv2.remap(sample.frame(view, FRAME), map_u, map_v, cv2.INTER_LINEAR).astype(np.float64)


def gradient_correlation(a: np.ndarray, b: np.ndarray, sigma: float = 1.5) -> float:
    """Mean of the normalised cross-correlations of the x and y gradients of ``a`` and ``b``."""
    out = []
    for img in (a, b):
        g = cv2.GaussianBlur(img.astype(np.float64), (0, 0), sigma)
        out.append((cv2.Sobel(g, cv2.CV_64F, 1, 0), cv2.Sobel(g, cv2.CV_64F, 0, 1)))
    ncc = []
    for ga, gb in zip(out[0], out[1], strict=True):
        x, y = ga - ga.mean(), gb - gb.mean()
        ncc.append(float((x * y).sum() / np.sqrt((x * x).sum() * (y * y).sum() + 1e-30)))
    return float(np.mean(ncc))


def edge_agreement(drr: np.ndarray, radiograph: np.ndarray, sigma: float = 1.0) -> float:
    """How strongly the radiograph has an edge where the DRR's silhouette is: the mean gradient
    magnitude of the (blurred) radiograph on the outline of ``drr > 5 % of its maximum``, over
    its mean in the whole box (1 = no better than anywhere)."""
    g = cv2.GaussianBlur(radiograph.astype(np.float64), (0, 0), sigma)
    mag = np.hypot(cv2.Sobel(g, cv2.CV_64F, 1, 0), cv2.Sobel(g, cv2.CV_64F, 0, 1))
    m = (drr > 0.05 * drr.max()).astype(np.uint8)
    edge = m - cv2.erode(m, np.ones((3, 3), np.uint8))
    if not edge.any():
        return 0.0
    return float(mag[edge > 0].mean() / (mag.mean() + 1e-12))


def render_pair(sample, volumes, poses, *, scale: float = 3.0, device=None):
    """Per (bone, view): ``(drr, radiograph crop, roi)`` of ``volumes[b]`` at ``poses[b]``."""
    from core.render.drr import DRRRenderer
    from core.render.volume import HUTransfer

    r = DRRRenderer(sample.rig, volumes, transfer=HUTransfer(threshold=300.0), device=device, step_mm=0.75)
    out = {}
    for b in range(len(volumes)):
        batch = r.render(np.asarray(poses)[None, b : b + 1], bones=[b], margin=40, scale=scale)
        for v in range(len(sample.rig)):
            drr = batch.item(0, v, 0)
            roi = batch.roi[0, v, 0]
            out[b, v] = (drr, _sample_radiograph(sample, v, roi, scale, drr.shape), roi)
    return out


def _perturb(T: np.ndarray, k: int, mm: float, deg: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    P = T.copy()
    if k < 6:  # translation ± x, y, z
        P[k // 2, 3] += mm if k % 2 == 0 else -mm
    else:  # rotation ± about the bone's x, y, z through its origin... about its centre below
        ax = np.zeros(3)
        ax[(k - 6) // 2] = np.radians(deg) * (1 if k % 2 == 0 else -1)
        P[:3, :3] = T[:3, :3] @ Rotation.from_rotvec(ax).as_matrix()
    return P


def scores(
    sample, volumes, poses, *, mm: float = 3.0, deg: float = 5.0, scale: float = 3.0, device=None
) -> dict:
    """:func:`edge_agreement` at ``poses`` and at 12 perturbations (±``mm`` along the lab's x, y,
    z; ±``deg`` about the bone's axes through its centroid), per bone, mean over the views."""
    base = render_pair(sample, volumes, poses, scale=scale, device=device)
    res = {}
    for b, vol in enumerate(volumes):
        nv = len(sample.rig)
        at = sum(edge_agreement(base[b, v][0], base[b, v][1]) for v in range(nv)) / nv
        c = np.append(vol.centroid(300.0), 1.0)
        pert = []
        for k in range(12):
            P = _perturb(poses[b], k, mm, deg)
            if k >= 6:  # keep the centroid in place: rotate about it
                P[:3, 3] += (poses[b] @ c)[:3] - (P @ c)[:3]
            Ps = np.array(poses, dtype=float).copy()
            Ps[b] = P
            rb = render_pair(sample, [vol], Ps[b : b + 1], scale=scale, device=device)
            pert.append(sum(edge_agreement(rb[0, v][0], rb[0, v][1]) for v in range(nv)) / nv)
        res[BONES[b]] = {"at_pose": at, "perturbed": pert}
    return res


def overlay(sample, volumes, poses, *, device=None) -> np.ndarray:
    """RGB figure: per camera the radiograph around both bones with the DRR outlines (radius red,
    ulna green) drawn on it."""
    scale = 1.25
    r = render_pair(sample, volumes, poses, scale=scale, device=device)
    rows = []
    colours = ((0, 0, 255), (0, 200, 0))  # BGR
    for v in range(len(sample.rig)):
        rois = np.array([r[b, v][2] for b in range(len(volumes))])
        u0, v0 = rois[:, :2].min(axis=0)
        u1, v1 = (rois[:, :2] + rois[:, 2:]).max(axis=0)
        img = sample.frame(v, FRAME)[v0:v1, u0:u1]
        img = cv2.resize(img, (int((u1 - u0) / scale), int((v1 - v0) / scale)), interpolation=cv2.INTER_AREA)
        bgr = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
        for b in range(len(volumes)):
            drr, _, roi = r[b, v]
            mask = (drr > 0.05 * drr.max()).astype(np.uint8)
            contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
            off = np.array([(roi[0] - u0) / scale, (roi[1] - v0) / scale]).round().astype(int)
            cv2.drawContours(bgr, [c + off for c in contours], -1, colours[b], 1, cv2.LINE_AA)
        cv2.putText(bgr, f"cam{v + 1} 0099 .tra: radius red, ulna green", (6, 18),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 220, 255), 1, cv2.LINE_AA)
        rows.append(bgr)
    w = max(x.shape[1] for x in rows)
    rows = [np.pad(x, ((0, 4), (0, w - x.shape[1]), (0, 0))) for x in rows]
    return np.vstack(rows)[..., ::-1].copy()


def autoscoper_frame_volumes(sample):
    """The sample's radius and ulna stacks read in Autoscoper's volume frame (``VolumeFlip 0 0 0``)."""
    from core.io.autoscoper_pose import autoscoper_volume_geometry
    from core.render.volume import CTVolume

    out = []
    for name in BONES:
        v = sample.volumes[name]
        origin, direction = autoscoper_volume_geometry(v.shape_ijk, v.spacing, (0, 0, 0))
        out.append(CTVolume(v.data, v.spacing, origin, direction, v.units, v.name))
    return out


def main(argv=None) -> int:
    from core.io.autoscoper_pose import lab_from_bone_from_tra, tra_from_lab_from_bone
    from core.io.autoscoper_tra import read_tra, write_tra
    from core.samples import load_wrist_sample
    from core.studies import sample_data_dir

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=None)
    ap.add_argument("--out", type=Path, default=Path("resources/figures/autoscoper_wrist_tra_overlay.png"))
    ap.add_argument("--tra", type=Path, default=Path("/tmp/wrist_0099.tra"))
    a = ap.parse_args(argv)
    data = a.data or sample_data_dir() / "autoscoper_wrist"
    sample = load_wrist_sample(data)
    vols = [sample.volumes[b] for b in BONES]
    talus = wrist_tra_poses()
    tra = np.stack([tra_from_lab_from_bone(talus[b], vols[b]) for b in range(2)])
    write_tra(a.tra, tra[None])
    back = read_tra(a.tra, n_volumes=2)[0]
    lab = np.stack([lab_from_bone_from_tra(back[b], vols[b]) for b in range(2)])
    print("max |T_lab_from_bone - original|:", float(np.abs(lab - talus).max()))
    print("Talus frame:", scores(sample, vols, lab))
    print("Autoscoper frame:", scores(sample, autoscoper_frame_volumes(sample), back))
    rgb = overlay(sample, autoscoper_frame_volumes(sample), back)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(a.out), rgb[..., ::-1])
    print("wrote", a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
