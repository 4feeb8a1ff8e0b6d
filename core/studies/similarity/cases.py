"""Registration test cases for the metric studies: one bone, a reference pose, fluoroscope ROIs.

A :class:`RegistrationCase` holds everything a metric needs to score a pose: a DRR renderer for
the bone alone, the fixed ROI of each view (the tracker renders every candidate pose into the
same ROI), and the fluoroscope ROI of each view sampled at the DRR's ray positions, both as
relative fluence in [0, 1] (``fluence``) and in DRR polarity (``fluoro`` = ``-ln`` fluence, see
:func:`core.similarity.line_integral_image`). Poses are perturbed about the bone's attenuation
centroid (its projection is the bone's projected centre of mass, thesis §6.3.2).

Builders: :func:`synthetic_case` (a :func:`core.synthetic.make_foot_scene` frame: ground truth)
and :func:`wrist_case` (the real Autoscoper wrist sample: radius at the hand-found
:data:`core.samples.WRIST_RADIUS_POSE` against radiograph 0099 — a reference, not a truth).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy import ndimage
from scipy.spatial.transform import Rotation

from core.render import DRRBatch, DRRRenderer, HUTransfer
from core.render.volume import CTVolume
from core.similarity.domain import line_integral_image, sample_roi

__all__ = ["RegistrationCase", "synthetic_case", "wrist_case"]


@dataclass(frozen=True, eq=False)
class RegistrationCase:
    """One bone, its reference pose and the fluoroscope ROIs of every view.

    Attributes
    ----------
    name : str
    renderer : DRRRenderer
        Renders this bone only (volume index 0).
    pose : (4, 4) array
        Reference ``T_lab_from_bone`` (ground truth for synthetic cases).
    centre : (3,) array
        Rotation centre in the bone's frame, mm (attenuation-weighted centroid).
    roi : (n_views, 4) int array
        ``(u0, v0, w, h)`` of each view, full-resolution pixels.
    scale : float
        Full-resolution pixels per DRR pixel.
    fluence : tuple of (h, w) float32 arrays
        Flatfield-normalised fluoroscope ROI per view, [0, 1].
    fluoro : tuple of (h, w) float32 arrays
        The same in DRR polarity (``-ln`` fluence).
    mm_per_px : float
        Lab millimetres per DRR pixel at the bone centre, mean over views (converts the
        thesis' pixel translations to mm).
    truth : bool
        True when ``pose`` is the ground truth.
    masks : tuple of (h, w) bool arrays or None
        Usable fluoroscope pixels per view (the ``fluoro_mask`` of the metrics), or None = all.
    """

    name: str
    renderer: DRRRenderer
    pose: np.ndarray
    centre: np.ndarray
    roi: np.ndarray
    scale: float
    fluence: tuple[np.ndarray, ...]
    fluoro: tuple[np.ndarray, ...]
    mm_per_px: float
    truth: bool
    masks: tuple[np.ndarray, ...] | None = None

    def options(self, view: int) -> dict:
        """Domain options of ``view`` for the metrics (its ``fluoro_mask`` when there is one)."""
        return {} if self.masks is None else {"fluoro_mask": self.masks[view]}

    @property
    def n_views(self) -> int:
        return len(self.fluoro)

    def render(self, poses) -> DRRBatch:
        """DRRs of ``poses (B, 4, 4)`` in the fixed ROIs (one launch, items ordered (pose, view))."""
        P = np.asarray(poses, dtype=float).reshape(-1, 1, 4, 4)
        return self.renderer.render(P, roi=self.roi[None, :, None], scale=self.scale)

    def drrs(self, poses) -> tuple[np.ndarray, ...]:
        """Host copies of the DRRs of ``poses``: per view ``(B, h, w)``, the fluoroscope ROI's size."""
        out = self.render(poses).numpy()[:, :, 0]
        return tuple(out[:, v, : f.shape[0], : f.shape[1]].copy() for v, f in enumerate(self.fluoro))

    def perturb(self, translation_mm, rotvec=None) -> np.ndarray:
        """Poses ``(B, 4, 4)``: the reference rotated by ``rotvec`` (rad, lab axes) about the bone
        centre, then translated by ``translation_mm`` (lab, mm)."""
        t = np.atleast_2d(np.asarray(translation_mm, dtype=float))
        r = np.zeros_like(t) if rotvec is None else np.atleast_2d(np.asarray(rotvec, dtype=float))
        if t.shape[1] != 3 or r.shape != t.shape:
            raise ValueError(f"translation_mm, rotvec: expected (B, 3) arrays, got {t.shape} and {r.shape}")
        c = self.pose[:3, :3] @ self.centre + self.pose[:3, 3]
        R = Rotation.from_rotvec(r).as_matrix()
        out = np.tile(self.pose, (len(t), 1, 1))
        out[:, :3, :3] = R @ self.pose[:3, :3]
        out[:, :3, 3] = np.einsum("bij,j->bi", R, self.pose[:3, 3] - c) + c + t
        return out


def _centroid(mu: CTVolume) -> np.ndarray:
    k, j, i = np.nonzero(mu.data > 0)
    w = mu.data[k, j, i].astype(float)
    if w.sum() <= 0:
        raise ValueError(f"volume: {mu.name or 'the bone'} has no attenuation")
    return mu.index_to_physical((np.c_[i, j, k] * w[:, None]).sum(axis=0) / w.sum())


def _mm_per_px(renderer: DRRRenderer, pose: np.ndarray, centre: np.ndarray, scale: float) -> float:
    c = pose[:3, :3] @ centre + pose[:3, 3]
    vals = []
    for cam in renderer.cameras:
        _, z = cam.project(c[None], return_depth=True)
        vals.append(float(z[0]) / cam.fx * scale)
    return float(np.mean(vals))


def _build(name, renderer, mu, pose, fluence_frames, *, scale, margin, truth,
           valid: tuple[float, float] | None = None) -> RegistrationCase:
    roi = renderer.auto_roi(pose[None, None], views=range(len(renderer.cameras)), bones=[0],
                            margin=margin)[0, :, 0]
    fluence = tuple(np.clip(sample_roi(f, r, scale=scale), 0.0, 1.0) for f, r in
                    zip(fluence_frames, roi, strict=True))
    fluoro = tuple(line_integral_image(f) for f in fluence)
    masks = None
    if valid is not None:  # exclude black (outside the field) and saturated pixels and their rims
        lo, hi = valid
        masks = tuple(ndimage.binary_erosion((f > lo) & (f < hi), iterations=5, border_value=1)
                      for f in fluence)
    centre = _centroid(mu)
    return RegistrationCase(name, renderer, pose, centre, roi, float(scale), fluence, fluoro,
                            _mm_per_px(renderer, pose, centre, scale), truth, masks)


def synthetic_case(*, bone: str = "talus", pixels: int = 256, seed: int = 0, frame: int = 0,
                   spacing: float = 0.5, scale: float = 1.0, margin: int = 8,
                   noise: bool = True, device: str | None = None) -> RegistrationCase:
    """A bone of a :func:`core.synthetic.make_foot_scene` frame, at its true pose.

    The frame goes through the realistic image chain of
    :meth:`core.synthetic.ImagingModel.fluoroscope` (quantum noise, PSF, veiling glare, roll-off,
    12-bit camera; ``noise=False`` switches the noise off) without intensifier distortion (its
    correction is a separate step); the whole foot, soft tissue, walkway and beads are in the
    image, only ``bone`` is in the DRR. ``pixels`` is the detector width (256 → 1.17 mm pixels).
    """
    from core.synthetic import BONE_NAMES, ImagingModel, make_foot_scene

    if bone not in BONE_NAMES:
        raise ValueError(f"bone: expected one of {BONE_NAMES}, got {bone!r}")
    scene = make_foot_scene(n_frames=frame + 1, pixels=pixels, seed=seed, spacing=spacing,
                            imaging="ideal", tissue_spacing=max(2.0, spacing))
    models = []
    for cam in scene.rig:
        m = ImagingModel.fluoroscope(cam, distortion=None)
        if not noise:
            m = replace(m, photons_per_pixel=None, read_noise_dn=0.0)
        models.append(m)
    scene = replace(scene, imaging=tuple(models))
    b = scene.names.index(bone)
    frames = scene.render_frame(frame)
    fluence = [m.to_float(f) for m, f in zip(scene.imaging, frames, strict=True)]
    mu = scene.bones[b].to_attenuation(scene.bone_transfer)
    renderer = DRRRenderer(scene.rig, [mu], device=device)
    return _build(f"synthetic-{bone}", renderer, mu, scene.poses(frame)[b], fluence, scale=scale,
                  margin=margin, truth=True)


def wrist_case(data_dir: str | Path, *, bone: str = "radius", frame_index: int = 1, scale: float = 2.0,
               margin: int = 24, threshold_hu: float = 300.0, device: str | None = None) -> RegistrationCase:
    """The radius of the Autoscoper wrist sample at the hand-found pose, against radiograph 0099.

    The 8-bit radiographs are not flatfield-corrected: grey level / 255 stands in for relative
    fluence. Pixels outside the intensifier field (fluence < 0.12) or saturated (≥ 0.995, air
    beside the forearm), and 5 px around them, are masked out. The DRR uses the preview's transfer
    (bone above ``threshold_hu``), 0.5 mm steps, and ``scale`` (2 → one DRR pixel per 2 × 2
    radiograph pixels).
    """
    from core.samples import WRIST_RADIUS_POSE, load_wrist_sample

    if bone != "radius":
        raise ValueError(f"bone: only the radius has a reference pose (WRIST_RADIUS_POSE), got {bone!r}")
    sample = load_wrist_sample(data_dir)
    mu = sample.volumes[bone].to_attenuation(HUTransfer(threshold=float(threshold_hu)))
    renderer = DRRRenderer(sample.rig, [mu], device=device, step_mm=0.5)
    frames = [sample.frame(v, frame_index).astype(np.float32) / 255.0 for v in range(len(sample.rig))]
    return _build("wrist-radius", renderer, mu, np.array(WRIST_RADIUS_POSE), frames, scale=scale,
                  margin=margin, truth=False, valid=(0.12, 0.995))
