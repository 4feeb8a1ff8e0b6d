"""DRR overlays for the fluoroscope panes (Qt-free): render each bone at its pose, then colour.

:class:`OverlayRenderer` owns two :class:`core.render.DRRRenderer` instances for a rig and the
bones: a *preview* one (rays through ``preview_scale``-pixel blocks and a coarser ray step, used
while the user drags) and a *full* one (used when the interaction pauses). A render returns,
for each (view, bone), the DRR line integrals over the bone's projected box; :func:`colorize`
turns one into an RGBA image in one of three modes:

* ``"blend"`` — the bone's colour with alpha proportional to its line integral;
* ``"edges"`` — the gradient magnitude of the DRR (bone outline and inner edges);
* ``"outline"`` — only the silhouette boundary.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from core.geometry.camera import Rig
from core.render import CTVolume, DRRRenderer, HUTransfer

__all__ = ["MODES", "OverlayImage", "OverlayRenderer", "colorize"]

MODES = ("blend", "edges", "outline")


@dataclass(frozen=True)
class OverlayImage:
    """DRR of one bone in one view: ``drr[r, c]`` is the ray through full-resolution pixel
    ``(u0 + (c + 0.5) * scale - 0.5, v0 + (r + 0.5) * scale - 0.5)``."""

    view: int
    bone: int
    roi: tuple[int, int, int, int]
    scale: float
    drr: np.ndarray


class OverlayRenderer:
    """Preview and full-resolution bone DRRs for the panes.

    Parameters
    ----------
    rig : Rig
    volumes : sequence of CTVolume
        One per bone, in HU.
    device : str, optional
        Warp device (default CUDA when present).
    preview_scale : float
        Full-resolution pixels per preview ray (default 2).
    transfer : HUTransfer, optional
        Default: bone only (HU >= 150).
    """

    def __init__(self, rig: Rig, volumes: Sequence[CTVolume], *, device: str | None = None,
                 preview_scale: float = 2.0, transfer: HUTransfer | None = None) -> None:
        tr = transfer or HUTransfer(threshold=150.0)
        step = float(min(v.spacing.min() for v in volumes))
        self.full = DRRRenderer(rig, volumes, transfer=tr, device=device)
        self.preview = DRRRenderer(rig, volumes, transfer=tr, device=device, step_mm=2.0 * step)
        self.preview_scale = float(preview_scale)
        self.n_views = len(rig)

    def render(self, poses, *, bones: Sequence[int] | None = None, preview: bool = False,
               cancel=None) -> list[OverlayImage]:
        """DRRs of ``bones`` (default all) at ``poses`` (one (4, 4) per rendered bone)."""
        renderer = self.preview if preview else self.full
        scale = self.preview_scale if preview else 1.0
        bones = tuple(range(len(renderer.volumes))) if bones is None else tuple(bones)
        poses = np.asarray(poses, dtype=float).reshape(len(bones), 4, 4)
        if cancel is not None and cancel():
            return []
        batch = renderer.render(poses[None], bones=bones, scale=scale, margin=2)
        out = []
        for v in range(self.n_views):
            for n, bone in enumerate(bones):
                roi = tuple(int(a) for a in batch.roi[0, v, n])
                if roi[2] == 0 or roi[3] == 0:
                    continue
                out.append(OverlayImage(v, bone, roi, scale, batch.item(0, v, n).copy()))
        return out


def colorize(drr: np.ndarray, color: Sequence[float], opacity: float, mode: str = "blend",
             *, reference: float | None = None) -> np.ndarray:
    """RGBA (H, W, 4) uint8 overlay of a DRR.

    ``reference`` is the line integral shown fully opaque in ``"blend"`` mode (default: the
    99th percentile of the bone's pixels).
    """
    if mode not in MODES:
        raise ValueError(f"mode: expected one of {MODES}, got {mode!r}")
    d = np.asarray(drr, dtype=np.float32)
    rgba = np.zeros((*d.shape, 4), dtype=np.uint8)
    rgba[..., :3] = (np.clip(np.asarray(color, dtype=np.float32), 0, 1) * 255).astype(np.uint8)
    inside = d > 0
    if not inside.any():
        return rgba
    if mode == "blend":
        ref = reference or float(np.percentile(d[inside], 99)) or 1.0
        alpha = np.clip(d / ref, 0, 1)
    elif mode == "edges":
        gx = cv2.Sobel(d, cv2.CV_32F, 1, 0, ksize=3)
        gy = cv2.Sobel(d, cv2.CV_32F, 0, 1, ksize=3)
        mag = np.hypot(gx, gy)
        ref = float(np.percentile(mag[mag > 0], 95)) or 1.0
        alpha = np.clip(mag / ref, 0, 1)
    else:
        mask = inside.astype(np.uint8)
        alpha = (mask - cv2.erode(mask, np.ones((3, 3), np.uint8))).astype(np.float32)
    rgba[..., 3] = (np.clip(opacity, 0, 1) * 255 * alpha).astype(np.uint8)
    return rgba
