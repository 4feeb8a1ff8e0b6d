"""Check a calibrated rig on real radiographs: beads of one view on the epipolar lines of the other.

With a correct calibration, the image of a bead in view 2 lies on the epipolar line of its image
in view 1 (and vice versa); the distance measures the rig's error (plus localisation noise)
without any ground truth. Beads are detected and localised with :mod:`core.markers`
(:func:`~core.markers.detect_beads`, the recommended localizer) inside the exposed field, and
matched one-to-one by the Hungarian assignment on the symmetric epipolar distance within
``gate_px`` (:func:`core.markers.match_epipolar`). Because the matching itself uses the epipolar
distance, every unmatched detection and the distance of each bead to the *nearest* other-view
detection's line (no gate) are reported too.

Pixels are ``(u, v) = (column, row)``, origin at the centre of the top-left pixel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.camera import Rig
from ..markers import detect_beads, fundamental_matrix, match_epipolar, triangulate_beads
from ..markers.detect import field_mask

__all__ = ["EpipolarCheck", "epipolar_check", "line_distances"]


def line_distances(F: np.ndarray, uv1: np.ndarray, uv2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distances (px) of ``uv2[i]`` from the epipolar line of ``uv1[i]`` in view 2 and of
    ``uv1[i]`` from the line of ``uv2[i]`` in view 1 (``x₂ᵀ F x₁ = 0``)."""
    h1 = np.column_stack([uv1, np.ones(len(uv1))])
    h2 = np.column_stack([uv2, np.ones(len(uv2))])
    l2, l1 = h1 @ F.T, h2 @ F
    num = np.abs(np.sum(h2 * l2, axis=1))
    return num / np.hypot(l2[:, 0], l2[:, 1]), num / np.hypot(l1[:, 0], l1[:, 1])


@dataclass(frozen=True, eq=False)
class EpipolarCheck:
    """Result of :func:`epipolar_check` for one frame pair.

    ``uv (2,)`` detections per view; ``pairs (K, 2)`` matched indices; ``d_view2 (K,)`` distance
    of each matched view-2 bead from its view-1 bead's line and ``d_view1 (K,)`` the converse,
    px; ``nearest_view2 (N1,)`` for every view-1 detection the distance of the closest view-2
    detection to its line (no gate); ``reprojection_px (K,)`` RMS reprojection error of the
    triangulated matches; ``F`` the rig's fundamental matrix.
    """

    uv: tuple[np.ndarray, np.ndarray]
    radius: tuple[np.ndarray, np.ndarray]
    pairs: np.ndarray
    d_view2: np.ndarray
    d_view1: np.ndarray
    nearest_view2: np.ndarray
    reprojection_px: np.ndarray
    F: np.ndarray

    def summary(self) -> dict:
        d = np.concatenate([self.d_view1, self.d_view2])
        return {"detections": [len(u) for u in self.uv], "matched": len(self.pairs),
                "median_px": float(np.median(d)) if d.size else None,
                "rms_px": float(np.sqrt(np.mean(d**2))) if d.size else None,
                "max_px": float(d.max()) if d.size else None,
                "median_reprojection_px": float(np.median(self.reprojection_px)) if d.size else None}


def epipolar_check(rig: Rig, images, *, diameter_px: float = 7.0, min_snr: float = 10.0,
                   gate_px: float = 3.0, field_margin_px: int = 40) -> EpipolarCheck:
    """Detect beads in both radiographs and measure their distances from the epipolar lines.

    Parameters
    ----------
    rig : Rig
        Two calibrated cameras.
    images : pair of (H, W) arrays
        The two (distortion-corrected) radiographs of one instant.
    diameter_px : float
        Expected projected bead diameter (px); the wrist sample's ~1 mm beads are ~7 px.
    min_snr : float
        Detection threshold of :func:`core.markers.detect_beads`.
    gate_px : float
        Largest symmetric epipolar distance of a match.
    field_margin_px : int
        Detections closer than this to the unexposed border are ignored (lettering, rim).
    """
    if not isinstance(rig, Rig) or len(rig) != 2:
        raise ValueError("rig: expected a Rig of two cameras")
    if len(images) != 2:
        raise ValueError(f"images: expected two radiographs, got {len(images)}")
    dets = [detect_beads(img, diameter_px=diameter_px, min_snr=min_snr,
                         mask=field_mask(img, margin_px=field_margin_px)) for img in images]
    F = fundamental_matrix(rig[0], rig[1])
    m = match_epipolar(rig[0], rig[1], dets[0].uv, dets[1].uv, max_distance=gate_px)
    uv1, uv2 = dets[0].uv[m.pairs[:, 0]], dets[1].uv[m.pairs[:, 1]]
    d2, d1 = line_distances(F, uv1, uv2)
    if len(dets[0]) and len(dets[1]):
        a, b = np.repeat(dets[0].uv, len(dets[1]), 0), np.tile(dets[1].uv, (len(dets[0]), 1))
        nearest = line_distances(F, a, b)[0].reshape(len(dets[0]), len(dets[1])).min(axis=1)
    else:
        nearest = np.zeros(0)
    rep = triangulate_beads(rig, np.stack([uv1, uv2])).rms_error if len(uv1) else np.zeros(0)
    return EpipolarCheck((dets[0].uv, dets[1].uv), (dets[0].radius, dets[1].radius), m.pairs, d2, d1,
                         nearest, np.asarray(rep), F)
