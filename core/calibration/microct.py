"""Bead centres of a calibration object from a micro-CT scan (thesis §5.3.2).

:func:`extract_beads` finds bright beads in a (micro-)CT volume and returns their 3-D
intensity-weighted centroids and equivalent-sphere diameters; :func:`target_from_volume` turns
them into a :class:`~core.calibration.objects.CalibrationTarget` in the object's local frame (the
helix frame of :func:`core.calibration.hardware.helix_frame_from_beads` for a spiral). Physical coordinates
(mm) follow the volume's spacing, origin and direction (:class:`core.render.CTVolume`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from .._validate import positive
from ..render.volume import CTVolume
from .hardware import helix_frame_from_beads
from .objects import _HELIX_FRAME, KINDS, CalibrationTarget, _ids

__all__ = ["VolumeBeads", "extract_beads", "target_from_volume"]


@dataclass(frozen=True, eq=False)
class VolumeBeads:
    """Beads found in a CT volume by :func:`extract_beads`.

    ``centers (n, 3)`` physical mm (intensity-weighted centroids), ``diameters (n,)`` mm
    (equivalent sphere of the bead's excess intensity), ``n_voxels (n,)`` voxels above the
    threshold, ``threshold`` and ``background`` in the volume's units.
    """

    centers: np.ndarray
    diameters: np.ndarray
    n_voxels: np.ndarray
    threshold: float
    background: float


def extract_beads(volume: CTVolume, *, threshold: float | None = None, min_diameter_mm: float = 0.5,
                  max_diameter_mm: float = 20.0, margin_voxels: int = 2) -> VolumeBeads:
    """Bead centres in a (micro-)CT volume by 3-D intensity-weighted centroids.

    1. Voxels above ``threshold`` (default: half-way between the background, the volume's median,
       and the 99.99th percentile) form connected components (26-connectivity).
    2. Each component is dilated by ``margin_voxels`` so the partial-volume rim is included; its
       centroid is weighted by the excess ``max(value - background, 0)``.
    3. The diameter is that of the sphere whose volume is the excess summed over the component
       divided by the bead's plateau excess (median of the component's core, the voxels above
       the 75th percentile of its excess).

    Components outside ``[min_diameter_mm, max_diameter_mm]`` are dropped (dust, end plates).

    Parameters
    ----------
    volume : CTVolume
        Scan of the object (any units; beads brighter than the body).
    threshold : float, optional
        Segmentation threshold in the volume's units.
    min_diameter_mm, max_diameter_mm : float
        Accepted equivalent diameters, mm.
    margin_voxels : int
        Rim added around each component for the weighted centroid.

    Returns
    -------
    VolumeBeads
        Ordered by decreasing diameter.
    """
    if not isinstance(volume, CTVolume):
        raise ValueError(f"volume: expected a CTVolume, got {type(volume).__name__}")
    lo, hi = positive(min_diameter_mm, "min_diameter_mm"), positive(max_diameter_mm, "max_diameter_mm")
    if int(margin_voxels) != margin_voxels or margin_voxels < 0:
        raise ValueError(f"margin_voxels: expected an integer >= 0, got {margin_voxels!r}")
    data = np.asarray(volume.data, dtype=np.float64)
    bg = float(np.median(data))
    top = float(np.percentile(data, 99.99))
    thr = bg + 0.5 * (top - bg) if threshold is None else float(threshold)
    if not thr > bg:
        raise ValueError(f"threshold: expected a value above the background {bg:g}, got {thr:g}")
    lab, n = ndimage.label(data > thr, structure=np.ones((3, 3, 3)))
    empty = VolumeBeads(np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64), thr, bg)
    if n == 0:
        return empty
    voxel_mm3 = float(np.prod(volume.spacing))
    excess = np.clip(data - bg, 0.0, None)
    centers, dias, counts = [], [], []
    for idx, sl in enumerate(ndimage.find_objects(lab), start=1):
        m = margin_voxels
        sl = tuple(slice(max(s.start - m, 0), min(s.stop + m, dim))
                   for s, dim in zip(sl, data.shape, strict=True))
        comp = lab[sl] == idx
        region = ndimage.binary_dilation(comp, iterations=m) if m else comp
        region &= (lab[sl] == 0) | comp  # never take a neighbour's voxels
        w = np.where(region, excess[sl], 0.0)
        total = w.sum()
        core = excess[sl][comp]
        plateau = float(np.median(core[core >= np.percentile(core, 75)]))
        if total <= 0 or plateau <= 0:
            continue
        d = (6.0 * total / plateau * voxel_mm3 / np.pi) ** (1.0 / 3.0)
        if not lo <= d <= hi:
            continue
        kk, jj, ii = np.nonzero(w)
        ww = w[kk, jj, ii]
        ijk = np.array([ii @ ww, jj @ ww, kk @ ww]) / total + [s.start for s in sl[::-1]]
        centers.append(volume.index_to_physical(ijk))
        dias.append(d)
        counts.append(int(comp.sum()))
    if not centers:
        return empty
    order = np.argsort(-np.asarray(dias), kind="stable")
    return VolumeBeads(np.asarray(centers)[order], np.asarray(dias)[order],
                       np.asarray(counts, np.int64)[order], thr, bg)


def _snap(d: np.ndarray, nominal) -> np.ndarray:
    if nominal is None:
        return d
    nom = np.asarray(nominal, dtype=float)
    return nom[np.argmin(np.abs(d[:, None] - nom[None]), axis=1)]


def target_from_volume(volume: CTVolume, *, kind: str = "spiral", name: str = "object",
                       nominal_diameters=None, reverse: bool = False, metadata: dict | None = None,
                       **extract_options) -> CalibrationTarget:
    """A target from a micro-CT scan of the object (thesis §5.3.2).

    ``kind="spiral"``: beads are ordered along the helix axis (principal axis of the bead cloud)
    and expressed in the helix frame of :func:`core.calibration.hardware.helix_frame_from_beads` (the
    module docstring's definition); the first bead is at the end of the axis whose direction's
    largest scan component is negative (``reverse=True`` starts from the other end). Other kinds
    keep the scan's physical coordinates, ordered by
    decreasing diameter. ``nominal_diameters`` (mm) snaps each measured diameter to the nearest
    nominal size (the measured one is kept in ``metadata["measured_diameters_mm"]``).
    """
    if kind not in KINDS:
        raise ValueError(f"kind: expected one of {KINDS}, got {kind!r}")
    beads = extract_beads(volume, **extract_options)
    P, d = beads.centers, beads.diameters
    meta = dict(metadata or {})
    meta.update(source="micro-CT", threshold=beads.threshold, spacing_mm=volume.spacing.tolist())
    if kind == "spiral":
        if len(P) < 5:
            raise ValueError(f"volume: found {len(P)} beads, a helix needs at least 5")
        m = P.mean(axis=0)
        axis = np.linalg.svd(P - m)[2][0]
        axis = axis * np.sign(axis[np.argmax(np.abs(axis))]) * (-1.0 if reverse else 1.0)
        order = np.argsort((P - m) @ axis)
        P, d = P[order], d[order]
        T = helix_frame_from_beads(P)
        local = (P - T[:3, 3]) @ T[:3, :3]
        frame = _HELIX_FRAME
    else:
        if len(P) < 1:
            raise ValueError("volume: no beads found")
        local, frame = P, "physical coordinates of the CT scan (mm)"
    meta["measured_diameters_mm"] = [round(float(x), 4) for x in d]
    return CalibrationTarget(name, _ids(len(local)), local, _snap(d, nominal_diameters), kind=kind,
                             frame=frame, metadata=meta)
