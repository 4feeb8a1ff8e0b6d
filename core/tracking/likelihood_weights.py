"""The likelihood final stage's weights of the region (:class:`core.tracking.engine_likelihood.
LikelihoodEngine`'s): the frame's expected counts scaled per pixel and back (the stage's support
mask, the robust factors: :mod:`core.tracking.final_stage`), the robust factors made on the device,
and the bone's DRR support. A mixin of the engine's."""

from __future__ import annotations

import numpy as np
import warp as wp

from .likelihood_kernels import _times_kernel, robust_factors_device


@wp.kernel
def _positive_count_kernel(w: wp.array3d(dtype=wp.float32), chunk: int, out: wp.array(dtype=wp.float64)):
    """out[v] += the pixels of view v with a positive weight. dim = (views, chunks)."""
    v, ch, lane = wp.tid()
    bd = wp.block_dim()
    W = w.shape[2]
    start = ch * chunk
    stop = wp.min(w.shape[1] * W, start + chunk)
    n = float(0.0)  # noqa: UP018
    for p in range(start + lane, stop, bd):
        r = p // W
        if w[v, r, p - r * W] > 0.0:
            n += 1.0
    t = wp.tile_sum(wp.tile(n))
    if lane == 0:
        wp.atomic_add(out, v, wp.float64(t[0]))


class _RegionWeights:
    """:class:`~core.tracking.engine_likelihood.LikelihoodEngine`'s weights of the region (its
    attributes: ``n_views``, ``bone``, ``device``, ``_w``, ``_cap``, ``_ref_hw``, buffers, launches,
    the residual of :class:`~core.tracking.likelihood_confidence._Confidence`)."""

    def reset_weights(self) -> None:
        """The weights back to the expected counts of :meth:`set_frame` (no factors)."""
        if self._w0_set:
            wp.copy(self._w, self._w0)
            if self._count_weights:  # (some were zeroed: the count of the expected counts again)
                self.count_weights()

    def count_weights(self) -> None:
        """The pixels with a positive weight counted on the device: :attr:`n_pixels` (the χ²/N of the
        steps and the independent-pixel covariance) from the next step's synchronisation on, instead of
        the region's usable pixels (a support mask or the rim band weighs some of them 0)."""
        nv, (Hc, Wc) = self.n_views, self._cap
        out = self._buffer("wcount", (nv,), wp.float64)
        out.zero_()
        self._launch("wcount", _positive_count_kernel, (nv, -(-Hc * Wc // self.chunk)),
                     [self._w, self.chunk, out], self.block_dim)
        host = self._pinned("wcount", (nv,), wp.float64, exact=True)
        wp.copy(host, out)
        self._count_weights = True
        self._wcount_pending = True

    def _take_weights_count(self) -> None:
        """:meth:`count_weights`' count (copied before the last synchronisation) as :attr:`n_pixels`."""
        self._wcount_pending = False
        self.n_pixels = round(float(self._view(self._host["wcount"]).sum()))

    def scale_weights(self, factor: np.ndarray) -> None:
        """The expected counts of :meth:`set_frame` times ``factor (views, H, W)`` (per pixel, on
        the host or a Warp array on the device; the regions' padded layout of :meth:`residual`) from
        now on."""
        nv, (Hc, Wc) = self.n_views, self._cap
        if not self._w0_set:
            self._w0 = self._buffer("w0", (nv, Hc, Wc))
            wp.copy(self._w0, self._w)
            self._w0_set = True
        if isinstance(factor, wp.array):  # already on the device (robust_weights: positive where w0 is)
            f = factor
        else:
            f = self._buffer("wf", (nv, Hc, Wc))
            f.assign(np.asarray(factor, dtype=np.float32).reshape(nv, Hc, Wc))
        self._launch("times", _times_kernel, (nv, Hc, Wc), [self._w0, f, self._w])
        if not isinstance(factor, wp.array) or self._count_weights:  # (a factor 0 somewhere: counted)
            self.count_weights()

    def robust_weights(self, s: dict, k: float, *, sigma_px: float = 2.0, kind: str = "cauchy"):
        """The robust factors of the weighted residual at the centre of the last step's design
        (``s``: that :meth:`step`'s result) and the current weights' usable pixels, on the device
        (:func:`robust_factors_device`; a Warp array for :meth:`scale_weights`)."""
        e, _ = self._residual_device(s, jacobian=False, pin="lin_robust")  # (a sandwich's may be pending)
        return robust_factors_device(e, self._w, k, sigma_px=sigma_px, kind=kind, device=self.device,
                                     bufs=self._bufs, launch=self._robust_launch)

    def robust_scale(self, s: dict, k: float, *, sigma_px: float = 2.0, kind: str = "cauchy") -> None:
        """:meth:`scale_weights` of :meth:`robust_weights`' factors: the same work, one recorded graph where
        :data:`~core.tracking.likelihood_segments.SEGMENT_GRAPHS` applies (the fit's coefficients written
        into their pinned buffer first, the frame's weights kept in ``_w0`` after)."""
        if self._count_weights:  # (the weights counted again after the product: the calls one by one)
            self.scale_weights(self.robust_weights(s, k, sigma_px=sigma_px, kind=kind))
            return
        from .likelihood_kernels import MEDIAN_BISECT, MEDIAN_ONE_SORT

        lin_h = self._lin_pinned(s, "lin_robust")  # (a sandwich's upload may be pending)
        first = not self._w0_set
        key = (self._residual_key(None), float(k), float(sigma_px), str(kind), first, MEDIAN_ONE_SORT,
               MEDIAN_BISECT, self.n_views)
        self._segment("robust", key, lambda: self._robust_enqueue(lin_h, k, sigma_px, kind, first))
        if first:
            self._w0 = self._bufs["w0"]
            self._w0_set = True

    def _robust_enqueue(self, lin_h, k: float, sigma_px: float, kind: str, first: bool) -> None:
        """:meth:`robust_scale`'s device work."""
        e, _ = self._residual_enqueue(lin_h, False, None)
        f = robust_factors_device(e, self._w, k, sigma_px=sigma_px, kind=kind, device=self.device,
                                  bufs=self._bufs, launch=self._robust_launch)
        nv, (Hc, Wc) = self.n_views, self._cap
        w0 = self._buffer("w0", (nv, Hc, Wc))
        if first:
            wp.copy(w0, self._w)
        self._launch("times", _times_kernel, (nv, Hc, Wc), [w0, f, self._w])

    def _robust_launch(self, name, kernel, dim, inputs) -> None:
        """:func:`robust_factors_device`'s launches recorded (:meth:`_launch`)."""
        self._launch(("robust", name), kernel, dim, inputs)

    def support(self, x=None) -> np.ndarray:
        """``(views, H, W)`` the bone's DRR at ``x`` (default the base pose) in the regions'
        padded layout, on the host (0 outside each view's region)."""
        x = np.zeros((1, 6)) if x is None else np.asarray(x, dtype=float).reshape(1, 6)
        img = self._render(self.poses(x)[:, None], (self.bone,)).numpy()[: self.n_views]
        out = np.zeros((self.n_views, *self._cap), np.float32)
        for v, (h, w) in enumerate(self._ref_hw.numpy()):
            out[v, :h, :w] = np.nan_to_num(img[v, :h, :w])
        return out
