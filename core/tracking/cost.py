"""The registration cost: a weighted combination of similarity metrics over a population of poses.

Search space
------------
Optimisers see ``x = (tx, ty, tz, rx, ry, rz)`` in **millimetres and degrees** (so that one unit
of translation and one of rotation are of comparable effect on a bone of a few cm), relative to
a *base pose* (the initial guess) and about the bone's centroid ``c``: ``x`` maps to the pose
:func:`core.geometry.transforms.pose_from_params` ``((t, radians(r)), center=c, base=base)``
— the centre moves by ``t`` in the lab and the bone turns by the rotation vector ``r`` (lab axes)
about its centre. ``x = 0`` is the base pose.

Cost
----
For metric terms ``k`` with weights ``w_k`` (scores of :mod:`core.similarity`, larger = more
similar, 1 = identical)::

    cost(x) = Σ_k w_k (1 - score_k(x)) / Σ_k w_k,     score_k = mean over views of the metric

so the cost is 0 for a perfect match and the optimiser minimises it. :data:`DEFAULT_TERMS` is
gradient correlation with the fluoroscope ROI *and* every DRR smoothed by the same Gaussian of
σ = 0.3 mm at the bone (``fluoro_sigma_mm = drr_sigma_mm = 0.3``: about 1 px of a 1024² view of
the foot, turned into pixels per pyramid level and dropped below a quarter pixel, so coarse
views are not blurred further; the DRR blur runs on the device, :class:`core.similarity.
BatchedMetric`). The response study of :mod:`core.similarity` ranked smoothed GC first
(monotonic, no false optima within the capture range, robust to quantum noise). Smoothing only
the fluoroscope moves the optimum (on ideal 128² test views it made a 2 mm / 2° offset score
better than the truth); smoothing both alike keeps it and still averages the noise. A converged
registration's optimum does not move with more optimiser work (CMA-ES population 64 plus
quadratic refinement, or the exact trilinear DRR, 1024² synthetic trial): the remaining error
is the cost's, set by noise, blur and the residual distortion. NCC, GI, GO, GD, SID, MI and NMI
can be combined. The ``gc`` term's ``rim_sigmas`` (:data:`RIM_OPTION`, off by default) takes a band
at the intensifier's round field's rim out of the domain (:func:`rim_radius`, :func:`rim_masks`):
on the acceptance trial it moved the tibia's translation error from 1.73 to 1.67× its bound and its
rotation from 1.85 to 1.89× (one NVIDIA H100, :mod:`core.studies.tracking.tibia_cost`).

Hot path (DESIGN.md)
--------------------
One call ``cost(X (B, 6))`` = one :meth:`core.render.DRRRenderer.render` launch of every pose ×
both views at the fixed ROI and pyramid scale (the renderer reuses its buffers), one
:meth:`core.similarity.BatchedMetric.evaluate` per metric term (a single term by default: one
launch, a CUDA graph on the GPU) and one copy of ``B (1 + n_views)`` floats to the host. The
ROI of each view is fixed for the whole optimisation (the bone's projected box at the base pose
grown by the search range), so the fluoroscope ROIs are sampled, smoothed and uploaded once per
frame and pyramid level.

Fluoroscope frames enter as flatfield-normalised fluence in [0, 1] and are compared in DRR
polarity (``-ln I/I0``, :func:`core.similarity.line_integral_image`). At a pyramid level of
``scale`` s > 1 the frame is low-passed with a Gaussian of σ = 0.5 s px before it is sampled at
the DRR's ray positions (one ray per s × s block), so its noise is not aliased. The search regions
(:func:`search_roi`, :func:`snap_roi`) and :class:`OutsideViewError` live in
:mod:`core.tracking.roi` (importable from here too).
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..geometry.transforms import pose_from_params
from .noise import NOISE_OPTION, FrameNoise, noise_maps
from .roi import OutsideViewError, pixel_mm, search_roi, snap_roi

__all__ = ["DEFAULT_TERMS", "NOISE_OPTION", "RIM_OPTION", "CostTimer", "FrameImages", "MetricTerm",
           "OutsideViewError", "RegistrationCost", "fluoro_rois", "metric_terms", "mm_per_pixel",
           "noise_maps", "prepare_frame", "rim_masks", "rim_radius", "search_roi", "snap_roi"]


@dataclass(frozen=True)
class MetricTerm:
    """One metric of the cost: ``kind`` (a :data:`core.similarity.BATCHED_KINDS` name), its
    ``weight`` (> 0) and ``options`` for :class:`core.similarity.BatchedMetric` (``fluoro_sigma``,
    ``drr_sigma``, ``dilate``, ``threshold``, ``operator``, ``bins``…; ``fluoro_sigma_mm`` and
    ``drr_sigma_mm`` give the smoothing in mm at the bone instead of DRR pixels; ``gc`` with
    ``components=True`` correlates the gradient components instead of the magnitudes, also in the
    Gauss–Newton engine; ``gc`` of the magnitudes with ``noise_correction=True`` takes the frame's
    quantum noise out of the fluoroscope's magnitudes at full resolution, :func:`noise_maps`;
    ``rim_sigmas`` = k > 0 takes the usable pixels within ``k σ + 2`` px of a black pixel — outside
    the intensifier's round field — out of the domain at full resolution, σ the fluoroscope's
    smoothing in pixels, :data:`RIM_OPTION`)."""

    kind: str
    weight: float = 1.0
    options: Mapping = field(default_factory=dict)

    def __post_init__(self) -> None:
        from ..similarity import BATCHED_KINDS

        if self.kind not in BATCHED_KINDS:
            raise ValueError(f"kind: expected one of {BATCHED_KINDS}, got {self.kind!r}")
        if not (np.isfinite(self.weight) and self.weight > 0):
            raise ValueError(f"weight: expected a positive weight, got {self.weight!r}")
        object.__setattr__(self, "options", dict(self.options))

    def to_dict(self) -> dict:
        return {"kind": self.kind, "weight": self.weight, "options": dict(self.options)}


_MM_KEYS = {"fluoro_sigma_mm": "fluoro_sigma", "drr_sigma_mm": "drr_sigma"}


def mm_per_pixel(renderer, pose: np.ndarray, center: np.ndarray, views: Sequence[int] | None = None) -> float:
    """Mean size (mm) of a full-resolution pixel at the bone's centre over ``views`` (the depth of
    :meth:`core.geometry.Camera.project` over ``max(fx, fy)``; :func:`core.tracking.roi.pixel_mm`)."""
    return pixel_mm(renderer, pose, center, views)


def _in_pixels(options, px_mm: float | None) -> dict:
    """Metric options with ``*_sigma_mm`` (mm at the bone) turned into DRR-pixel σ; below a
    quarter pixel the smoothing is dropped (coarse views: nothing to smooth at that scale)."""
    out = dict(options)
    for k_mm, k in _MM_KEYS.items():
        if k_mm in out:
            if k in out:
                raise ValueError(f"metric options: give {k} or {k_mm}, not both")
            sig = float(out.pop(k_mm)) / px_mm
            out[k] = sig if sig >= 0.25 else 0.0
    return out


#: The metric term's option of the band at the round field's rim (:class:`MetricTerm`): the usable
#: pixels within ``rim_sigmas · σ + 2`` px (σ the fluoroscope's smoothing in full-resolution pixels;
#: the smoothing's reach, the gradient's pixel and one more; rounded up to a whole pixel,
#: :func:`rim_radius`) of a black pixel leave the domain, so
#: that the black field's line integral (8.3 against the bones' and tissue's 1-3), which the
#: smoothing and the gradient spread over the 3 px the usable mask's erosion leaves, is not
#: correlated with the DRR. Black: at or below a quarter of the valid range's low end
#: (:data:`core.tracking.likelihood_rim.BLACK_FRACTION`). None or 0: no band.
RIM_OPTION = "rim_sigmas"
#: the band's pixels beyond ``rim_sigmas · σ``: the gradient's 3 × 3 stencil and one more
RIM_EXTRA_PX = 2.0
_BLACK_FRACTION = 0.25  # = core.tracking.likelihood_rim.BLACK_FRACTION (that module imports this one)


def rim_radius(rim_sigmas, fluoro_sigma_px: float, scale: float = 1.0) -> float:
    """The band's radius in full-resolution pixels (:data:`RIM_OPTION`) for a fluoroscope
    smoothing of ``fluoro_sigma_px``: ``rim_sigmas · σ + 2`` rounded up to a whole pixel (σ follows
    the bone's pixel size from frame to frame; a whole radius keeps the engine's band from frame to
    frame, :class:`core.tracking.likelihood_rim.RimCache`, where a fractional one built a new
    whole-image band almost every frame: the tibia tracked alone took 20-21 ms per frame instead
    of 3.5 on one H100); 0 (no band) without the option, without smoothing (the gradient's pixel
    lies within the mask's erosion) or at a pyramid level (``scale`` != 1)."""
    k = float(rim_sigmas or 0.0)
    if k <= 0 or scale != 1.0 or fluoro_sigma_px <= 0:
        return 0.0
    return float(math.ceil(k * float(fluoro_sigma_px) + RIM_EXTRA_PX - 1e-9))


def rim_masks(frame, views, roi, masks: list, radius_px: float) -> list:
    """``masks`` (the usable pixels of ``views``' full-resolution regions ``roi``, top-left) with the
    pixels within ``radius_px`` of a black pixel of ``frame`` False (OpenCV's 5×5 Euclidean
    distance, as :func:`core.tracking.likelihood_rim.rim_keep`); a view with no black pixel that
    near, or whose every pixel is that near, is left as it is."""
    import cv2

    if not isinstance(frame, FrameImages) or radius_px <= 0:
        return masks
    thr = _BLACK_FRACTION * (frame._valid[0] if frame._valid is not None else 0.02)
    r = math.ceil(radius_px)
    out = list(masks)
    for i, v in enumerate(views):
        u0, v0, w, h = (int(a) for a in roi[i])
        H, W = frame.shapes[v]
        R0, R1, C0, C1 = max(v0 - r, 0), min(v0 + h + r, H), max(u0 - r, 0), min(u0 + w + r, W)
        dark = frame._fluence[v][R0:R1, C0:C1] <= thr
        if not dark.any():
            continue
        keep = cv2.distanceTransform((~dark).view(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5) > radius_px
        keep = keep[v0 - R0:v0 - R0 + h, u0 - C0:u0 - C0 + w]
        if keep.all() or not keep.any():
            continue
        out[i] = np.ascontiguousarray(out[i] & keep[:out[i].shape[0], :out[i].shape[1]])
    return out


_LI_FLOOR = np.float32(1.0 / 4096)  # core.similarity.line_integral_image's default floor
_CROSS = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], dtype=np.uint8)

DEFAULT_TERMS = (MetricTerm("gc", 1.0, {"fluoro_sigma_mm": 0.3, "drr_sigma_mm": 0.3}),)

def metric_terms(name: str = "magnitudes") -> tuple[MetricTerm, ...]:
    """The cost terms of a similarity's name (``talus track``/``talus batch --metric``, the
    window's Similarity): :data:`DEFAULT_TERMS` for ``"magnitudes"`` (or ``"gc"``, its older
    name), the same with ``components=True`` on the ``gc`` terms for ``"components"``, and one
    term of any other :mod:`core.similarity` batched kind (e.g. ``"ncc"``)."""
    from dataclasses import replace

    if name in ("magnitudes", "gc"):
        return DEFAULT_TERMS
    if name == "components":
        return tuple(replace(t, options={**t.options, "components": True}) if t.kind == "gc" else t
                     for t in DEFAULT_TERMS)
    return (MetricTerm(name),)


class FrameImages(FrameNoise):
    """One biplane frame ready for registration.

    Holds each view's flatfield-normalised fluence and computes what registration compares —
    the line-integral image ``-ln(I/I0)`` (DRR polarity, :func:`core.similarity.line_integral_image`)
    and the usable-pixel mask — only for the regions asked for (:meth:`region`): a bone's search
    region is a small part of a 1024² frame. Build it with :func:`prepare_frame`.

    Attributes
    ----------
    images : tuple of (H, W) float32
        Whole-image line integrals per view (computed on first access).
    masks : tuple of (H, W) bool or None
        Whole-image usable pixels per view (False outside the intensifier's field, on
        black/saturated pixels and ``erode_px`` around them); None = all usable.
    """

    def __init__(self, fluence, masks, valid_range, erode_px: int) -> None:
        self._fluence = tuple(fluence)
        self._given = tuple(masks)
        self._valid = valid_range
        self._erode = int(erode_px)
        self._whole: tuple | None = None
        self._regions: dict = {}  # the last few regions asked for (pyramid levels, rounds of joint tracking)
        self._noise: dict = {}  # noise energies estimated (noise_energy)

    @property
    def n_views(self) -> int:
        return len(self._fluence)

    @property
    def shapes(self) -> tuple[tuple[int, int], ...]:
        return tuple(f.shape for f in self._fluence)

    def region(self, view: int, rows: slice, cols: slice) -> tuple[np.ndarray, np.ndarray | None]:
        """``(line_integral (h, w) float32, mask (h, w) bool or None)`` of ``view`` over
        ``[rows, cols]`` (slices with explicit, in-range bounds); the same values as the whole
        image's, cut out (the erosion of the mask sees ``erode_px`` pixels beyond the region)."""
        key = (int(view), rows.start, rows.stop, cols.start, cols.stop)
        hit = self._regions.get(key)
        if hit is not None:  # the same region again: the same (read-only) arrays
            return hit
        out = self._region(view, rows, cols)
        for a in out:
            if a is not None:
                a.flags.writeable = False
        if len(self._regions) >= 16:
            self._regions.pop(next(iter(self._regions)))
        self._regions[key] = out
        return out

    def _region(self, view: int, rows: slice, cols: slice) -> tuple[np.ndarray, np.ndarray | None]:
        import cv2

        img = self._fluence[view]
        H, W = img.shape
        r0, r1, c0, c1 = rows.start, rows.stop, cols.start, cols.stop
        if not (0 <= r0 < r1 <= H and 0 <= c0 < c1 <= W):
            raise ValueError(f"rows, cols: expected a non-empty region inside {H}x{W}, got {rows}, {cols}")
        # = line_integral_image(clip(sub, 0, 1)) in float32 (prepare_frame checked the frame is finite)
        li = np.clip(img[r0:r1, c0:c1], _LI_FLOOR, 1.0).astype(np.float32, copy=False)
        np.log(li, out=li)
        np.negative(li, out=li)
        mask = None
        if self._valid is not None:
            p = self._erode
            R0, R1, C0, C1 = max(r0 - p, 0), min(r1 + p, H), max(c0 - p, 0), min(c1 + p, W)
            sub = img[R0:R1, C0:C1]
            lo, hi = self._valid
            valid = (sub > lo) & (sub < hi)
            if p and not valid.all():  # = ndimage.binary_erosion(valid, iterations=p, border_value=1)
                valid = cv2.erode(valid.view(np.uint8), _CROSS, iterations=p, borderType=cv2.BORDER_CONSTANT,
                                  borderValue=1).view(bool)
            mask = valid[r0 - R0:r1 - R0, c0 - C0:c1 - C0]
        given = self._given[view]
        if given is not None:
            g = given[r0:r1, c0:c1]
            mask = g if mask is None else mask & g
        return li, mask

    def _all(self) -> tuple:
        if self._whole is None:
            out = [self.region(v, slice(0, f.shape[0]), slice(0, f.shape[1]))
                   for v, f in enumerate(self._fluence)]
            self._whole = (tuple(o[0] for o in out), tuple(o[1] for o in out))
        return self._whole

    @property
    def images(self) -> tuple[np.ndarray, ...]:
        return self._all()[0]

    @property
    def masks(self) -> tuple[np.ndarray | None, ...]:
        return self._all()[1]


def prepare_frame(fluence, *, masks=None, valid_range: tuple[float, float] | None = (0.02, 0.999),
                  erode_px: int = 3) -> FrameImages:
    """:class:`FrameImages` from flatfield-normalised frames (one ``(H, W)`` per view, in [0, 1]).

    ``valid_range`` (relative fluence) marks pixels outside it — black (outside the round field,
    collimator) or saturated — as unusable, together with ``erode_px`` pixels around them;
    ``masks`` (True = usable) are combined with that. ``valid_range=None`` keeps every pixel.
    The line integrals and masks are computed lazily, per search region.
    """
    views = [np.asarray(f, dtype=np.float32) for f in fluence]
    if not views or any(v.ndim != 2 for v in views):
        raise ValueError("fluence: expected one 2-D flatfield-normalised image per view")
    given = [None] * len(views) if masks is None else list(masks)
    if len(given) != len(views):
        raise ValueError(f"masks: expected {len(views)} masks (one per view) or None")
    for v, (img, m) in enumerate(zip(views, given, strict=True)):
        if img.size and not (math.isfinite(float(img.min())) and math.isfinite(float(img.max()))):
            raise ValueError(f"fluence[{v}]: contains NaN or infinite pixels")
        if m is not None:
            m = np.asarray(m, dtype=bool)
            if m.shape != img.shape:
                raise ValueError(f"masks[{v}]: expected shape {img.shape}, got {m.shape}")
            given[v] = m
    if valid_range is not None:
        lo, hi = (float(a) for a in valid_range)
        if not lo < hi:
            raise ValueError(f"valid_range: expected (low, high) with low < high, got {valid_range!r}")
        valid_range = (lo, hi)
    if isinstance(erode_px, bool) or int(erode_px) != erode_px or erode_px < 0:
        raise ValueError(f"erode_px: expected an integer >= 0, got {erode_px!r}")
    return FrameImages(views, given, valid_range, int(erode_px))


def padded_region(frame: FrameImages, view: int, roi_row, scale: float):
    """The fluoroscope region of ``view`` around the full-resolution ``roi_row`` ``(u0, v0, w, h)``,
    padded for a pyramid level of ``scale`` (a multiple of 8 pixels, the same region at scales 1
    and 2: one read) and clipped to the image: ``(region, usable mask or None, (u0, v0, w, h)
    within the region)``. Raises :class:`OutsideViewError` when the region is empty or outside."""
    u0, v0, w, h = (int(a) for a in roi_row)
    if w <= 0 or h <= 0:
        raise OutsideViewError(f"roi: the search region of view {view} is empty (outside the image)")
    H_img, W_img = frame.shapes[view]
    pad = 8 * math.ceil((math.ceil(2 * float(scale)) + 2) / 8)
    ys, xs = max(v0 - pad, 0), max(u0 - pad, 0)
    ye, xe = min(v0 + h + pad, H_img), min(u0 + w + pad, W_img)
    if ye <= ys or xe <= xs:
        raise OutsideViewError(f"roi: the search region of view {view} lies outside its image")
    sub, m = frame.region(view, slice(ys, ye), slice(xs, xe))
    return sub, m, np.array([u0 - xs, v0 - ys, w, h])


def fluoro_rois(renderer, frame: FrameImages, *, views: Sequence[int], roi, scale: float = 1.0,
                others=None) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The fluoroscope's search regions of ``views`` in DRR polarity at pyramid ``scale``, as the
    cost compares them (low-passed and sampled at the DRR's rays for ``scale`` > 1), with their
    usable-pixel masks, and the DRRs of ``others`` (``(poses (n, 4, 4), bones (n,))`` at fixed
    poses) subtracted. ``roi``: ``(n_views, 4)`` full-resolution ``(u0, v0, w, h)``.
    Raises :class:`OutsideViewError` when a region is empty or has no usable pixel."""
    from scipy import ndimage

    from ..similarity import sample_roi

    s = float(scale)
    roi = np.asarray(roi, dtype=np.int64).reshape(len(views), 4)
    rois, masks = [], []
    for i, v in enumerate(views):
        sub, m, r = padded_region(frame, v, roi[i], s)
        w, h = int(r[2]), int(r[3])
        if s > 1:
            sub = ndimage.gaussian_filter(sub, 0.5 * s, mode="nearest")
        if s == 1 and r[0] + w <= sub.shape[1] and r[1] + h <= sub.shape[0]:
            rois.append(np.ascontiguousarray(sub[r[1]:r[1] + h, r[0]:r[0] + w], dtype=np.float32))
            mm = None if m is None else m[r[1]:r[1] + h, r[0]:r[0] + w]
        else:
            rois.append(sample_roi(sub, r, scale=s))
            mm = None if m is None else sample_roi(m.astype(np.float32), r, scale=s) > 0.999
        masks.append(np.ones(rois[-1].shape, bool) if mm is None else np.ascontiguousarray(mm))
        if not masks[-1].any():
            raise OutsideViewError(f"frame: no usable fluoroscope pixel in the search region of view {v}")
    if others is not None:
        poses_o, bones_o = others
        poses_o = np.asarray(poses_o, dtype=float)
        if len(bones_o):
            batch = renderer.render(poses_o[None], views=tuple(views), bones=list(bones_o),
                                    roi=roi[None, :, None, :], scale=s)
            bg = batch.numpy()[0].sum(axis=1)  # (n_views, H, W)
            rois = [r - bg[i, : r.shape[0], : r.shape[1]] for i, r in enumerate(rois)]
    return rois, masks


@dataclass
class CostTimer:
    """Accumulated wall time (s) of the cost's stages and its evaluation counts.

    ``render``: host tables + DRR launch (+ the device's rendering time when the cost runs with
    ``profile=True``, which synchronises after the launch); ``metric``: metric launches, the
    device's remaining work and the copy to the host; ``host``: parameters → poses and the
    weighted sum. ``calls`` launches rendered ``evaluations`` poses.
    """

    render: float = 0.0
    metric: float = 0.0
    host: float = 0.0
    calls: int = 0
    evaluations: int = 0

    def total(self) -> float:
        return self.render + self.metric + self.host

    def to_dict(self) -> dict:
        return {"render_s": self.render, "metric_s": self.metric, "host_s": self.host,
                "calls": self.calls, "evaluations": self.evaluations}


class RegistrationCost:
    """``cost(X (B, 6)) -> (B,)`` for one bone in one frame at one pyramid scale.

    Parameters
    ----------
    renderer : core.render.DRRRenderer
        Holds the bone volumes (HU→μ already applied) and the cameras.
    frame : FrameImages
    bone : int
        Volume index of the bone in ``renderer``.
    base_pose : (4, 4) array
        ``T_lab_from_bone`` at ``x = 0`` (the initial guess).
    center : (3,) array
        Rotation centre in the bone's CT frame, mm.
    roi : (n_views, 4) int array
        Fixed ROIs (:func:`search_roi`).
    scale : float
        Full-resolution pixels per DRR pixel (pyramid level).
    terms : sequence of MetricTerm
    views : sequence of int, optional
        Cameras used (default all).
    others : (poses (n, 4, 4), bones (n,)) , optional
        Other bones at fixed poses whose DRRs are subtracted from the fluoroscope ROIs (their
        projections accounted for when bones overlap).
    profile : bool
        Synchronise after each render to time DRR and metric separately (slower; benchmarks).
    """

    def __init__(self, renderer, frame: FrameImages, *, bone: int, base_pose, center, roi,
                 scale: float = 1.0, terms: Sequence[MetricTerm] = DEFAULT_TERMS,
                 views: Sequence[int] | None = None, others=None, profile: bool = False) -> None:
        from ..similarity import BatchedMetric

        self.renderer = renderer
        self.views = tuple(range(frame.n_views)) if views is None else tuple(int(v) for v in views)
        if frame.n_views != len(renderer.cameras):
            raise ValueError(f"frame: {frame.n_views} views, the renderer has "
                             f"{len(renderer.cameras)} cameras")
        self.bone = int(bone)
        self.base = np.asarray(base_pose, dtype=float)
        self.center = np.asarray(center, dtype=float)
        self.scale = float(scale)
        if not (np.isfinite(self.scale) and self.scale > 0):
            raise ValueError(f"scale: expected a positive pyramid scale, got {scale!r}")
        self.terms = tuple(terms)
        if not self.terms:
            raise ValueError("terms: expected at least one MetricTerm")
        self.roi = np.asarray(roi, dtype=np.int64).reshape(len(self.views), 4)
        self.profile = bool(profile)
        self.timer = CostTimer()
        rois, masks = fluoro_rois(renderer, frame, views=self.views, roi=self.roi, scale=self.scale,
                                  others=others)
        s = self.scale
        self.fluoro_rois = tuple(rois)
        self.fluoro_masks = tuple(masks)
        dev = str(renderer.device)
        px_mm = None
        if any(k in t.options for t in self.terms for k in _MM_KEYS):
            px_mm = s * mm_per_pixel(renderer, self.base, self.center, self.views)
        self.metrics = []
        raw = None
        for t in self.terms:
            opts = _in_pixels(t.options, px_mm)
            rim = rim_radius(opts.pop(RIM_OPTION, None), float(opts.get("fluoro_sigma", 0.0)), s)
            fm = (rim_masks(frame, self.views, self.roi, list(self.fluoro_masks), rim) if rim > 0
                  else self.fluoro_masks)
            if opts.pop(NOISE_OPTION, False) and s == 1.0 and isinstance(frame, FrameImages):
                if raw is None:  # the regions before the neighbours are subtracted: their fluence
                    raw = rois if others is None else fluoro_rois(renderer, frame, views=self.views,
                                                                  roi=self.roi, scale=s)[0]
                sig = float(opts.get("fluoro_sigma", 0.0))
                opts["noise_energy"] = noise_maps(frame, self.views, raw, sig, opts.get("operator", "sobel"))
            self.metrics.append(BatchedMetric(t.kind, list(self.fluoro_rois), device=dev,
                                              fluoro_masks=list(fm), **opts))
        w = np.array([t.weight for t in self.terms], dtype=float)
        self._w = w / w.sum()
        self._roi_arg = self.roi[None, :, None, :]

    # ------------------------------------------------------------------ mapping
    def poses(self, X) -> np.ndarray:
        """``(B, 4, 4)`` poses of parameter rows ``X (B, 6)`` (mm, degrees)."""
        X = np.atleast_2d(np.asarray(X, dtype=float))
        if X.ndim != 2 or X.shape[1] != 6:
            raise ValueError(f"X: expected shape (B, 6) (mm, degrees), got {np.shape(X)}")
        p = np.concatenate([X[:, :3], np.radians(X[:, 3:])], axis=1)
        return pose_from_params(p, center=self.center, base=self.base)

    def params(self, pose) -> np.ndarray:
        """``(6,)`` x (mm, degrees) of a pose (inverse of :meth:`poses`)."""
        from ..geometry.transforms import params_from_pose

        p = params_from_pose(np.asarray(pose, float), center=self.center, base=self.base)
        return np.concatenate([p[:3], np.degrees(p[3:])])

    # ------------------------------------------------------------------ evaluation
    def scores(self, X, *, views: bool = False):
        """``(B, n_terms)`` similarity scores (mean over views) of each term; with ``views=True``
        also ``(B, n_terms, n_views)`` per-view scores (same launch)."""
        import warp as wp

        t0 = time.perf_counter()
        P = self.poses(X)
        t1 = time.perf_counter()
        batch = self.renderer.render(P[:, None], views=self.views, bones=[self.bone],
                                     roi=self._roi_arg, scale=self.scale)
        if self.profile:
            wp.synchronize_device(self.renderer.device)
        t2 = time.perf_counter()
        res = [m.evaluate(batch) for m in self.metrics]
        out = np.stack([r.pose for r in res], axis=1)
        t3 = time.perf_counter()
        tm = self.timer
        tm.host += t1 - t0
        tm.render += t2 - t1
        tm.metric += t3 - t2
        tm.calls += 1
        tm.evaluations += len(P)
        if views:
            return out, np.stack([r.item[:, :, 0] for r in res], axis=1)
        return out

    def __call__(self, X) -> np.ndarray:
        """``(B,)`` costs ``Σ w_k (1 - score_k)`` (weights normalised to sum 1)."""
        s = self.scores(X)
        t0 = time.perf_counter()
        c = (1.0 - s) @ self._w
        c = np.where(np.isfinite(c), c, 2.0)
        self.timer.host += time.perf_counter() - t0
        return c

    def score(self, x) -> float:
        """Weighted mean similarity (1 - cost) at one parameter vector."""
        return float(1.0 - self(np.asarray(x, float)[None])[0])

    def score_and_views(self, x) -> tuple[float, np.ndarray]:
        """Weighted mean similarity at ``x`` and the weighted per-view similarity
        ``(n_views,)``, from one launch."""
        s, v = self.scores(np.asarray(x, float)[None], views=True)
        tot = float(1.0 - np.nan_to_num((1.0 - s[0]) @ self._w, nan=2.0))
        return tot, np.nan_to_num(v[0].T @ self._w, nan=-1.0)
