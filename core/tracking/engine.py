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

Noise correction (the ``gc`` term's ``noise_correction`` option, set by
:class:`core.tracking.register.RegistrationOptions`): quantum noise adds its expected squared
gradient ``E = E₁ / F`` to the fluoroscope's squared gradient magnitudes, more where fewer photons
arrive, and the correlation of magnitudes follows that pedestal
(:mod:`core.studies.tracking.gc_noise_bias`). At full resolution the fluoroscope's gradients are
shortened on the device to ``sqrt(max(|g|² - E, 0))``
(:func:`~core.tracking.engine_kernels.fluoro_gradient_kernel`), ``E₁`` per view estimated from
the frame itself (:meth:`core.tracking.cost.FrameImages.noise_energy`), ``F`` the fluence of the
smoothed region before any neighbour is subtracted (joint tracking: two more blur passes at the
frame's set-up; each round's, since the smoothing follows the pose's pixel size). The moments and
scores are unchanged; the same values as :func:`core.similarity.gradient_correlation` with
``noise_energy`` and the host cost's (:func:`core.tracking.cost.noise_maps`). Pyramid levels are
left as they are.

Band at the round field's rim (the term's ``rim_sigmas``, :data:`core.tracking.cost.RIM_OPTION`, off
by default): at full resolution, once the regions are prepared, the usable pixels within
``⌈rim_sigmas · σ + 2⌉`` px of a black pixel (σ the fluoroscope's smoothing in pixels) are taken out
of Ω (:func:`~core.tracking.engine_frames.apply_rim_band`: the band of
:func:`core.tracking.likelihood_rim.rim_keep`, kept between frames in the engine's
:class:`~core.tracking.likelihood_rim.RimCache`), so that the black field's line integral, which the
smoothing and the gradient spread past the mask's erosion, is not correlated with the DRR; a region
no black pixel comes near is left as it is, to the bit (:mod:`core.studies.tracking.tibia_cost`).

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
the ROIs' size rounded up to 32 pixels) and, on CUDA, one graph per batch size from frame to
frame: the copy of the parameter rows from pinned memory, their DRR item table computed on the
device (:mod:`core.tracking.engine_render`), the DRR launch, the metric (2 blur passes, scores,
moments) and the copies of the results to pinned host memory — a step is one graph launch and
one synchronisation, its host part the 6 × 6 arithmetic. At full resolution
:meth:`~GaussNewtonCost.set_frame` uploads each view's region of the fluence as it is (grown by
the usable-pixel mask's erosion) and
:func:`~core.tracking.engine_kernels.fluoro_roi_kernel` computes the line integrals, the eroded
mask and their statistics on the device (the same values as
:meth:`core.tracking.cost.FrameImages.region`); they stay there, and the same regions of the same
frame again (the next round of joint tracking, which subtracts the neighbours at new poses) are
neither uploaded nor prepared again. At a pyramid level the host prepares them
(:func:`~core.tracking.engine_frames.pyramid_rois`). Smoothing and gradients run on the device.
:func:`engine_cost` caches one per (renderer, bone, views, scale, terms). A frame's set-up has no
wait of its own (the usable pixels counted on the device are checked at the first step's
synchronisation), its launches recorded once, and the same set-up again (restarts) is kept.
:meth:`~GaussNewtonCost.submit` and :meth:`~GaussNewtonCost.collect` split an evaluation
from its wait, so several bones' steps (:mod:`core.tracking.joint`), or several searches of one
bone on :meth:`~GaussNewtonCost.sibling` costs, are in flight together. Kernels:
:mod:`core.tracking.engine_kernels`; the metric pipeline: :mod:`core.tracking.engine_pipeline`;
the device preparation of the regions:
:mod:`core.tracking.engine_frames`; the search and the Gauss–Newton algebra:
:mod:`core.tracking.engine_search`; the buffers per output size, recorded launches, pinned uploads,
blur taps and siblings: :mod:`core.tracking.engine_buffers`.
"""

from __future__ import annotations

import math
import time
import weakref
from collections.abc import Sequence

import numpy as np
import warp as wp

from ..similarity import _kernels as K
from .cost import (
    NOISE_OPTION,
    RIM_OPTION,
    CostTimer,
    FrameImages,
    MetricTerm,
    OutsideViewError,
    fluoro_rois,
    mm_per_pixel,
    rim_radius,
)
from .engine_buffers import _BUFFER_SETS, _Buffers, _EngineBuffers, copy_array  # noqa: F401 (re-exported)
from .engine_frames import apply_rim_band, host_stage, pyramid_rois, stage, staged_shapes
from .engine_kernels import (
    N_POSES,
    fluoro_gradient_kernel,
    subtract_kernel,
)
from .engine_pipeline import _Pipeline
from .engine_render import DeviceRender, host_poses, render_items
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
            "components", NOISE_OPTION, RIM_OPTION)
_N = N_POSES  # poses per step: the centre and ±h_k e_k


class GaussNewtonCost(_EngineBuffers):
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
                 term: MetricTerm, block_dim: int = 128, chunk: int | None = None) -> None:
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
        self.noise = bool(term.options.get(NOISE_OPTION, False))
        if self.noise and (term.kind != "gc" or self.components):
            raise ValueError(f"term: the {NOISE_OPTION} option is the gc metric's of the gradient magnitudes")
        self.rim_sigmas = float(term.options.get(RIM_OPTION) or 0.0)  # the band at the rim (0: none)
        self._rim_dev = None
        self._rim_on = 0.0  # the band's radius (px) the usable-pixel masks on the device hold
        self.threshold = float(term.options.get("threshold", 0.0))
        self.dilate = int(term.options.get("dilate", 0))
        ku, kv = derivative_kernels(term.options.get("operator", "sobel"))
        if ku.shape != (3, 3):
            raise ValueError("term: the Gauss-Newton engine needs a 3x3 gradient operator")
        self._ku_np, self._kv_np = ku, kv
        self._ku = wp.mat33f(*ku.astype(np.float32).ravel())
        self._kv = wp.mat33f(*kv.astype(np.float32).ravel())
        # pixels per block of the statistics and moments passes: on the H100, 1024 (2-4 times the
        # blocks of 4096) took the talus' moments pass from 0.19 to 0.09 ms per 13-pose step
        self.block_dim = int(block_dim)
        self.chunk = int(chunk) if chunk is not None else (1024 if renderer.device.is_cuda else 4096)
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
        self._e1 = wp.zeros(nv, dtype=wp.float32, device=dev)  # the noise correction's E1 per view
        self._e1_last: np.ndarray | None = None
        self._f_sig = 0.0  # the fluoroscope's smoothing at this frame's pixel size (px)
        self._fblur = None
        self._fblur_taps: np.ndarray | None = None
        self._taps_cache: dict = {}
        pinned = dev.is_cuda
        self._host_hw = wp.zeros(nv, dtype=wp.vec2i, device="cpu", pinned=pinned)
        self._host_hw_np = self._host_hw.numpy()  # the pinned buffers' numpy views, made once
        # device preparation of the fluoroscope ROIs (set_frame): per-view geometry, sums, counts
        self._host_info = wp.zeros((nv, 8), dtype=wp.int32, device="cpu", pinned=pinned)
        self._host_info_np = self._host_info.numpy()
        self._info = wp.zeros((nv, 8), dtype=wp.int32, device=dev)
        self._msum = wp.zeros((nv, 2), dtype=wp.float64, device=dev)
        self._count = wp.zeros(nv, dtype=wp.int32, device=dev)
        self._host_count = wp.zeros(nv, dtype=wp.int32, device="cpu", pinned=pinned)
        self._host_count_np = self._host_count.numpy()
        self._stage_src = None
        self._stage_done = None  # (the frame, the inputs) of the regions and statistics on the device (stage)
        self._stage_checked = False  # their usable pixels counted and found
        self._pinned: dict = {}  # pinned buffers of small uploads and their numpy views (_put)
        self._tables: dict = {}  # DRR item tables per (batch, bones) (_render)
        self._staged_last = None  # (the frame, its regions) now on the device
        self.device_frames = True  # full-resolution ROIs prepared on the device (set_frame)
        self._count_pending = False  # the device's usable-pixel count not checked yet (set_frame)
        self._pending = None  # the evaluation submitted and not collected yet (submit)
        self._prepared = None  # (the frame, the inputs) of the regions now prepared (set_frame)
        self._unsynced = False  # a preparation's copies from pinned memory may still be in flight
        self._cmds: dict = {}  # recorded launches of the frame preparation (_launch)
        self._cmd_last: dict = {}  # name -> (dim, inputs, launch) of its last launch (_launch's shortcut)
        self._hw_last = self._info_last = None  # the ROI sizes and staging geometry on the device
        self._siblings: dict = {}  # costs sharing this one's prepared regions (sibling)
        # CUDA: the poses' item tables on the device, each step one graph (engine_render)
        self._dev_render = DeviceRender(self) if dev.is_cuda else None
        self.base = self.center = self.roi = None

    @property
    def renderer(self):
        r = self._renderer()
        if r is None:
            raise RuntimeError("renderer: the renderer of this cost no longer exists")
        return r

    # ------------------------------------------------------------------ per frame
    def set_frame(self, frame: FrameImages, *, base_pose, center, roi, others=None,
                  px_mm: float | None = None) -> None:
        """Take the fluoroscope ROIs ``roi (n_views, 4)`` of ``frame`` (the DRRs of ``others``
        subtracted, see :func:`core.tracking.cost.fluoro_rois`) and the parameterisation
        ``base_pose``, ``center`` for the next evaluations. The ROIs are smoothed and
        differentiated on the device; at full resolution (``scale`` 1, the ROIs inside the
        images) the line integrals and usable-pixel masks are computed there too, from the
        fluence uploaded as it is (:attr:`device_frames`). Raises
        :class:`~core.tracking.cost.OutsideViewError` like :class:`RegistrationCost` (for the
        device preparation's count of usable pixels: the next evaluation raises it). The same
        inputs again (frame, ROIs, pose, centre, neighbours; e.g. the restarts of
        :func:`core.tracking.verify.verify_start`) keep the regions prepared last time.
        ``px_mm``: :func:`~core.tracking.cost.mm_per_pixel` of ``base_pose``, ``center`` and this
        cost's views when the caller has it (:func:`core.tracking.register.register`), else
        computed here."""
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
        if others is None or not len(others[1]):  # (one bone: the preparation as one CUDA graph, PREP_GRAPH)
            self._record()
        try:
            self._prepare_frame(frame, key, others, px_mm)
        except BaseException:
            self._flush()  # (what was asked for before the error, run as it would have been)
            raise
        self._replay()
        self.timer.host += time.perf_counter() - t0

    def _prepare_frame(self, frame, key, others, px_mm) -> None:
        """:meth:`set_frame`'s preparation of a new frame or new inputs (its operations recorded where
        :data:`~core.tracking.engine_buffers.PREP_GRAPH` is set)."""
        if self._dev_render is not None:
            self._dev_render.upload(self.base, self.center, self.roi, copy=self._copy)
        if px_mm is None:
            px_mm = mm_per_pixel(self.renderer, self.base, self.center, self.views)
        px_mm = self.scale * px_mm
        taps, ftaps = self._taps(px_mm)
        staged = staged_shapes(self, frame) if self.device_frames else None
        if staged is None:
            self._flush()  # (the host's preparation: its copies as they are asked for)
            if self.scale > 1 and isinstance(frame, FrameImages):  # a pyramid level
                rois, masks = pyramid_rois(frame, self.views, self.roi, self.scale)
            else:
                rois, masks = fluoro_rois(self.renderer, frame, views=self.views, roi=self.roi,
                                          scale=self.scale)
            shapes = [r.shape for r in rois]
        else:
            shapes = [(r[3], r[2]) for r in self.roi.tolist()]
        need = (max(sh[0] for sh in shapes), max(sh[1] for sh in shapes))
        same_taps = (taps is None and self._blur_taps is None) or (
            taps is not None and self._blur_taps is not None and len(taps) == len(self._blur_taps))
        # the buffers' size depends on this frame alone (32-pixel steps), so a frame is scored
        # alike whatever came before it (a resumed run repeats an uninterrupted one)
        new = tuple(int(math.ceil(n / 32.0) * 32) for n in need)
        if new != self._cap or not same_taps:
            self._allocate(new, taps)
        if taps is not None and taps is not self._blur_taps and not np.array_equal(taps, self._blur_taps):
            self._put("blur", self._blur, taps)
        self._blur_taps = self._bufs.blur_taps = taps
        Hc, Wc = self._cap
        nv = self.n_views
        dev = self.device
        hw_now = tuple(tuple(int(a) for a in sh) for sh in shapes)
        if hw_now != self._hw_last:
            self._host_hw_np[:] = np.array(shapes, dtype=np.int32)
            self._copy(self._ref_hw, self._host_hw)
            self._hw_last = hw_now
        elif self._rec is not None:  # (recorded: copied again, the same values: one graph either way)
            self._copy(self._ref_hw, self._host_hw)
        rim = rim_radius(self.rim_sigmas, self._f_sig, self.scale)
        if staged is None:
            host_stage(self, rois, masks)
            ran = False
            fresh = True
        else:
            if self._rim_on != rim:  # the masks on the device hold another band: prepared again
                self._stage_done = None
            ran = fresh = stage(self, frame, staged)
        if fresh:  # the masks as prepared, then the band at the rim (none where no black pixel is near)
            if rim > 0:
                apply_rim_band(self, frame, rim)
            self._rim_on = rim
        src = self._raw0  # the regions' line integrals as prepared
        if others is not None and len(others[1]):  # subtracted on the device, at the fixed output size
            self._flush()
            nb = len(others[1])
            images = self._render(np.asarray(others[0], dtype=float)[None], tuple(int(b) for b in others[1]))
            self._launch("subtract", subtract_kernel, (nv, Hc, Wc), [self._raw0, images, nb, self._raw])
            src = self._raw
        if ftaps is not None:
            if self._fblur is None or len(self._fblur) != len(ftaps):
                self._fblur = wp.array(ftaps, dtype=wp.float32, device=dev)
                self._fblur_taps = ftaps
            elif ftaps is not self._fblur_taps and not np.array_equal(ftaps, self._fblur_taps):
                self._put("fblur", self._fblur, ftaps)
                self._fblur_taps = ftaps
            for a, dst, axis in ((src, self._ftmp, 1), (self._ftmp, self._fluoro, 0)):
                self._launch(f"blur{axis}", K.blur_kernel, (nv, Hc, Wc),
                             [a, dst, self._fblur, self._ref_hw, nv, axis])
        else:
            self._copy(self._fluoro, src)
        ys = self._fluoro
        noise = int(self.noise and self.scale == 1.0 and isinstance(frame, FrameImages))
        if noise:
            ys = self._noise_setup(frame, ftaps, src)
        self._launch("gradient", fluoro_gradient_kernel, (nv, Hc, Wc),
                     [self._fluoro, self._ref_hw, self._fmax, self._ku, self._kv, noise, self._e1, ys,
                      self._fgrad])
        # the usable pixels counted on the device are checked at the first evaluation's
        # synchronisation (no wait of its own)
        self._count_pending = ran
        self._prepared = (weakref.ref(frame), key)
        self._unsynced = True

    def _noise_setup(self, frame: FrameImages, ftaps, src) -> wp.array:
        """The noise correction's inputs of this frame (full resolution): each view's ``E₁``
        estimated from the frame (:meth:`~core.tracking.cost.FrameImages.noise_energy`) uploaded,
        and the smoothed line integrals before the neighbours are subtracted — the smoothed
        fluoroscope itself when none are, else the unsubtracted regions smoothed alike."""
        op = self.term.options.get("operator", "sobel")
        e1 = np.array([frame.noise_energy(v, self._f_sig, op) for v in self.views], np.float32)
        if self._e1_last is None or not np.array_equal(e1, self._e1_last):
            self._put("e1", self._e1, e1)
            self._e1_last = e1
        if src is self._raw0:
            return self._fluoro
        if ftaps is None:  # no smoothing: the unsubtracted regions themselves
            return self._raw0
        nv = self.n_views
        Hc, Wc = self._cap
        b = self._bufs
        if b.ys is None:
            b.ys = wp.zeros((nv, Hc, Wc), dtype=wp.float32, device=self.device)
        for a, dst, axis in ((self._raw0, self._ftmp, 1), (self._ftmp, b.ys, 0)):
            self._launch(f"noise_blur{axis}", K.blur_kernel, (nv, Hc, Wc),
                         [a, dst, self._fblur, self._ref_hw, nv, axis])
        return b.ys

    def _check_count(self) -> None:
        """Raise OutsideViewError when the device preparation found no usable pixel in a view
        (its count copied to the host before the last synchronisation)."""
        self._count_pending = False
        for i, n in enumerate(self._host_count_np):
            if n <= 0:
                self._prepared = None
                self._stage_done = None
                raise OutsideViewError(f"frame: no usable fluoroscope pixel in the search region of view "
                                       f"{self.views[i]}")
        self._stage_checked = True  # the regions now on the device may be kept (stage)

    # ------------------------------------------------------------------ mapping
    def poses(self, X) -> np.ndarray:
        """``(B, 4, 4)`` poses of parameter rows ``X (B, 6)`` (mm, degrees): those of
        :func:`core.geometry.transforms.pose_from_params` (Rodrigues' formula here, without its
        checks: the optimiser's own parameters)."""
        X = np.atleast_2d(np.asarray(X, dtype=float))
        return host_poses(X, self.base, self.center)

    # ------------------------------------------------------------------ evaluation
    _render = render_items  # the DRRs of given poses (the neighbours subtracted; the CPU's steps)

    def submit(self, X: np.ndarray) -> None:
        """Enqueue the evaluation of parameter rows ``X (B, 6)`` (one DRR launch, one metric
        graph; on CUDA one graph for both, the poses' table computed on the device) without
        waiting for it: :meth:`collect` gives its results once the device has synchronised
        (:mod:`core.tracking.joint` submits several bones' steps, then waits once)."""
        if self._cap is None:
            raise RuntimeError("set_frame: no frame set")
        t0 = time.perf_counter()
        B = len(X)
        pipe = self._pipes.get(B)
        if self._dev_render is not None:
            if pipe is None:
                pipe = self._pipes[B] = _Pipeline(self, None, B, render=self._dev_render)
            pipe.x_np[:] = X
            t1 = t2 = time.perf_counter()
            if self.profile:  # the DRRs timed apart
                pipe.enqueue_render()
                wp.synchronize_device(self.device)
                t2 = time.perf_counter()
                pipe.enqueue_metric()
            else:
                pipe.launch()
        else:
            P = self.poses(X)
            t1 = time.perf_counter()
            images = self._render(P[:, None], (self.bone,))
            t2 = time.perf_counter()
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
        out = out.astype(np.float64)
        if not math.isfinite(np.add.reduce(out)):  # (float32 values: a finite sum is all finite)
            out = np.nan_to_num(out, nan=-1.0)
        scores = out[:B]
        views = out[B:].reshape(B, self.n_views)
        tm.metric += time.perf_counter() - t0
        return 1.0 - scores, views, gn

    def _evaluate(self, X: np.ndarray, idle=None):
        self.submit(X)
        if idle is not None:  # host work that needs nothing of this evaluation, while the device works
            idle()
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

    def step(self, x, h, idle=None) -> GaussNewtonStep:
        """Evaluate the 13-pose design about ``x`` with half-steps ``h`` (6,): costs, gradient and
        Gauss–Newton Hessian (one DRR launch, one metric graph). ``idle``: a callable run once the
        evaluation is enqueued, before the wait for the device (host work that needs nothing of it;
        on the CPU, where the launches run as they are enqueued, after them)."""
        x = np.asarray(x, dtype=float)
        h = np.asarray(h, dtype=float)
        return self.newton(x, h, self._evaluate(step_design(x, h), idle))


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
