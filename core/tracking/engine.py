"""Gauss–Newton registration engine: the cost's gradient and curvature from 13 poses per step.

The similarity of :data:`core.tracking.cost.DEFAULT_TERMS` (gradient correlation, GC) and NCC
are Pearson correlations ``r = cov(a, b) / sqrt(var a · var b)`` over the domain Ω of the
fluoroscope quantity ``a`` (GC: the gradient magnitude of the smoothed fluoroscope ROI; NCC: its
intensity) and the DRR quantity ``b(x)`` at pose parameters ``x`` (mm, degrees; see
:mod:`core.tracking.cost`). With ``â``, ``b̂`` the centred, unit-length vectors,
``1 - r = ½ ‖â - b̂(x)‖²``: a least-squares problem in the pixels, solved by Gauss–Newton /
Levenberg–Marquardt steps.

One step (:meth:`GaussNewtonCost.step`)
---------------------------------------
One DRR launch renders the 13 poses ``x``, ``x ± h_k e_k`` (both views); the DRRs are smoothed on
the device as the metric smooths them; one pass over the pixels of Ω (that of the centre DRR)
accumulates, per view, the 9 × 9 moment matrix of ``z = (1, a, b(x), δ_1 … δ_6)`` with
``δ_k = b(x + h_k e_k) - b(x - h_k e_k)`` (per-pixel central differences: ``∂b/∂x_k ≈ δ_k / 2h_k``).
From it, in float64 on the host (6 × 6 arithmetic)::

    ∂r/∂x_k = cov(a, D_k) / sqrt(var a var b) - r cov(b, D_k) / var b          D_k = δ_k / 2h_k
    (JᵀJ)_kl = [cov(D_k, D_l) - cov(b, D_k) cov(b, D_l) / var b] / var b

(covariances as centred sums over Ω). The cost ``Σ_v w_v (1 - r_v)`` (mean over views) has the
gradient ``g = -Σ w_v ∂r_v/∂x`` and the Gauss–Newton Hessian ``H = Σ w_v (JᵀJ)_v`` — the whole
6 × 6 curvature, couplings included, from 13 poses (a fitted quadratic needs ≥ 28). The same
launch also scores the 13 poses with the ordinary cost (per-pose Ω, as
:class:`~core.tracking.cost.RegistrationCost` scores them), so a step needs no other launch.

Search (:func:`gauss_newton_search`)
------------------------------------
Levenberg–Marquardt: the step ``d = -(H + λ diag H)⁻¹ g`` (clipped to a trust box and the
search box) is taken when the cost at the new centre is not worse than the old one by more than
the cost's roughness; otherwise λ grows ×10 and the step is recomputed from the old centre's
``g``, ``H`` (no extra launch). Converged (``"tol_x"``) when every coordinate of a step from an
accepted centre is below ``tol_x``; the result is that centre plus the step (the model's
minimum). A fixed point of the iteration is a stationary point of the cost: the gradient is the
cost's own (central differences of the images), only the curvature is approximated.

The last step's 13 cost values, fitted by ``c0 + gᵀd + ½ dᵀHd`` with ``H`` fixed (7 free
coefficients, 6 residual degrees of freedom), give the cost's roughness ``σ_c`` at the scale of
``h``; :func:`core.tracking.confidence.confidence_from_fit` turns ``(H, σ_c)`` into the pose
uncertainty as it does for the quadratic-model search's fit.

Speed design
------------
:class:`GaussNewtonCost` keeps its device buffers, the DRR output buffer (a fixed output size,
:meth:`core.render.DRRRenderer.render` ``out_shape``, the ROIs' size rounded up to 32 pixels)
and, on CUDA, one graph of the metric pipeline (2 blur passes, scores, moments, copies to pinned
host memory) from frame to frame. At full resolution :meth:`~GaussNewtonCost.set_frame` uploads
each view's region of the fluence as it is (grown by the usable-pixel mask's erosion) and
:func:`~core.tracking.engine_kernels.fluoro_roi_kernel` computes the line integrals, the eroded
mask and their statistics on the device (the same values as
:meth:`core.tracking.cost.FrameImages.region`; the regions stay on the device for the next round
of joint tracking in the same frame); at a pyramid level the host prepares them
(:func:`~core.tracking.engine_frames.pyramid_rois`). Smoothing and
gradients run on the device. The engine fills the DRR item table of its own (rigid) poses itself
and launches the renderer's recorded launch. :func:`engine_cost` caches one per (renderer, bone,
views, scale, terms). A step is one DRR launch, one graph launch and one synchronisation; a
frame's set-up none of its own (the usable pixels counted on the device are checked at the first
step's synchronisation), its launches recorded once, and the same set-up again (restarts) is
kept. :meth:`~GaussNewtonCost.submit` and :meth:`~GaussNewtonCost.collect` split an evaluation
from its wait, so several bones' steps (:mod:`core.tracking.joint`), or several searches of one
bone on :meth:`~GaussNewtonCost.sibling` costs, are in flight together. Kernels:
:mod:`core.tracking.engine_kernels`; the metric pipeline: :mod:`core.tracking.engine_pipeline`;
the device preparation of the regions:
:mod:`core.tracking.engine_frames`; the search and the Gauss–Newton algebra:
:mod:`core.tracking.engine_search`.
"""

from __future__ import annotations

import math
import time
import weakref
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import warp as wp

from ..render._kernels import ITEM_COLS
from ..similarity import _kernels as K
from .cost import CostTimer, FrameImages, MetricTerm, OutsideViewError, _in_pixels, fluoro_rois, mm_per_pixel
from .engine_frames import pyramid_rois, stage, staged_shapes
from .engine_kernels import (
    N_POSES,
    fluoro_gradient_kernel,
    subtract_kernel,
)
from .engine_pipeline import _Pipeline
from .engine_search import (
    GaussNewtonFit,
    GaussNewtonStep,
    gauss_newton_search,
    moments_to_newton,
    step_design,
)

__all__ = ["ENGINE_KINDS", "GaussNewtonCost", "GaussNewtonFit", "GaussNewtonStep", "engine_cost",
           "gauss_newton_search", "moments_to_newton", "step_design", "supports"]

#: Similarity kinds the engine handles (Pearson correlations of a per-pixel quantity).
ENGINE_KINDS = ("gc", "ncc")
_MODE = {"ncc": 0, "gc": 1}
_OPTIONS = ("fluoro_sigma", "drr_sigma", "fluoro_sigma_mm", "drr_sigma_mm", "threshold", "dilate", "operator",
            "components")
_N = N_POSES  # poses per step: the centre and ±h_k e_k

def _poses(X: np.ndarray, base: np.ndarray, center: np.ndarray) -> np.ndarray:
    """:func:`core.geometry.transforms.pose_from_params` of ``(mm, degrees)`` rows ``X``."""
    r = np.radians(X[:, 3:])
    th = np.linalg.norm(r, axis=1)
    small = th < 1e-8
    k = r / np.where(small, 1.0, th)[:, None]
    Kx = np.zeros((len(X), 3, 3))
    Kx[:, 0, 1], Kx[:, 0, 2], Kx[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    Kx[:, 1, 0], Kx[:, 2, 0], Kx[:, 2, 1] = k[:, 2], -k[:, 1], k[:, 0]
    s, c = np.sin(th)[:, None, None], (1.0 - np.cos(th))[:, None, None]
    Rd = np.eye(3) + s * Kx + c * (Kx @ Kx)
    Rd[small] = np.eye(3)
    Rb, tb = base[:3, :3], base[:3, 3]
    c_lab = Rb @ center + tb
    R = Rd @ Rb
    out = np.zeros((len(X), 4, 4))
    out[:, :3, :3] = R
    out[:, :3, 3] = c_lab + X[:, :3] - R @ center
    out[:, 3, 3] = 1.0
    return out


#: Buffer sets (output sizes) an engine keeps with their pipelines (:meth:`GaussNewtonCost._allocate`):
#: over the 100-frame walking trial at 1024² the tracking frames' search regions take 2-4 sizes per
#: bone (32-pixel steps), the first frame and its restarts two more.
_BUFFER_SETS = 6


@dataclass(eq=False)
class _Buffers:
    """The fluoroscope buffers of one output size of an engine, the pipelines recorded on them
    (its own by batch size, and its siblings') and the host preparation's pinned buffers."""

    cap: tuple
    raw: object
    ftmp: object
    fluoro: object
    fgrad: object
    fmask: object
    blur: object
    blur_taps: object
    pipes: dict = field(default_factory=dict)
    sibling_pipes: dict = field(default_factory=dict)
    host_raw_wp: object = None
    host_mask_wp: object = None


class GaussNewtonCost:
    """The registration cost of one bone at one pyramid scale with Gauss–Newton steps (module
    docs), reusable from frame to frame.

    Parameters
    ----------
    renderer : core.render.DRRRenderer
    bone : int
        Volume index in ``renderer``.
    views : sequence of int
    scale : float
        Full-resolution pixels per DRR pixel.
    term : MetricTerm
        A single ``gc`` or ``ncc`` term (options as :class:`core.similarity.BatchedMetric`'s
        domain and smoothing options; ``*_sigma_mm`` in mm at the bone; ``components`` for GC of
        the gradient components: two statistics and two moment passes, each of the correlations
        ``r_u``, ``r_v`` a least-squares problem of its own, their mean the score).

    :meth:`set_frame` must be called before the first evaluation of each frame.
    """

    def __init__(self, renderer, *, bone: int, views: Sequence[int], scale: float = 1.0,
                 term: MetricTerm, block_dim: int = 128, chunk: int = 4096) -> None:
        if term.kind not in ENGINE_KINDS:
            raise ValueError(f"term: the Gauss-Newton engine handles {ENGINE_KINDS}, got {term.kind!r}")
        bad = set(term.options) - set(_OPTIONS)
        if bad:
            raise ValueError(f"term: options {sorted(bad)} are not supported by the Gauss-Newton engine")
        from ..imaging.edges import derivative_kernels

        self._renderer = weakref.ref(renderer)  # the cache of engine_cost is keyed by the renderer
        self.device = renderer.device
        self.bone = int(bone)
        self.views = tuple(int(v) for v in views)
        self.n_views = len(self.views)
        self.scale = float(scale)
        self.term = term
        self.kind = term.kind
        self.mode = _MODE[term.kind]
        self.components = bool(term.options.get("components", False))
        if self.components and term.kind != "gc":
            raise ValueError(f"term: only the gc metric has a component form, not {term.kind!r}")
        self.threshold = float(term.options.get("threshold", 0.0))
        self.dilate = int(term.options.get("dilate", 0))
        ku, kv = derivative_kernels(term.options.get("operator", "sobel"))
        if ku.shape != (3, 3):
            raise ValueError("term: the Gauss-Newton engine needs a 3x3 gradient operator")
        self._ku_np, self._kv_np = ku, kv
        self._ku = wp.mat33f(*ku.astype(np.float32).ravel())
        self._kv = wp.mat33f(*kv.astype(np.float32).ravel())
        self.block_dim, self.chunk = int(block_dim), int(chunk)
        self.timer = CostTimer()
        self.profile = False  # synchronise after each render (time DRR and metric apart)
        self.batches: dict[int, int] = {}  # launches per batch size since the timer was reset
        self._cap: tuple[int, int] | None = None  # (H, W) DRR pixels
        self._blur = None
        self._blur_taps: np.ndarray | None = None
        self._pipes: dict[int, _Pipeline] = {}
        self._bufs: _Buffers | None = None  # the buffers in use (one of _buf_sets)
        self._buf_sets: dict = {}  # (output size, blur taps) -> _Buffers, least recently used first
        dev = self.device
        nv = self.n_views
        self._weights = wp.array(np.full(nv, 1.0, np.float32), dtype=wp.float32, device=dev)
        self._ref_hw = wp.zeros(nv, dtype=wp.vec2i, device=dev)
        self._fshift = wp.zeros(nv, dtype=wp.float32, device=dev)
        self._fmax = wp.zeros(nv, dtype=wp.float32, device=dev)
        self._fblur = None
        self._fblur_taps: np.ndarray | None = None
        self._taps_cache: dict = {}
        pinned = dev.is_cuda
        self._host_hw = wp.zeros(nv, dtype=wp.vec2i, device="cpu", pinned=pinned)
        # device preparation of the fluoroscope ROIs (set_frame): per-view geometry, sums, counts
        self._host_info = wp.zeros((nv, 8), dtype=wp.int32, device="cpu", pinned=pinned)
        self._info = wp.zeros((nv, 8), dtype=wp.int32, device=dev)
        self._msum = wp.zeros((nv, 2), dtype=wp.float64, device=dev)
        self._count = wp.zeros(nv, dtype=wp.int32, device=dev)
        self._host_count = wp.zeros(nv, dtype=wp.int32, device="cpu", pinned=pinned)
        self._stage_src = None
        self._tables: dict = {}  # DRR item tables per (batch, bones) (_render)
        self._staged_last = None  # (the frame, its regions) now on the device
        self.device_frames = True  # full-resolution ROIs prepared on the device (set_frame)
        self._count_pending = False  # the device's usable-pixel count not checked yet (set_frame)
        self._pending = None  # the evaluation submitted and not collected yet (submit)
        self._prepared = None  # (the frame, the inputs) of the regions now prepared (set_frame)
        self._unsynced = False  # a preparation's copies from pinned memory may still be in flight
        self._cmds: dict = {}  # recorded launches of the frame preparation (_launch)
        self._hw_last = self._info_last = None  # the ROI sizes and staging geometry on the device
        self._siblings: dict = {}  # costs sharing this one's prepared regions (sibling)
        self.base = self.center = self.roi = None

    @property
    def renderer(self):
        r = self._renderer()
        if r is None:
            raise RuntimeError("renderer: the renderer of this cost no longer exists")
        return r

    # ------------------------------------------------------------------ per frame
    def set_frame(self, frame: FrameImages, *, base_pose, center, roi, others=None) -> None:
        """Take the fluoroscope ROIs ``roi (n_views, 4)`` of ``frame`` (the DRRs of ``others``
        subtracted, see :func:`core.tracking.cost.fluoro_rois`) and the parameterisation
        ``base_pose``, ``center`` for the next evaluations. The ROIs are smoothed and
        differentiated on the device; at full resolution (``scale`` 1, the ROIs inside the
        images) the line integrals and usable-pixel masks are computed there too, from the
        fluence uploaded as it is (:attr:`device_frames`). Raises
        :class:`~core.tracking.cost.OutsideViewError` like :class:`RegistrationCost` (for the
        device preparation's count of usable pixels: the next evaluation raises it). The same
        inputs again (frame, ROIs, pose, centre, neighbours; e.g. the restarts of
        :func:`core.tracking.verify.verify_start`) keep the regions prepared last time."""
        t0 = time.perf_counter()
        self.base = np.asarray(base_pose, dtype=float)
        self.center = np.asarray(center, dtype=float)
        self.roi = np.asarray(roi, dtype=np.int64).reshape(self.n_views, 4)
        key = (self.roi.tobytes(), self.base.tobytes(), self.center.tobytes(), bool(self.device_frames),
               None if others is None else (np.asarray(others[0], float).tobytes(), tuple(others[1])))
        last = self._prepared
        if last is not None and last[0]() is frame and last[1] == key:
            return
        self._prepared = None
        if self._unsynced and self.device.is_cuda:  # the last preparation's copies from pinned memory
            wp.synchronize_device(self.device)
        px_mm = self.scale * mm_per_pixel(self.renderer, self.base, self.center, self.views)
        taps, ftaps = self._taps(px_mm)
        staged = staged_shapes(self, frame) if self.device_frames else None
        if staged is None:
            if self.scale > 1 and isinstance(frame, FrameImages):  # a pyramid level
                rois, masks = pyramid_rois(frame, self.views, self.roi, self.scale)
            else:
                rois, masks = fluoro_rois(self.renderer, frame, views=self.views, roi=self.roi,
                                          scale=self.scale)
            shapes = [r.shape for r in rois]
        else:
            shapes = [(int(r[3]), int(r[2])) for r in self.roi]
        need = (max(sh[0] for sh in shapes), max(sh[1] for sh in shapes))
        same_taps = (taps is None and self._blur_taps is None) or (
            taps is not None and self._blur_taps is not None and len(taps) == len(self._blur_taps))
        # the buffers' size depends on this frame alone (32-pixel steps), so a frame is scored
        # alike whatever came before it (a resumed run repeats an uninterrupted one)
        new = tuple(int(math.ceil(n / 32.0) * 32) for n in need)
        if new != self._cap or not same_taps:
            self._allocate(new, taps)
        if taps is not None and not np.array_equal(taps, self._blur_taps):
            self._blur.assign(taps)
        self._blur_taps = self._bufs.blur_taps = taps
        Hc, Wc = self._cap
        nv = self.n_views
        dev = self.device
        hw_now = tuple(tuple(int(a) for a in sh) for sh in shapes)
        if hw_now != self._hw_last:
            self._host_hw.numpy()[:] = np.array(shapes, dtype=np.int32)
            wp.copy(self._ref_hw, self._host_hw)
            self._hw_last = hw_now
        if staged is None:
            if self._host_raw_wp is None:
                pinned = dev.is_cuda
                self._host_raw_wp = wp.zeros((nv, Hc, Wc), dtype=wp.float32, device="cpu", pinned=pinned)
                self._host_mask_wp = wp.zeros((nv, Hc, Wc), dtype=wp.uint8, device="cpu", pinned=pinned)
            raw, fm = self._host_raw_wp.numpy(), self._host_mask_wp.numpy()
            shift = np.zeros(nv, np.float32)
            fmax = np.zeros(nv, np.float32)
            for i, (f, m) in enumerate(zip(rois, masks, strict=True)):
                h, w = f.shape
                raw[i, :h, :w] = f
                raw[i, h:] = 0.0
                raw[i, :h, w:] = 0.0
                fm[i, :h, :w] = m
                fm[i, h:] = 0
                fm[i, :h, w:] = 0
                if self.mode == 0:  # the intensities' mean (the Pearson scores do not depend on it)
                    shift[i] = float(f[m].mean()) if m.any() else 0.0
                fmax[i] = max(float(f.max()), -float(f.min()))
            wp.copy(self._raw, self._host_raw_wp)
            wp.copy(self._fmask, self._host_mask_wp)
            self._fshift.assign(shift)
            self._fmax.assign(fmax)
        else:
            stage(self, frame, staged)
        if others is not None and len(others[1]):  # subtracted on the device, at the fixed output size
            nb = len(others[1])
            images = self._render(np.asarray(others[0], dtype=float)[None], tuple(int(b) for b in others[1]))
            self._launch("subtract", subtract_kernel, (nv, Hc, Wc), [images, nb, self._raw])
        if ftaps is not None:
            if self._fblur is None or len(self._fblur) != len(ftaps):
                self._fblur = wp.array(ftaps, dtype=wp.float32, device=dev)
                self._fblur_taps = ftaps
            elif not np.array_equal(ftaps, self._fblur_taps):
                self._fblur.assign(ftaps)
                self._fblur_taps = ftaps
            for src, dst, axis in ((self._raw, self._ftmp, 1), (self._ftmp, self._fluoro, 0)):
                self._launch(f"blur{axis}", K.blur_kernel, (nv, Hc, Wc),
                             [src, dst, self._fblur, self._ref_hw, nv, axis])
        else:
            wp.copy(self._fluoro, self._raw)
        self._launch("gradient", fluoro_gradient_kernel, (nv, Hc, Wc),
                     [self._fluoro, self._ref_hw, self._fmax, self._ku, self._kv, self._fgrad])
        # the usable pixels counted on the device are checked at the first evaluation's
        # synchronisation (no wait of its own)
        self._count_pending = staged is not None
        self._prepared = (weakref.ref(frame), key)
        self._unsynced = True
        self.timer.host += time.perf_counter() - t0

    def _launch(self, name: str, kernel, dim: tuple, inputs: list) -> None:
        """Launch ``kernel`` through a recorded launch, kept while its dimensions, arrays and
        values stay the same (the frame preparation's launches from frame to frame)."""
        key = (name, dim, tuple((a.ptr, a.shape) if isinstance(a, wp.array)
                                else a if isinstance(a, (int, float)) else id(a) for a in inputs))
        cmd = self._cmds.get(key)
        if cmd is None:  # kept per buffer set too (the arrays' addresses are in the key)
            cmd = wp.launch(kernel, dim=dim, inputs=inputs, device=self.device, record_cmd=True)
            if len(self._cmds) >= 8 * _BUFFER_SETS:
                self._cmds.pop(next(iter(self._cmds)))
            self._cmds[key] = cmd
        cmd.launch()

    def _check_count(self) -> None:
        """Raise OutsideViewError when the device preparation found no usable pixel in a view
        (its count copied to the host before the last synchronisation)."""
        self._count_pending = False
        for i, n in enumerate(self._host_count.numpy()):
            if n <= 0:
                self._prepared = None
                raise OutsideViewError(f"frame: no usable fluoroscope pixel in the search region of view "
                                       f"{self.views[i]}")

    def _taps(self, px_mm: float):
        """The DRR and fluoroscope blur taps at this pixel size (kept for the next frames)."""
        from ..similarity.batched import gaussian_weights

        opts = _in_pixels({k: v for k, v in self.term.options.items()
                           if k in ("fluoro_sigma", "drr_sigma", "fluoro_sigma_mm", "drr_sigma_mm")}, px_mm)
        key = (float(opts.get("fluoro_sigma", 0.0)), float(opts.get("drr_sigma", 0.0)))
        hit = self._taps_cache.get(key)
        if hit is None:
            f_sig, d_sig = key
            taps = gaussian_weights(d_sig) if d_sig > 0 else None
            ftaps = gaussian_weights(f_sig, truncate=4.0) if f_sig > 0 else None  # as the host preparation
            if len(self._taps_cache) >= 64:
                self._taps_cache.pop(next(iter(self._taps_cache)))
            hit = self._taps_cache[key] = (taps, ftaps)
        return hit

    def _allocate(self, cap: tuple[int, int], taps) -> None:
        """Take the buffers of this output size (and number of blur taps): those kept from an
        earlier frame (with their pipelines and CUDA graphs), else new ones. The first frame's
        wider search regions, the restarts' and the tracking frames' alternate between a few
        sizes; each change cost new pipelines (a graph capture each)."""
        if self._bufs is not None:  # keep the current ones with what was recorded on them
            self._bufs.host_raw_wp, self._bufs.host_mask_wp = self._host_raw_wp, self._host_mask_wp
        key = (cap, None if taps is None else len(taps))
        b = self._buf_sets.pop(key, None)
        if b is None:
            dev = self.device
            nv = self.n_views
            b = _Buffers(
                cap=cap, raw=wp.zeros((nv, *cap), dtype=wp.float32, device=dev),
                ftmp=wp.zeros((nv, *cap), dtype=wp.float32, device=dev),
                fluoro=wp.zeros((nv, *cap), dtype=wp.float32, device=dev),
                fgrad=wp.zeros((nv, *cap), dtype=wp.vec2f, device=dev),
                fmask=wp.zeros((nv, *cap), dtype=wp.uint8, device=dev),
                blur=None if taps is None else wp.array(taps, dtype=wp.float32, device=dev),
                blur_taps=None if taps is None else np.array(taps))
            while len(self._buf_sets) >= _BUFFER_SETS:  # the least recently used goes first
                self._buf_sets.pop(next(iter(self._buf_sets)))
        self._buf_sets[key] = b  # most recently used last
        self._bufs = b
        self._cap = cap
        self._host_raw_wp, self._host_mask_wp = b.host_raw_wp, b.host_mask_wp  # the host preparation's
        self._raw, self._ftmp, self._fluoro = b.raw, b.ftmp, b.fluoro
        self._fgrad, self._fmask = b.fgrad, b.fmask
        self._blur, self._blur_taps = b.blur, b.blur_taps
        self._pipes = b.pipes

    def sibling(self, k: int) -> GaussNewtonCost:
        """The ``k``-th sibling of this cost: its own launches, buffers of results and timer, the
        regions prepared by this cost's last :meth:`set_frame` (shared, read only), so that
        several searches of the same bone in the same frame (the restarts of
        :func:`core.tracking.verify.verify_start`) can have steps in flight together."""
        import copy

        sib = self._siblings.get(k)
        if sib is None:
            sib = copy.copy(self)
            sib._siblings, sib._pipes, sib._tables, sib._cmds = {}, {}, {}, {}
            sib._buf_sets, sib._bufs = {}, None
            sib._pending, sib._prepared, sib._unsynced = None, None, False
            self._siblings[k] = sib
        if self._count_pending:  # the usable pixels of the prepared regions, checked here once
            if self.device.is_cuda:
                wp.synchronize_device(self.device)
            self._check_count()
        # the sibling's pipelines read this cost's buffers: kept with them (new buffers, new launches)
        sib._pipes = self._bufs.sibling_pipes.setdefault(k, {})
        for a in ("base", "center", "roi", "_cap", "_raw", "_fluoro", "_fgrad", "_fmask", "_blur",
                  "_blur_taps"):
            setattr(sib, a, getattr(self, a))
        sib._count_pending = False
        sib.timer, sib.batches, sib.profile = CostTimer(), {}, self.profile
        return sib

    # ------------------------------------------------------------------ mapping
    def poses(self, X) -> np.ndarray:
        """``(B, 4, 4)`` poses of parameter rows ``X (B, 6)`` (mm, degrees): those of
        :func:`core.geometry.transforms.pose_from_params` (Rodrigues' formula here, without its
        checks: the optimiser's own parameters)."""
        X = np.atleast_2d(np.asarray(X, dtype=float))
        return _poses(X, self.base, self.center)

    # ------------------------------------------------------------------ evaluation
    def _render(self, P: np.ndarray, bones: tuple) -> wp.array:
        """The DRRs of ``bones`` at poses ``P (B, n_bones, 4, 4)`` in this cost's views and ROIs
        at its output size: the images of :meth:`core.render.DRRRenderer.render` (item
        ``(b · n_views + v) · n_bones + n``), its item table filled here without the checks of
        poses the engine made rigid itself (the inverse in closed form), one launch."""
        r = self.renderer
        B, nb = P.shape[:2]
        nv = self.n_views
        key = (B, bones)
        hit = self._tables.get(key)
        if hit is None:
            table = np.zeros((B, nv, nb, ITEM_COLS), dtype=np.float32)
            table[..., 0] = np.array(self.views, dtype=np.float32)[None, :, None]
            table[..., 1] = np.array(bones, dtype=np.float32)[None, None, :]
            if len(self._tables) >= 8:
                self._tables.pop(next(iter(self._tables)))
            # the table, the bones' index-from-physical transforms, the sources, the ROIs filled in
            hit = self._tables[key] = [table, r._T_idx[list(bones)], r._src_h[list(self.views)], None]
        table, T, S, roi_in = hit
        # index-from-physical ∘ inverse pose, the inverse in closed form: rotation M, translation tt
        M = T[:, :3, :3] @ np.swapaxes(P[..., :3, :3], -1, -2)  # (B, nb, 3, 3)
        tt = T[:, :3, 3] - (M @ P[..., :3, 3:4])[..., 0]
        table[..., 2:5] = (M @ S[:, :3].T).transpose(0, 3, 1, 2) + tt[:, None] * S[None, :, None, 3:4]
        table[..., 5:14] = M.reshape(B, 1, nb, 9)
        if roi_in is None or not np.array_equal(roi_in, self.roi):
            table[..., 14:18] = self.roi[None, :, None, :]
            hit[3] = self.roi.copy()
        Hc, Wc = self._cap
        H = max(Hc, math.ceil(int(self.roi[:, 3].max()) / self.scale))
        W = max(Wc, math.ceil(int(self.roi[:, 2].max()) / self.scale))
        return r._launch(table.reshape(B * nv * nb, ITEM_COLS), H, W, self.scale)

    def submit(self, X: np.ndarray) -> None:
        """Enqueue the evaluation of parameter rows ``X (B, 6)`` (one DRR launch, one metric
        graph) without waiting for it: :meth:`collect` gives its results once the device has
        synchronised (:mod:`core.tracking.joint` submits several bones' steps, then waits once)."""
        if self._cap is None:
            raise RuntimeError("set_frame: no frame set")
        t0 = time.perf_counter()
        P = self.poses(X)
        t1 = time.perf_counter()
        images = self._render(P[:, None], (self.bone,))
        if self.profile:
            wp.synchronize_device(self.device)
        t2 = time.perf_counter()
        B = len(P)
        pipe = self._pipes.get(B)
        if pipe is None or pipe.images.ptr != images.ptr:
            pipe = self._pipes[B] = _Pipeline(self, images, B)
        pipe.launch()
        self._pending = (pipe, B)
        tm = self.timer
        tm.host += t1 - t0
        tm.render += t2 - t1
        tm.metric += time.perf_counter() - t2

    def collect(self):
        """``(costs (B,), view scores (B, n_views), moments or None)`` of the last
        :meth:`submit`, after a synchronisation of the device."""
        t0 = time.perf_counter()
        pipe, B = self._pending
        self._pending = None
        self._unsynced = False
        out, gn = pipe.fetch()
        if self._count_pending:
            self._check_count()
        tm = self.timer
        tm.calls += 1
        tm.evaluations += B
        self.batches[B] = self.batches.get(B, 0) + 1
        scores = np.nan_to_num(out[:B].astype(np.float64), nan=-1.0)
        views = np.nan_to_num(out[B:].astype(np.float64).reshape(B, self.n_views), nan=-1.0)
        tm.metric += time.perf_counter() - t0
        return 1.0 - scores, views, gn

    def _evaluate(self, X: np.ndarray):
        self.submit(X)
        t0 = time.perf_counter()
        if self.device.is_cuda:
            wp.synchronize_device(self.device)
        self.timer.metric += time.perf_counter() - t0
        return self.collect()

    def newton(self, x, h, evaluated) -> GaussNewtonStep:
        """The :class:`GaussNewtonStep` of the 13-pose design about ``x`` from its evaluation
        (:meth:`collect`)."""
        c, v, gn = evaluated
        t0 = time.perf_counter()
        # GC of the components: the cost is the mean of the u and v correlations, so its gradient
        # and Hessian are the means over the 2 · n_views moment matrices (equal weights)
        r, g, H = moments_to_newton(gn.reshape(-1, 9, 9), h)
        if self.components:
            r = r.reshape(2, self.n_views).mean(axis=0)
        self.timer.host += time.perf_counter() - t0
        return GaussNewtonStep(np.asarray(x, dtype=float), np.asarray(h, dtype=float), c, v, g, H, r)

    def __call__(self, X) -> np.ndarray:
        """``(B,)`` costs ``1 - score`` (B = 1 or 13 poses per launch are cached; any B works)."""
        return self._evaluate(np.atleast_2d(np.asarray(X, dtype=float)))[0]

    def score_and_views(self, x) -> tuple[float, np.ndarray]:
        """Similarity at ``x`` and per view, from one launch."""
        c, v, _ = self._evaluate(np.asarray(x, dtype=float)[None])
        return float(1.0 - c[0]), v[0]

    def step(self, x, h) -> GaussNewtonStep:
        """Evaluate the 13-pose design about ``x`` with half-steps ``h`` (6,): costs, gradient and
        Gauss–Newton Hessian (one DRR launch, one metric graph)."""
        x = np.asarray(x, dtype=float)
        h = np.asarray(h, dtype=float)
        return self.newton(x, h, self._evaluate(step_design(x, h)))


_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def supports(terms: Sequence[MetricTerm]) -> bool:
    """Whether the engine can run a cost of these terms (one ``gc`` or ``ncc`` term with domain
    and smoothing options)."""
    terms = tuple(terms)
    return (len(terms) == 1 and terms[0].kind in ENGINE_KINDS
            and set(terms[0].options) <= set(_OPTIONS))


def engine_cost(renderer, *, bone: int, views: Sequence[int], scale: float,
                term: MetricTerm) -> GaussNewtonCost:
    """The :class:`GaussNewtonCost` of ``renderer`` for this bone, views, scale and term, kept for
    the renderer's lifetime (its buffers and graphs serve every later frame)."""
    per = _CACHE.setdefault(renderer, {})
    key = (int(bone), tuple(views), float(scale), term.kind, tuple(sorted(term.options.items())))
    c = per.get(key)
    if c is None:
        c = per[key] = GaussNewtonCost(renderer, bone=bone, views=views, scale=scale, term=term)
    return c
