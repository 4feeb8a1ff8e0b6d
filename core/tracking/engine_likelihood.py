"""Weighted least squares of the DRR against the line-integral image on the device: a final
refinement of a registered pose, and its confidence with correlated noise.

The model and the weights are those of :mod:`core.similarity.likelihood` (the numpy reference) and
:class:`core.tracking.likelihood_cost.LikelihoodCost` (its host refinement): per view, the search
region's line integrals ``y`` (the neighbours' DRRs at their current poses subtracted), both ``y``
and the bone's DRRs ``D`` high-passed by a Gaussian of ``highpass_px`` pixels (``D`` blurred by a
PSF first when one is given — estimated from calibration images, never the generator's), the
model ``a · D(x) + c₀ [+ c_u u + c_v v]`` with the gain and the background fitted linearly at every
pose (variable projection), the pixels weighted by their expected counts ``w`` (computed once per
frame from the unsubtracted line integrals, :func:`~core.similarity.likelihood.expected_counts`).

One Gauss–Newton step (:meth:`LikelihoodEngine.step`)
-----------------------------------------------------
One DRR launch renders the 13 poses ``x``, ``x ± h_k e_k`` (the engine's design,
:func:`core.tracking.engine_search.step_design`); two blur passes give their low-passed images;
one pass over each view's region accumulates the weighted products table
``M = Σ w z zᵀ`` of ``z = (y, D(x), δ_1 … δ_6, 1, u, v)`` (11 × 11, ``δ_k`` the central
differences of the high-passed DRRs). The host solves it in float64 with ``A = (D, 1[, u, v])``
for the step ``δ = (JᵀWJ)⁻¹ JᵀWr`` summed over views, the gain and the background projected out
(Golub–Pereyra): :func:`~core.tracking.likelihood_solve.solve_moments` (the formulas there) —
the same arithmetic as :func:`core.similarity.likelihood.wls_gauss_newton_step` without the pixels
on the host.

Extra regressors (a frame's soft tissue: :meth:`LikelihoodEngine.set_tissue`, or given images:
``set_frame(regressors=)``) widen ``z`` and ``A``, each with its own coefficient:
:mod:`core.tracking.likelihood_tissue`.

Set-up (:meth:`LikelihoodEngine.set_frame`)
-------------------------------------------
Per frame each view's region of the fluence is uploaded (or taken on the device from the rows
:func:`~core.tracking.final_stage.stage_prefetch` uploaded while the search ran, where they cover it:
:data:`~core.tracking.likelihood_frames.PREFETCH`) and its line integrals and usable pixels
made on the device (:data:`DEVICE_REGIONS`; off: cut on the host, numpy's float32 logarithm, as
first measured, and uploaded from pinned buffers, a float32 and a byte plane per view); the
neighbours' DRRs are rendered with the steps' launch, summed and subtracted on the device
(:func:`others_kernel`), and the weights and high-passes made there: no synchronisation, nothing
read back. Before, the neighbours' DRRs were read back and subtracted on the host and four float32
planes uploaded from pageable memory: 10.4 ms per bone-frame of the stage's set-up with three
bones jointly (4.6 ms for the talus alone) on one NVIDIA H200 (1024², the acceptance trial).

Confidence (:meth:`LikelihoodEngine.sandwich`)
----------------------------------------------
``χ²/dof · (JᵀWJ)⁻¹`` treats the pixels as independent and is too small with correlated
residuals; the sandwich covariance ``H⁻¹ meat H⁻¹`` estimates their autocovariance from the image
itself: :mod:`core.tracking.likelihood_confidence`.

Measured (``python -m core.studies.tracking.ml_cost --final``, the 100-frame walking trial of
``talus bench track`` at 1024², one NVIDIA H200; resources/benchmarks/tracking_likelihood_h200.json)
-------------------------------------------------------------------------------------------------
As the registrations' final stage (:mod:`core.tracking.final_stage`, high-pass 4 px): the talus
alone goes from 2.21/2.15× the Cramér–Rao bound (mm/degrees) to 1.47/1.46×, for 11.6 ms per
bone-frame (3.6 ms of host set-up, 4.6 steps, the sandwich); three bones jointly: talus
1.78/1.58× → 1.37/1.30×, rotation better for the tibia (2.01 → 1.69×) and the calcaneus (1.54 →
1.40×), translation worse for both (tibia 2.21 → 4.34×, calcaneus 1.45 → 1.89×; alone 4.26×,
1.80×: errors smooth from frame to frame, the trial's residual distortion). The sandwich's σ
covers 85-86 % of the talus's axes within 2σ (the independent-pixel σ 36-42 % before); with the
stage's move added (``final_confidence="sandwich+move"``) 94 %, and 100 % of the tibia's and
calcaneus's.

Speed: :mod:`core.tracking.likelihood_fast` (where the stage's time goes on one NVIDIA H100 and what
:data:`DIFF_IMAGES`, :data:`BLOCK_BLUR` change).

Fewer steps (:data:`STOP_PRED`, :data:`~core.tracking.final_stage.ROBUST_FROM_LAST`, :data:`DEVICE_REGIONS`)
------------------------------------------------------------------------------------------------
The stage starts at the tracker's optimum, and Gauss–Newton from there converges at once: on Warp's
CPU device (the talus, 256², 1 mm, 4 px) the first step's predicted decrease ``Jrᵀδ`` was 4-9 χ²/N,
the second's 0.05-0.08, the third's below 0.005 — yet the refinements ran on to ``tol`` (10⁻³ mm
and degrees) or five steps, 8.5 a bone-frame with the robust round. Now a refinement ends after a
step below ``STOP_PRED`` = 4 χ²/N (two independent-pixel σ), that step taken without rendering its
pose; the robust round takes its factors from the first refinement's last step (same weights, same
images) and starts its refinement there on those images, so it renders only where its step is
resolved; and the regions are made on the device (whose logarithm's last bit moved poses, before
the uphill rule of :data:`UPHILL_RESOLVED`, by 0.015 mm on 192² CPU tests; now 0.010 mm / 0.026° at
1024², within the stage's floor of 0.011 mm / 0.031°). Measured on one NVIDIA H100 (the acceptance
trial at 1024², 30 frames, three bones jointly, old and new alternated in one call, three repeats;
``resources/benchmarks/tracking_stage_fewer_steps_h100.json``): 10.97 → 4.99 ms per bone-frame at 4
px and 15.58 → 8.55 ms at 8 px, 8.54 → 3.23 steps (moment tables; about 2.2 renders, the robust
round's first step on the images before it), the device's time 8.30 → 4.19 ms (4 px), the frame
53 → 35 ms; errors over the Cramér–Rao bound (tibia, talus,
calcaneus mm/°, 4 px) 1.670/1.435, 1.465/1.385, 1.380/1.308 → 1.633/1.476, 1.469/1.397, 1.343/1.285,
no frame over 4× its bound unflagged; poses moved by up to 0.033 mm / 0.068° (over 90 bone-frames,
the tracker carrying each pose into the next frame), σ by up to 16 %. A single step (no verification
at all) took 6.1 ms but the tibia's rotation to 1.57×; forward differences (:data:`FORWARD_DESIGN`,
7 poses) moved poses by ~1 σ on a 256² CPU trial (the derivatives' O(h) error biases the fixed point).

The device work reuses the engine's renderer launch (:meth:`core.tracking.engine.GaussNewtonCost._render`,
its pose mapping) and the separable blur of :mod:`core.similarity._kernels`. A step of the default
model is one CUDA graph on a CUDA device (:data:`STEP_GRAPH`, :mod:`core.tracking.likelihood_graph`);
the other kernels (and a step's where it is off) are launched one by one, each from a recorded launch
while its arguments stay the same (:meth:`LikelihoodEngine._launch`,
:mod:`core.tracking.likelihood_launches`; the frame's set-up, the robust factors and the sandwich each
one recorded graph too, :mod:`core.tracking.likelihood_segments`): one graph launch (4-5 launches without
it) and one wait per step, for the engine's own work only (an event recorded after the table's copy):
:meth:`LikelihoodEngine.refine_steps` yields there, so that several bones' refinements run side
by side (:func:`run_side_by_side`). The kernels live in :mod:`core.tracking.likelihood_kernels`
(re-exported here), its constructor and buffers in :mod:`core.tracking.likelihood_state`, the
weights of the region (:meth:`LikelihoodEngine.scale_weights` …) in
:mod:`core.tracking.likelihood_weights`.
"""

from __future__ import annotations

import math
import time
import weakref
from collections.abc import Sequence
from contextvars import ContextVar

import numpy as np
import warp as wp

from ..similarity import _kernels as K
from . import likelihood_device_steps as _DS
from . import likelihood_launches as _LL
from . import likelihood_solve as _LS
from .cost import FrameImages
from .engine import GaussNewtonCost
from .engine_buffers import copy_array
from .engine_search import step_design
from .likelihood_confidence import _Confidence
from .likelihood_fast import blur_block_dim, blur_block_kernel, design_diff_kernel
from .likelihood_frames import _FrameRegions
from .likelihood_graph import _StepGraphs
from .likelihood_kernels import (  # noqa: F401 (re-exported: the kernels' names as before)
    NA,
    NZ,
    _blur_pair_kernel,
    _hp,
    _local_rms_kernel,
    _robust_sq_kernel,
    _robust_weight_kernel,
    _times_kernel,
    autocov_kernel,
    fluence_psf_kernel,
    highpass_kernel,
    mat12f,
    mat66f,
    meat_kernel,
    others_kernel,
    psf_kernel,
    regressor_kernels,
    regressor_sum_kernel,
    residual_kernel,
    robust_factors_device,
    taper_kernel,
    vec2d,
    vec5f,
    vec6f,
    vec12f,
    weights_kernel,
    wls_moments_kernel,
)
from .likelihood_launches import _Launches
from .likelihood_segments import _Segments
from .likelihood_solve import solve_moments
from .likelihood_state import _EngineState
from .likelihood_steps import StepClock, run_side_by_side, run_steps
from .likelihood_tissue import _TissueRegressors
from .likelihood_weights import _RegionWeights

__all__ = ["BLOCK_BLUR", "DEVICE_REGIONS", "DEVICE_STEPS", "DIFF_IMAGES", "MOMENTS_TRI", "STEP_GRAPH",
           "STOP_PRED", "UPHILL_RESOLVED",
           "LikelihoodEngine", "StepClock", "likelihood_engine", "robust_factors_device", "run_side_by_side",
           "run_steps", "solve_moments"]

#: The regions' line integrals and usable pixels made on the device from the fluence
#: (:func:`~core.tracking.engine_kernels.fluoro_roi_kernel`, as the tracker's engine makes them)
#: instead of on the host (:meth:`~core.tracking.cost.FrameImages.region`; off, as first measured:
#: 3.3-3.4 → 1.5 ms of set-up per bone-frame on one NVIDIA H100, three bones jointly at 1024²). The
#: device's logarithm differs from numpy's float32 one in the last bit of 13-19 % of the pixels;
#: that moved the stage's poses by up to 0.015 mm on 192² CPU tests before :data:`UPHILL_RESOLVED`,
#: by 0.010 mm / 0.026° at 1024² since, the stage's floor (module docs: Fewer steps).
DEVICE_REGIONS = True
#: A step's 13 images taken as the design's centre and its six central differences before the
#: high-pass's low-pass (:func:`~core.tracking.likelihood_fast.design_diff_kernel`: 7 images a
#: view blurred instead of 13; the high-pass is linear, the moments the same up to float32
#: rounding; module docs: Speed). Off: every pose's image low-passed, as first measured.
DIFF_IMAGES = True
#: The separable blurs of the high-pass and the weights with several outputs a thread
#: (:func:`~core.tracking.likelihood_fast.blur_block_kernel`; the same values). Off: one
#: output a thread (:func:`core.similarity._kernels.blur_kernel`), as first measured.
BLOCK_BLUR = True
#: :meth:`LikelihoodEngine.refine`'s uphill test (χ² rose: the pose before kept) is for steps the
#: data resolve: one whose predicted decrease of χ² (``Jrᵀδ``) is below this many pixels' shares of
#: χ² (χ²/N: 4, within two independent-pixel σ) stands whatever χ² did, and a rise after it ends
#: the refinement as converged; there χ²'s comparison is within its rounding and chose whether a
#: whole step stood (:mod:`~core.tracking.likelihood_fast`: Rounding). 0: every rise, as first measured.
UPHILL_RESOLVED = 4.0
#: A step's design the 7 poses ``x``, ``x + h_k e_k`` (forward differences, twice each taken as the
#: central one: the DRR launch renders 7 poses instead of 13; the derivatives' error O(h) instead of
#: O(h²)); implies :data:`DIFF_IMAGES`. Off: the 13-pose central design, as first measured.
FORWARD_DESIGN = False
_FORWARD = [0, 1, 3, 5, 7, 9, 11]  # step_design's x and x + h_k e_k
#: A refinement's steps after its first render only the design's centre, the six differences (the
#: Jacobian) those of the last full design (a chord method: one pose rendered and blurred instead
#: of 13 and 7). Off: every step a full design, as first measured. Its fixed point is where the
#: first design's Jacobian is orthogonal to the residual: with the fewer steps it moved poses by
#: 0.09-0.18 σ from the default's on a 256² CPU trial (the stage's floor there 0.003-0.01 σ); not
#: measured on a GPU.
CHORD_STEPS = False
#: A step's device work (the design's item table, DRRs, differences, blurs, moments and the table's
#: copy) recorded once per output size and replayed, on a CUDA device as one CUDA graph
#: (:mod:`core.tracking.likelihood_graph`; the same values). None: on CUDA devices only; True: on
#: every device (the CPU's launches one by one: tests); False: the step's launches made one by one,
#: the item table filled on the host, as first measured. Used for the default model's steps (no
#: PSF, no extra regressors, a high-pass, the design's differences, the 13-pose design). Measured with
#: the moments' triangle and the sandwich's kernels: :mod:`core.tracking.likelihood_fast` (Phase 2).
STEP_GRAPH: bool | None = None
#: A step's moments table summed on and above its diagonal only
#: (:func:`~core.tracking.likelihood_fast.wls_moments_tri_kernel`: 78 of the 144 entries, each the
#: same sum; the host mirrors the rest), without extra regressors. Off: every entry, as first measured.
#: One NVIDIA H100, the acceptance trial at 1024² (``tracking_stage_h2_h100.json``): 0.47 → 0.37 ms per
#: bone-frame (3.6 tables).
MOMENTS_TRI = True
#: pixels a thread block of a step's moments kernel sums (None: the engine's ``chunk``, 4096, as
#: first measured; smaller: more blocks, the same terms summed in another order, float32 rounding)
MOMENTS_CHUNK: int | None = None
#: :meth:`LikelihoodEngine.refine` ends after a step whose predicted decrease of χ² (``Jrᵀδ``) is
#: below this many pixels' shares of χ² (χ²/N: the step's Mahalanobis length in independent-pixel
#: σ, squared), that step taken without rendering its pose to verify it (Gauss–Newton from the
#: tracker's optimum: the next step is 1-10 % of this one's length; module docs: Fewer steps).
#: 0: only ``tol`` (1e-3 mm and degrees, far below σ) or an uphill step ends it, as first measured.
STOP_PRED = 4.0
#: A refinement's steps back to back on the device, the host waiting once (each step's table solved, the
#: stopping rules and the next design by a kernel, the loop a CUDA graph's conditional node:
#: :mod:`core.tracking.likelihood_device_steps`); the same steps up to the solves' float64 rounding. Off:
#: the host solves each step's table and enqueues the next, as first measured. ``"render"``: only refinements
#: whose first step renders (a robust refinement's first step on the last design's images, where it most
#: often ends, on the host).
DEVICE_STEPS: bool | str = False
#: Inside :func:`core.tracking.final_stage.confirm_move`'s second run: refinements to ``tol`` (no
#: :data:`STOP_PRED` stop; the robust round from the first refinement's result)
TO_TOL: ContextVar = ContextVar("likelihood_to_tol", default=False)


class LikelihoodEngine(_EngineState, _Launches, _FrameRegions, _TissueRegressors, _Confidence,
                       _RegionWeights, _StepGraphs, _Segments):
    """The weighted least-squares refinement of one bone on the device (module docs), reusable from
    frame to frame (:func:`likelihood_engine` keeps one per renderer, bone and settings).

    ``highpass_px``: σ of the high-pass (pixels; None or 0: none, then a background of order
    ``background`` 0 or 1 carries the smooth structure); ``psf``: an odd 2-D kernel estimated from
    calibration images, or None; ``weight_sigma_px``: smoothing of the expected counts;
    ``others_gain``: the neighbours' DRRs (``others`` of :meth:`set_frame`) a regressor with a gain
    of their own (fitted at every pose like the bone's) instead of subtracted as they are;
    ``lag_px``: the autocovariance's lag window of :meth:`sandwich` (default ``2 · highpass_px``
    plus the PSF's radius, at least 2).
    """

    _render = GaussNewtonCost._render
    poses = GaussNewtonCost.poses

    # ------------------------------------------------------------------ per frame
    def set_frame(self, frame: FrameImages, *, base_pose, center, roi, others=None, regressors=None) -> None:
        """The regions ``roi (views, 4)`` of ``frame`` (line integrals, usable pixels, weights; the
        DRRs of ``others = (poses, bones)`` at their poses subtracted), high-passed on the device,
        and the parameterisation ``base_pose``, ``center`` of the next steps (module docs: Set-up).
        ``regressors``: per view ``(q, h, w)`` (or ``(h, w)``) fixed images over the region as the
        frame shows them, each with its own coefficient fitted at every pose, high-passed like the
        frame (not blurred by the PSF: the ``regressors`` of
        :class:`~core.tracking.likelihood_cost.LikelihoodCost`); without them the frame has none
        (:meth:`set_tissue` renders them).
        Raises :class:`~core.tracking.cost.OutsideViewError` for a region without usable pixels
        (on the device path at the next :meth:`step`'s synchronisation)."""
        t0 = time.perf_counter()
        self._frame_work = None  # (the recorded step of the last frame: _step_work)
        self.base = np.asarray(base_pose, dtype=float)
        self.center = np.asarray(center, dtype=float)
        self.roi = np.asarray(roi, dtype=np.int64).reshape(self.n_views, 4)
        nv = self.n_views
        if self._up_event is not None:  # the pinned buffers are written again after their last copies
            wp.synchronize_event(self._up_event)
        staged = self._staged(frame) if DEVICE_REGIONS else None
        if staged is None:  # the host's regions (those of fluoro_rois), uploaded
            rois, masks = self._regions(frame)
            shapes = [v.shape for v in rois]
        else:
            shapes = [(int(h), int(w)) for _, _, w, h in self.roi]
        self._cap = tuple(int(math.ceil(max(sh[k] for sh in shapes) / 32.0) * 32) for k in (0, 1))
        Hc, Wc = self._cap
        if _LL.BUFFERS_PER_SIZE:  # (each size's buffers kept)
            self._use_buffers(self._cap)
        hw = np.array(shapes, dtype=np.int32)
        if self._hw_last is None or not same_array(hw, self._hw_last):
            self._host_hw.numpy()[:] = hw
            copy_array(self._ref_hw, self._host_hw)
            self._hw_last = hw
        li = self._buffer("li", (nv, Hc, Wc))
        mask = self._buffer("mask", (nv, Hc, Wc), wp.uint8)
        # the regions, the neighbours' DRRs (through the engine's own item table), the weights and the
        # high-pass one recorded piece (SEGMENT_GRAPHS)
        n_o = 0 if others is None else len(others[1])
        alone = staged is not None and self._segments_on() and (
            not n_o or (self._graph_step() and self._psf is None))
        made = oth = None
        if staged is None:
            self._host_upload(rois, masks, li, mask)
        else:
            made = self._stage(frame, staged, li, mask, launch=not alone)
        if alone and n_o:
            oth = self._others_own(others, li)
        else:
            self._frame_others(others, li)
        if not alone:
            self._uploaded()  # (after the neighbours' item table's upload too: _render_own)
        # the weights: the expected counts exp(-G ∗ y) of the unsubtracted line integrals (no scale:
        # neither the steps nor the covariances depend on one)
        self._w = self._buffer("w", (nv, Hc, Wc))
        self._w0_set = False  # the expected counts as computed below (scale_weights keeps a copy)
        self._count_weights = self._wcount_pending = False  # (count_weights)
        self._y = self._buffer("y", (nv, Hc, Wc))
        self._o = self._buffer("o", (nv, Hc, Wc))
        if alone:
            key = (made, oth, self._y_raw, self._o_raw, self._wtaps, self._taps, self.highpass_px, BLOCK_BLUR,
                   self.chunk)
            self._segment("prep", key, lambda: self._prep_enqueue(made, li, mask, oth))
            self._uploaded()
        else:
            self._prep_enqueue(None, li, mask)
        self._frame_regressors(regressors, hw)
        self.timer.host += time.perf_counter() - t0

    def _blurred(self, tag: str, src, n_refs: int, taps=None):
        """The Gaussian low-pass of ``src`` (two passes of the separable blur; ``taps`` default the
        high-pass's)."""
        tmp = self._buffer(tag + "_tmp", src.shape)
        low = self._buffer(tag + "_low", src.shape)
        taps = self._taps if taps is None else taps
        for a, b, axis in ((src, tmp, 1), (tmp, low, 0)):
            if BLOCK_BLUR:
                self._launch((tag, axis), blur_block_kernel, blur_block_dim(src.shape, axis),
                             [a, b, taps, self._ref_hw, n_refs, axis])
            else:
                self._launch((tag, axis), K.blur_kernel, src.shape, [a, b, taps, self._ref_hw, n_refs, axis])
        return low

    # ------------------------------------------------------------------ steps
    def _images(self, X: np.ndarray):
        """Render the poses ``X (13, 6)``; their (PSF-blurred) images and low-passed images
        (:data:`DIFF_IMAGES`: the centre's and the six differences', :attr:`_diff` 1)."""
        t0 = time.perf_counter()
        img = self._render(self.poses(X)[:, None], (self.bone,))
        t1 = time.perf_counter()
        fwd = int(len(X) == 7)  # (the forward design: FORWARD_DESIGN)
        diff = DIFF_IMAGES or bool(fwd)
        if self.own_images and self._psf is None and not diff:  # (the PSF's output is the engine's own)
            own = self._buffer("img", img.shape)
            wp.copy(own, img)
            img = own
        if self._psf is not None:
            out = self._buffer("psf", img.shape)
            wp.launch(psf_kernel, dim=img.shape, inputs=[img, out, self._psf, self._ref_hw, self.n_views],
                      device=self.device)
            img = out
        if diff:  # (the engine's own buffer)
            dd = self._buffer("dd", (7 * self.n_views, *img.shape[1:]))
            self._launch("diff", design_diff_kernel, dd.shape, [img, self.n_views, self._ref_hw, dd, fwd])
            img = dd
        self._diff = int(diff)
        low = self._blurred("d", img, self.n_views) if self.highpass_px else img
        self.timer.host += t1 - t0
        self.timer.render += time.perf_counter() - t1
        return img, low

    def _centre_images(self, x: np.ndarray, img, low):
        """The design's centre at ``x`` rendered into the last design's images ``img`` and its
        low-pass into ``low`` (items ``0 … views-1``; the differences kept: :data:`CHORD_STEPS`)."""
        t0 = time.perf_counter()
        one = self._render(self.poses(np.asarray(x, dtype=float)[None])[:, None], (self.bone,))
        t1 = time.perf_counter()
        nv = self.n_views
        if self._psf is not None:
            out = self._buffer("psf1", one.shape)
            wp.launch(psf_kernel, dim=one.shape, inputs=[one, out, self._psf, self._ref_hw, nv],
                      device=self.device)
            one = out
        c = self._buffer("c", (nv, *img.shape[1:]))
        self._launch("diff1", design_diff_kernel, c.shape, [one, nv, self._ref_hw, c, 0])
        n = c.size
        wp.copy(img, c, 0, 0, n)
        if self.highpass_px:
            wp.copy(low, self._blurred("c", c, nv), 0, 0, n)
        self.timer.host += t1 - t0
        self.timer.render += time.perf_counter() - t1
        return img, low

    def step(self, x, h, *, reuse: bool = False) -> dict:
        """The weighted products table of the 13-pose design about ``x`` (half-steps ``h``,
        mm and degrees) and :func:`solve_moments` of it (one DRR launch, 4-5 kernels, one
        synchronisation). ``reuse``: the last step's images where its design was the same (the
        caller knows nothing rendered into the renderer's buffer since), the weights those of now:
        no DRR launch."""
        self.step_launch(x, h, reuse=reuse)
        return self.step_result()

    def step_launch(self, x, h, *, reuse: bool = False, chord: bool = False) -> None:
        """The first half of :meth:`step`: its launches and the table's copy to the host enqueued,
        nothing waited for (:meth:`step_result` takes it). ``chord``: with :data:`CHORD_STEPS`, only
        the centre rendered, the differences the last design's."""
        x = np.asarray(x, dtype=float)
        h = np.asarray(h, dtype=float)
        last = self._last
        if reuse and last is not None and same_array(last[2], x) and same_array(last[3], h):
            img, low = last[0], last[1]
        elif chord and CHORD_STEPS and last is not None and self._diff and same_array(last[3], h):
            img, low = self._centre_images(x, last[0], last[1])
            self.timer.evaluations += 1
            self.renders += 1
        elif self._graph_step():  # (the step's work recorded: one graph)
            t0 = time.perf_counter()
            work = self._step_work()
            work.x_np[:] = step_design(x, h)
            work.replay()
            self._record()
            self._diff, self._tri = 1, work.tri
            self._last = (work.dd, work.low, x, h)
            self._pending = h
            self.timer.evaluations += 13
            self.renders += 1
            self.timer.render += time.perf_counter() - t0
            return
        else:
            X = step_design(x, h)
            X = X[_FORWARD] if FORWARD_DESIGN else X
            img, low = self._images(X)
            self.timer.evaluations += len(X)
            self.renders += 1
        t0 = time.perf_counter()
        self._tri = self._moments_tri()
        key = (img, low, self._y, self._w, self._o, self._t, self._q, self._tri, self._diff, self.highpass_px,
               self._moments_chunk(), self.block_dim)
        self._segment("moments", key, lambda: self._moments_enqueue(img, low))
        self._record()
        self._last = (img, low, x, h)
        self._pending = h
        self.timer.metric += time.perf_counter() - t0

    def _moments_chunk(self) -> int:
        return MOMENTS_CHUNK or self.chunk

    def _moments_tri(self) -> bool:
        return bool(MOMENTS_TRI and not self._q)

    def _graph_step(self) -> bool:
        """Whether a step's design is rendered and summed by its recorded work (:data:`STEP_GRAPH`)."""
        on = self.device.is_cuda if STEP_GRAPH is None else STEP_GRAPH
        return bool(on and DIFF_IMAGES and BLOCK_BLUR and not FORWARD_DESIGN and self._psf is None
                    and not self._q and self.highpass_px)

    def step_result(self) -> dict:
        """The second half of :meth:`step`: waits for the table of the last :meth:`step_launch`
        and solves it."""
        t0 = time.perf_counter()
        h, self._pending = self._pending, None
        self._wait()
        if self._count_pending:  # the regions prepared on the device: their usable pixels
            self._take_count()
        if self._wcount_pending:  # (those with a positive weight: count_weights)
            self._take_weights_count()
        host = self._tables_q()[1]  # (its numpy view kept: Warp makes one anew on every call)
        view = self.__dict__.get("_host_view")
        if view is None or view[0] is not host:
            view = self._host_view = (host, host.numpy())
        self.timer.metric += time.perf_counter() - t0
        self.timer.calls += 1
        t1 = time.perf_counter()
        out = _LS.solve_tables(view[1], h, self.background, self._with_o, self._q, self._tri)
        self.timer.host += time.perf_counter() - t1
        return out

    def refine(self, x0=None, *, iters: int = 5, step=(0.05, 0.05), tol=(1e-3, 1e-3),
               sandwich: bool = True, reuse: bool = False) -> dict:
        """Gauss–Newton minimisation of χ² from ``x0`` (default 0: the base pose), as
        :meth:`core.tracking.likelihood_cost.LikelihoodCost.refine` (stops when a step is below
        ``tol`` or :data:`STOP_PRED`, or χ² rises, keeping the pose before; :data:`UPHILL_RESOLVED`).
        Returns ``{"x", "chi2", "iterations", "covariance", "covariance_independent", "design"}`` (mm,
        degrees): ``chi2`` and the covariances are those of the last design's centre (``design``: that
        centre and its step's result), ``x`` that centre plus its step, not rendered (after an uphill
        stop ``x`` and ``chi2`` are the pose before's, the covariances the rejected design's, ``design``
        None); the sandwich covariance of :meth:`sandwich` (``sandwich`` False: NaN, not computed, and
        :attr:`autocorrelation` None) and ``χ²/N · (JᵀWJ)⁻¹``.
        ``reuse``: the first step takes the last step's images where its design is the same
        (:meth:`step`)."""
        return run_steps(self.refine_steps(x0, iters=iters, step=step, tol=tol, sandwich=sandwich,
                                           reuse=reuse))

    def refine_steps(self, x0=None, *, iters: int = 5, step=(0.05, 0.05), tol=(1e-3, 1e-3),
                     sandwich: bool = True, reuse: bool = False):
        """:meth:`refine` as a generator (its value the result): it yields where it would wait for
        the device, its work enqueued, so that a caller can run several engines' refinements side
        by side (:func:`run_side_by_side`); each one's iterates are those of :meth:`refine`. The
        renderer's output buffer is shared: between yields other engines render into it, so the
        engine keeps its own copy of the images (:attr:`own_images`) while side by side.
        ``sandwich="later"``: the sandwich launched and not waited for, ``covariance`` None and
        ``sandwich`` the H⁻¹ that :meth:`sandwich_result` takes (after more work of the engine's
        enqueued: it reads the sandwich's result when the device has got to it); ``"defer"``: not even
        launched, its design's step result ``sandwich_s`` for the caller's :meth:`sandwich_launch`
        (before the engine's images or weights change)."""
        hv = np.array([step[0]] * 3 + [step[1]] * 3, dtype=float)
        tv = np.array([tol[0]] * 3 + [tol[1]] * 3, dtype=float)
        x = np.zeros(6) if x0 is None else np.asarray(x0, dtype=float).copy()
        best, n_it, pred, last = None, 0, 0.0, None
        got = None
        if DEVICE_STEPS and not CHORD_STEPS and _DS.usable(self, iters, reuse, x, hv, DEVICE_STEPS):
            got = yield from _DS.device_refine(self, x, hv, tv, iters, reuse, uphill=UPHILL_RESOLVED,
                                               stop=STOP_PRED, small_ok=not TO_TOL.get())
        if got is not None:
            x, best, n_it, last, s = got
        for it in range(1, int(iters) + 1 if got is None else 0):
            n_it = it
            self.step_launch(x, hv, reuse=reuse and it == 1, chord=it > 1)
            yield
            s = self.step_result()
            share = s["chi2"] / max(self.n_pixels, 1)  # (χ²/N)
            rose = best is not None and s["chi2"] > best[1]["chi2"]
            if not math.isfinite(s["chi2"]) or (rose and pred >= UPHILL_RESOLVED * best[1]["chi2"]
                                              / max(self.n_pixels, 1)):
                x = best[0] if best is not None else x  # uphill: the previous pose stands
                last = None
                break
            best = last = (x.copy(), s)
            delta = _LS.solve6(s["JJ"], s["Jr"])
            pred = float(s["Jr"] @ delta)  # the step's predicted decrease of χ²
            x = x + delta
            small = pred < STOP_PRED * share and not TO_TOL.get()
            if rose or (np.abs(delta) < tv).all() or small:
                break  # (risen after a step the data do not resolve, or a step below STOP_PRED: converged)
        out = {"x": x, "chi2": best[1]["chi2"] if best else np.nan, "iterations": n_it,
               "design": last}  # (the last design's centre and its step, where the result stepped from it)
        nan = np.full((6, 6), np.nan)
        if best is None:  # not even the start could be fitted
            return {**out, "covariance": nan, "covariance_independent": nan}
        try:  # the last design rendered (its images are on the device)
            Hinv = _LS.inv6(s["JJ"])
        except np.linalg.LinAlgError:
            return {**out, "covariance": nan, "covariance_independent": nan}
        out["covariance_independent"] = Hinv * s["chi2"] / max(self.n_pixels, 1)
        if sandwich in ("later", "defer"):  # the caller takes it (sandwich_result(out["sandwich"]))
            if sandwich == "later":  # (launched; "defer": the caller launches it, sandwich_launch(s))
                self.sandwich_launch(s)
            else:
                out["sandwich_s"] = s
            out["covariance"] = None
            out["sandwich"] = Hinv
        elif sandwich:
            self.sandwich_launch(s)
            yield
            out["covariance"] = self.sandwich_result(Hinv)
        else:  # not computed (nor the autocorrelation: a study reading either sees none)
            out["covariance"] = nan
            self._cov_host = None
        return out


def same_array(a, b) -> bool:
    """``numpy.array_equal(a, b)`` of two arrays (the same shape and every entry equal, so never where a NaN
    is: not even ``a`` against itself), without its conversions and dispatch."""
    return a.shape == b.shape and bool((a == b).all())


_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def likelihood_engine(renderer, *, bone: int, views: Sequence[int], highpass_px: float | None = 4.0,
                      psf=None, background: int = 0, lag_px: int | None = None,
                      others_gain: bool = False) -> LikelihoodEngine:
    """The :class:`LikelihoodEngine` of ``renderer`` for this bone, views and settings, kept for the
    renderer's lifetime."""
    per = _CACHE.setdefault(renderer, {})
    key = (int(bone), tuple(int(v) for v in views), float(highpass_px or 0.0),
           None if psf is None else np.asarray(psf, np.float64).tobytes(), int(background), lag_px,
           bool(others_gain))
    e = per.get(key)
    if e is None:
        e = per[key] = LikelihoodEngine(renderer, bone=bone, views=views, highpass_px=highpass_px, psf=psf,
                                        background=background, lag_px=lag_px, others_gain=others_gain)
    return e
