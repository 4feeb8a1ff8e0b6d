"""The likelihood final stage's confidence (:class:`core.tracking.engine_likelihood.LikelihoodEngine`'s
sandwich covariance, its weighted residual and the residual's autocorrelation), on the device. A
mixin of the engine's.

``χ²/dof · (JᵀWJ)⁻¹`` treats the pixels as independent; the high-pass, the PSF and what the
model leaves out (soft tissue, glare) make the residuals correlated, and it is then too small
(36-42 % of frames within 2σ measured before). The sandwich covariance is

    Cov(δ) = H⁻¹ (Σ_ij J̃_i J̃_jᵀ C(i - j)) H⁻¹         H = JᵀWJ,  J̃ = √w J,  e = √w r

with ``C(Δ)`` the autocovariance of the weighted residual ``e`` estimated from the image itself
over lags ``|Δ_u|, |Δ_v| <= lag_px`` (pairs of usable pixels, a Bartlett taper keeps the estimate
positive semi-definite). Per view three device passes at the final pose: the weighted residual
and projected Jacobian images, the residual's autocovariance, and the "meat" sum. What it covers
as measured: the engine's module docs.
"""

from __future__ import annotations

import math
import time

import numpy as np
import warp as wp

from .engine_buffers import copy_array
from .likelihood_fast import autocov_rows_dim, autocov_rows_kernel
from .likelihood_kernels import autocov_kernel, meat_kernel, regressor_kernels, taper_kernel, vec6f
from .likelihood_stride import autocov_stride_kernel, meat_stride_kernel, stride_cells

#: pixels a thread block of the sandwich's meat kernel sums (None: the engine's ``chunk``, 4096, as
#: first measured: some 80 blocks of 128 threads for two 400² regions, too few to fill a GPU, each
#: pixel's 289 lags at 4 px in a thread). 512: the same terms summed in another order (σ within
#: 3 · 10⁻⁷ relative), the kernel 0.72 → 0.36 ms per bone-frame at 4 px and 2.69 → 1.25 ms at 8 px
#: (one NVIDIA H100, the acceptance trial at 1024²; ``tracking_stage_fewer_steps_h100.json``)
MEAT_CHUNK: int | None = 512
#: the same for the autocovariance kernel (None: the engine's ``chunk``; it has a block per lag
#: already, and was slower with 512: 0.51 → 0.76 ms at 4 px)
AUTOCOV_CHUNK: int | None = None
#: The autocovariance summed with 9 lags of a row a thread
#: (:func:`~core.tracking.likelihood_fast.autocov_rows_kernel`: each pixel read once for them, 18
#: passes over the region at 4 px instead of 145; the same pairs and products, summed in another
#: order). Off: a pass per lag (:func:`~core.tracking.likelihood_kernels.autocov_kernel`), as first
#: measured. One NVIDIA H100, the acceptance trial at 1024² (``tracking_stage_h2_h100.json``): 0.51 →
#: 0.31 ms per bone-frame at 4 px, 1.87 → 1.08 ms at 8 px.
AUTOCOV_ROWS = True
#: The meat over half the lags (those after lag 0, twice; :func:`~core.tracking.likelihood_kernels.
#: meat_kernel`'s ``half``): the same symmetric matrix in half the products (float32 sums in another
#: order). Off: every lag, as first measured. Same call: 0.43 → 0.22 ms at 4 px, 1.50 → 0.75 ms at 8 px;
#: σ within 7 · 10⁻⁸ relative over the 90 bone-frames.
MEAT_HALF = True
#: The sandwich's autocovariance and meat summed over the region's pixels whose row and column are
#: multiples of this (:mod:`core.tracking.likelihood_stride`; their partners at every lag still every
#: pixel; the meat times its square; as many thread blocks as before, each a quarter of the pixels):
#: 1 / stride² of the two passes' work (0.43 ms a bone-frame with every pixel on one NVIDIA H100, the
#: talus at 1024²), an estimate of the same matrix; poses unchanged. On this 2-core x86_64 machine
#: (``core.studies.tracking.stage_cuts``, seed 0, ten frames a bone, the stage from the truth moved
#: 1.5 bound σ) σ per axis against every pixel's: at 256² within 1-2 % on average (7.5 % at worst on
#: one bone-frame's axis; stride 3 up to 7 % and 22 %), at 512² within 0.5-1 % (3.2 % at worst).
#: 1: every pixel, as first measured.
SANDWICH_STRIDE = 2
#: A sandwich's autocovariance (:attr:`~_Confidence.autocorrelation`, read by studies) copied from the
#: device where it is read, not after every sandwich (the same buffer: the last sandwich's values, the copy
#: waits for it); off: copied into a pinned buffer after every sandwich, as before (one copy fewer a
#: bone-frame: the stage reads back only what it decides on).
COV_ON_READ = True


class _Confidence:
    """:class:`~core.tracking.engine_likelihood.LikelihoodEngine`'s sandwich covariance (its
    attributes: the last step's images ``_last``, the frame's buffers, ``lag_px``, launches)."""

    def _residual_device(self, s: dict, jacobian: bool = True, pin: str = "lin", weights=None) -> tuple:
        """``(e, jt)`` on the device: the weighted residual ``e = √w (y - A coef)`` and its
        projections at the centre of the last step's design (``s``: that :meth:`step`'s result;
        :func:`~core.tracking.likelihood_kernels.residual_kernel`), in the engine's buffers ``"e"`` and
        ``"jt"`` (``jacobian`` False: ``jt`` not computed). ``pin``: the pinned host buffer the fit's
        coefficients go up from (another than an upload still pending from the last one's).
        ``weights``: ``w`` (default the engine's weights now)."""
        lin_h = self._lin_pinned(s, pin)
        return self._residual_enqueue(lin_h, jacobian, weights)

    def _lin_pinned(self, s: dict, pin: str):
        """The fit's coefficients ``s["lin"]`` written into the pinned host buffer ``pin``."""
        lin_h = self._pinned(pin, s["lin"].shape, exact=True)  # (taken since: a step's wait followed it)
        self._view(lin_h)[...] = s["lin"]
        return lin_h

    def _residual_enqueue(self, lin_h, jacobian: bool, weights) -> tuple:
        """:meth:`_residual_device`'s device work: the coefficients up from ``lin_h``, the residual."""
        img, low, _, _ = self._last
        w = self._w if weights is None else weights
        nv, (Hc, Wc) = self.n_views, self._cap
        hp = 1.0 if self.highpass_px else 0.0
        lin = self._buffer("lin", tuple(lin_h.shape))
        copy_array(lin, lin_h)
        e = self._buffer("e", (nv, Hc, Wc))
        jt = self._buffer("jt", (nv, Hc, Wc), vec6f)
        reg = [self._t] if self._q else []
        self._launch(("residual", bool(jacobian), self._q, weights is None), regressor_kernels(self._q)[1],
                     (nv, Hc, Wc), [img, low, hp, self._y, w, self._o, *reg, self._ref_hw, nv, lin, e, jt,
                                    int(jacobian), self._diff])
        return e, jt

    def _residual_key(self, weights) -> tuple:
        """What a recorded residual reads besides the engine's kept buffers (:meth:`_segment`'s key)."""
        last = self._last
        return (last[0], last[1], weights, self._w, self._y, self._o, self._t, self._q, self._diff,
                self.highpass_px)

    def residual(self, s: dict) -> np.ndarray:
        """``(views, H, W)`` the weighted residual ``e = √w (y - A coef)`` at the centre of the last
        step's design (``s``: that :meth:`step`'s result), on the host (0 where unused)."""
        return self._residual_device(s, jacobian=False)[0].numpy()

    def sandwich(self, s: dict, Hinv: np.ndarray) -> np.ndarray:
        """``H⁻¹ meat H⁻¹`` (module docs) at the last step's design (``s``: its :meth:`step`): the
        residual's autocovariance, its taper and the meat on the device, one synchronisation."""
        self.sandwich_launch(s)
        return self.sandwich_result(Hinv)

    def sandwich_launch(self, s: dict, weights=None) -> None:
        """The first half of :meth:`sandwich`: its kernels and copies enqueued (no wait; an event of
        its own recorded after them, which :meth:`sandwich_result` waits for: a step enqueued after it
        is waited for without it). ``weights``: the weights ``w`` it reads (default the engine's now:
        the robust round's :meth:`scale_weights` keeps the frame's in ``_w0``). One recorded graph
        where :data:`~core.tracking.likelihood_segments.SEGMENT_GRAPHS` applies."""
        t0 = time.perf_counter()
        dev = self.device
        lin_h = self._lin_pinned(s, "lin")
        L = self.lag_px
        stride = self._sw_stride = max(1, int(SANDWICH_STRIDE))
        key = (self._residual_key(weights), L, stride, AUTOCOV_CHUNK, MEAT_CHUNK, AUTOCOV_ROWS, MEAT_HALF,
               COV_ON_READ, self.chunk, self.block_dim)
        self._segment("sandwich", key, lambda: self._sandwich_enqueue(lin_h, weights, L, stride))
        self._cov_host = self._bufs["cov"] if COV_ON_READ else self._host["cov"]
        if dev.is_cuda:  # (its own event: _wait waits for the engine's steps, this for the sandwich)
            if self.__dict__.get("_sw_event") is None:
                self._sw_event = wp.Event(dev)
            dev.stream.record_event(self._sw_event)  # (the engine's device's stream, its work's)
        self.timer.metric += time.perf_counter() - t0

    def _sandwich_enqueue(self, lin_h, weights, L: int, stride: int) -> None:
        """:meth:`sandwich_launch`'s device work (the meat into the pinned ``"meat"``; the autocovariance
        into the pinned ``"cov"`` too without :data:`COV_ON_READ`)."""
        nv, (Hc, Wc) = self.n_views, self._cap
        dev = self.device
        e, jt = self._residual_enqueue(lin_h, True, weights)
        w = self._w if weights is None else weights
        nl = (2 * L + 1) ** 2
        cov = self._buffer("cov", (nv, nl, 2), wp.float64)
        cov.zero_()
        chunk = AUTOCOV_CHUNK or self.chunk
        n_chunks = math.ceil(Hc * Wc / chunk)
        if stride > 1:  # (over the sub-lattice: likelihood_stride; the first half of the lags)
            chunk = max(64, chunk // (stride * stride))  # (as many thread blocks as every pixel's)
            dim, groups = autocov_rows_dim(nv, L, math.ceil(stride_cells((Hc, Wc), stride) / chunk))
            self._launch(("autocov_stride", weights is None), autocov_stride_kernel, dim,
                         [e, w, self._ref_hw, L, groups, chunk, stride, cov], self.block_dim)
        elif AUTOCOV_ROWS:  # (the first half of the lags; the rest mirrored)
            dim, groups = autocov_rows_dim(nv, L, n_chunks)
            self._launch(("autocov_rows", weights is None), autocov_rows_kernel, dim,
                         [e, w, self._ref_hw, L, groups, chunk, cov], self.block_dim)
        else:
            self._launch(("autocov", weights is None), autocov_kernel, (nv, nl // 2 + 1, n_chunks),
                         [e, w, self._ref_hw, L, chunk, cov], self.block_dim)
        taper = self._bufs.get(("taper", L))
        if taper is None:  # Bartlett's, per lag (rows, columns)
            d = np.arange(-L, L + 1)
            t = np.outer(1 - np.abs(d) / (L + 1), 1 - np.abs(d) / (L + 1)).ravel()
            taper = self._bufs[("taper", L)] = wp.array(t, dtype=wp.float64, device=dev)
        cw = self._buffer("cw", (nv, nl))
        self._launch("taper", taper_kernel, (nv, nl), [cov, taper, cw])
        acc = self._buffer("meat", (nv, 36), wp.float64)
        acc.zero_()
        mc = MEAT_CHUNK or self.chunk
        if stride > 1:
            mc = max(32, mc // (stride * stride))
            dim = (nv, math.ceil(stride_cells((Hc, Wc), stride) / mc))
            self._launch("meat_stride", meat_stride_kernel, dim,
                         [jt, cw, self._ref_hw, L, mc, stride, acc, int(MEAT_HALF)], self.block_dim)
        else:
            self._launch("meat", meat_kernel, (nv, math.ceil(Hc * Wc / mc)),
                         [jt, cw, self._ref_hw, L, mc, acc, int(MEAT_HALF)], self.block_dim)
        host = self._pinned("meat", (nv, 36), wp.float64, exact=True)
        copy_array(host, acc)
        if not COV_ON_READ:  # (autocorrelation reads the device's buffer, as a copy is, where COV_ON_READ)
            copy_array(self._pinned("cov", (nv, nl, 2), wp.float64, exact=True), cov)  # for autocorrelation

    def sandwich_result(self, Hinv: np.ndarray) -> np.ndarray:
        """The second half of :meth:`sandwich`: waits for the meat of the last
        :meth:`sandwich_launch`."""
        t0 = time.perf_counter()
        ev = self.__dict__.get("_sw_event")
        if ev is not None:
            wp.synchronize_event(ev)
        else:
            self._wait()
        meat = self._view(self._host["meat"]).reshape(self.n_views, 6, 6).sum(axis=0)
        meat = 0.5 * (meat + meat.T)
        stride = self.__dict__.get("_sw_stride", 1)
        if stride > 1:  # (the sub-lattice's sum: one pixel in stride²)
            meat = meat * float(stride * stride)
        self.timer.metric += time.perf_counter() - t0
        return Hinv @ meat @ Hinv

    @property
    def autocorrelation(self) -> np.ndarray | None:
        """Per view the weighted residual's autocorrelation over the lag window of the last
        :meth:`sandwich` (lag 0 at the centre), or None before one."""
        if self._cov_host is None:
            return None
        C = self._cov_host.numpy()
        c = C[..., 0] / np.maximum(C[..., 1], 1.0)
        nl, n = c.shape[1], 2 * self.lag_px + 1
        rho = c / np.maximum(c[:, nl // 2: nl // 2 + 1], 1e-30)
        return rho.reshape(-1, n, n)
