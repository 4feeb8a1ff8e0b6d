"""The likelihood final stage's engine state (:class:`core.tracking.engine_likelihood.LikelihoodEngine`'s
constructor: its settings, the high-pass's and the weights' taps, the device buffers it keeps from
frame to frame, the pinned host buffers of the regions' set-up, the records of its last step). A
mixin of the engine's; the parameters are the engine's (its class docs)."""

from __future__ import annotations

import weakref
from collections.abc import Sequence

import numpy as np
import warp as wp

from .cost import CostTimer
from .likelihood_kernels import NZ
from .likelihood_segments import Tracked


class _EngineState:
    """:class:`~core.tracking.engine_likelihood.LikelihoodEngine`'s constructor and its renderer."""

    def __init__(self, renderer, *, bone: int, views: Sequence[int], highpass_px: float | None = 4.0,
                 psf=None, background: int = 0, weight_sigma_px: float = 2.0, lag_px: int | None = None,
                 others_gain: bool = False, block_dim: int = 128, chunk: int = 4096) -> None:
        from ..similarity.batched import gaussian_weights

        if int(background) not in (0, 1):
            raise ValueError(f"background: expected a polynomial order 0 or 1, got {background!r}")
        self.psf = None if psf is None else np.asarray(psf, dtype=np.float64)
        if self.psf is not None and (self.psf.ndim != 2 or self.psf.shape[0] % 2 == 0
                                     or self.psf.shape[1] % 2 == 0 or self.psf.sum() <= 0):
            raise ValueError(f"psf: expected an odd-sized 2-D kernel with a positive sum, "
                             f"got {self.psf.shape}")
        self._renderer_ref = weakref.ref(renderer)
        self.device = renderer.device
        self.bone = int(bone)
        self.views = tuple(int(v) for v in views)
        self.n_views = len(self.views)
        self.scale = 1.0
        self.background = int(background)
        self.others_gain = bool(others_gain)
        self._with_o = False  # the neighbours' DRRs a regressor in this frame (set_frame)
        self._q = 0  # the frame's extra regressors a view (set_frame's regressors, set_tissue)
        self._t = None  # their images (q · views, H, W) as the model sees them
        self.highpass_px = float(highpass_px) if highpass_px else 0.0
        self.weight_sigma_px = float(weight_sigma_px)
        rad = 0 if self.psf is None else max(self.psf.shape) // 2
        self.lag_px = int(lag_px) if lag_px is not None else max(2, round(2 * self.highpass_px) + rad)
        self.block_dim, self.chunk = int(block_dim), int(chunk)
        dev = self.device
        self._taps = (wp.array(gaussian_weights(self.highpass_px, truncate=4.0), dtype=wp.float32, device=dev)
                      if self.highpass_px else None)
        self._wtaps = (wp.array(gaussian_weights(self.weight_sigma_px, truncate=4.0), dtype=wp.float32,
                                device=dev) if self.weight_sigma_px > 0 else None)
        self._psf = (None if self.psf is None else
                     wp.array((self.psf / self.psf.sum()).astype(np.float32), dtype=wp.float32, device=dev))
        self._ref_hw = wp.zeros(self.n_views, dtype=wp.vec2i, device=dev)
        pinned = dev.is_cuda
        self._host_hw = wp.zeros(self.n_views, dtype=wp.vec2i, device="cpu", pinned=pinned)
        self._hw_last = None
        # the device's preparation of the regions (_stage): its item table, the usable pixels
        # counted per view (and their sum, the regions' maxima: fluoro_roi_kernel's outputs)
        self._info = wp.zeros((self.n_views, 8), dtype=wp.int32, device=dev)
        self._host_info = wp.zeros((self.n_views, 8), dtype=wp.int32, device="cpu", pinned=pinned)
        self._msum = wp.zeros((self.n_views, 2), dtype=wp.float64, device=dev)
        self._host_msum = wp.zeros((self.n_views, 2), dtype=wp.float64, device="cpu", pinned=pinned)
        self._fmax = wp.zeros(self.n_views, dtype=wp.float32, device=dev)
        self._count_pending = False
        self._host: dict = Tracked()  # pinned host buffers (_pinned; Tracked: the recorded pieces' validity)
        self._up_event = None  # recorded after the last uploads from them
        self._y_raw = self._o_raw = None
        self._cov_host = None  # the last sandwich's autocovariance (autocorrelation)
        self._last = None  # the last step's (images, low-passed images, x, h)
        self._diff = 0  # its images in design_diff_kernel's layout (DIFF_IMAGES)
        self._tri = False  # its table summed on and above the diagonal only (MOMENTS_TRI)
        self._pending = None  # the half-steps of the step launched and not yet taken (step_result)
        self._done = None  # an event recorded after the last work a result waits for (_record)
        #: the rendered images copied into the engine's own buffer (refinements side by side:
        #: other engines render into the renderer's between this one's launches)
        self.own_images = False
        self._acc = wp.zeros((self.n_views, NZ * NZ), dtype=wp.float64, device=dev)
        self._host_acc = wp.zeros((self.n_views, NZ * NZ), dtype=wp.float64, device="cpu", pinned=dev.is_cuda)
        self._tables: dict = {}
        self._bufs: dict = Tracked()
        self._cmds: dict = {}  # recorded launches by name (_launch)
        self._cap = None
        self.timer = CostTimer()
        self.renders = 0  # the steps' DRR launches (a step reusing the last design's images renders none)
        self.base = self.center = self.roi = None
        self._w0_set = False
        self._count_weights = self._wcount_pending = False  # n_pixels from the weights (count_weights)

    @property
    def renderer(self):
        r = self._renderer_ref()
        if r is None:
            raise RuntimeError("renderer: the renderer of this engine no longer exists")
        return r

