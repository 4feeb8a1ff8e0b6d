"""The public Autoscoper wrist sample (``shared/data/autoscoper_wrist``): loading and a preview.

The sample holds two MayaCam 2.0 cameras, undistorted 1760² radiographs of a wrist, and CT
sub-volumes of the radius, ulna and metacarpals (uint16 multipage TIFF, slices first, voxel size
0.39625 × 0.39625 × 0.625 mm; stored values are CT numbers + 1024, 0 outside the segmented bone).

No ground-truth pose comes with it. :data:`WRIST_RADIUS_POSE` is a *hand-found* plausible pose of
the radius at frame 0099: the radius shaft axis was triangulated from its centre line picked in
both radiographs (matching points along epipolar lines), the volume's slice axis (distal end at
slice 0) was laid along it, and the roll about the shaft was chosen by eye (90° of four tried)
so that the distal flare matches both views. It is a starting pose for display and tests, not a
registration result.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .geometry.camera import Rig
from .geometry.mayacam import rig_from_mayacam
from .io.tiff_volume import read_tiff_volume
from .render.drr import DRRRenderer
from .render.volume import CTVolume, HUTransfer

__all__ = ["WRIST_RADIUS_POSE", "WristSample", "load_wrist_sample", "wrist_preview"]

WRIST_VOXEL_MM = (0.39625, 0.39625, 0.625)
WRIST_BONES = {"radius": "rad", "ulna": "uln", "mc3": "mc3", "mc2_mc3": "mc2_mc3"}
WRIST_RADIUS_POSE = np.array(
    [
        [-0.82454, -0.557306, 0.097694, 108.397386],
        [0.11766, 0.0, 0.993054, 136.757533],
        [-0.553435, 0.830307, 0.065573, 87.601601],
        [0.0, 0.0, 0.0, 1.0],
    ]
)
# re-orthonormalise the rounded rotation
_u, _s, _vt = np.linalg.svd(WRIST_RADIUS_POSE[:3, :3])
WRIST_RADIUS_POSE[:3, :3] = _u @ _vt
WRIST_RADIUS_POSE.setflags(write=False)


@dataclass(frozen=True)
class WristSample:
    rig: Rig
    volumes: dict[str, CTVolume]
    frame_paths: tuple[tuple[Path, ...], tuple[Path, ...]]  # per camera, sorted by frame number

    def frame(self, view: int, index: int) -> np.ndarray:
        """Radiograph ``index`` of camera ``view`` as a uint8 (H, W) array."""
        p = self.frame_paths[view][index]
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)  # LZW-compressed TIFF
        if img is None or img.ndim != 2:
            raise ValueError(f"frame: cannot read {p} as a grey-level image")
        return img


def load_wrist_sample(data_dir: str | Path) -> WristSample:
    """Load the wrist sample from ``data_dir`` (the ``autoscoper_wrist`` folder).

    Raises ``ValueError`` naming the missing file when the folder is incomplete.
    """
    d = Path(data_dir)
    cams = [d / "Calibration" / f"xr_calib_wrist_cam0{k}.txt" for k in (1, 2)]
    for p in cams:
        if not p.is_file():
            raise ValueError(f"data_dir: missing camera file {p}")
    rig = rig_from_mayacam(cams)
    vols = {}
    for name, stem in WRIST_BONES.items():
        p = d / "Models" / f"{stem}_dcm_cropped.tif"
        vols[name] = read_tiff_volume(p, WRIST_VOXEL_MM, hu_offset=-1024.0, name=name)
    frames = []
    for k in (1, 2):
        folder = d / "XMA_UND" / f"xr_data_wrist_cam0{k}"
        paths = tuple(sorted(folder.glob("*.tif")))
        if not paths:
            raise ValueError(f"data_dir: no radiographs (*.tif) in {folder}")
        frames.append(paths)
    return WristSample(rig, vols, (frames[0], frames[1]))


def wrist_preview(
    sample: WristSample,
    *,
    bone: str = "radius",
    pose: np.ndarray | None = None,
    frame_index: int = 1,
    device: str | None = None,
    transfer: HUTransfer | None = None,
    scale: float = 2.0,
) -> tuple[np.ndarray, list[np.ndarray]]:
    """Render ``bone`` at ``pose`` in both cameras and compose a preview.

    Returns ``(rgb (H, W, 3) uint8, drrs)``: per camera a row "radiograph | DRR | overlay"
    cropped to the bone's projected region (plus margin), and the DRR line-integral images.
    """
    T = WRIST_RADIUS_POSE if pose is None else np.asarray(pose, dtype=float)
    tr = transfer or HUTransfer(threshold=300.0)
    vol = sample.volumes[bone]
    r = DRRRenderer(sample.rig, [vol], transfer=tr, device=device, step_mm=0.5)
    batch = r.render(T[None, None], margin=120, scale=scale)
    rows, drrs = [], []
    for v in range(len(sample.rig)):
        u0, v0 = batch.roi[0, v, 0, :2]
        drr = batch.item(0, v, 0)
        # sample the radiograph at the DRR's ray positions: (u0 + (c + 0.5) s - 0.5, ...)
        rr, cc = np.mgrid[0 : drr.shape[0], 0 : drr.shape[1]].astype(np.float32)
        map_u = (u0 + (cc + 0.5) * batch.scale - 0.5).astype(np.float32)
        map_v = (v0 + (rr + 0.5) * batch.scale - 0.5).astype(np.float32)
        img = cv2.remap(sample.frame(v, frame_index), map_u, map_v, cv2.INTER_LINEAR)
        hi = np.percentile(drr[drr > 0], 99.5) if np.any(drr > 0) else 1.0
        d8 = (255 * np.clip(drr / hi, 0, 1)).astype(np.uint8)
        grey = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
        drr_rgb = cv2.cvtColor(255 - d8, cv2.COLOR_GRAY2BGR)  # radiograph-like: bone dark
        over = grey.copy()
        over[..., 2] = np.maximum(over[..., 2], d8)
        over[..., 1] = np.minimum(over[..., 1], 255 - d8)
        row = np.hstack([grey, drr_rgb, over])
        cv2.putText(row, f"cam{v + 1}: radiograph | DRR ({bone}) | overlay", (6, 18),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 200, 255), 1, cv2.LINE_AA)
        rows.append(row)
        drrs.append(drr)
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0))) for r in rows]
    return np.vstack(rows)[..., ::-1].copy(), drrs
