"""Pieces of the likelihood final stage's device work recorded once and replayed as one graph
(:class:`core.tracking.engine_likelihood.LikelihoodEngine`'s, :data:`SEGMENT_GRAPHS`): the frame's set-up
(:meth:`~core.tracking.engine_likelihood.LikelihoodEngine.set_frame`: the regions' item table up, their line
integrals and usable pixels made and counted, the count back, the weights and the high-pass: about eleven
runtime calls; with neighbours, where their DRRs go through the engine's own item table, that table up,
their DRRs and the neighbours taken out too: three more), the robust factors and the weights they scale
(:meth:`~core.tracking.likelihood_weights._RegionWeights.robust_scale`: the fit's coefficients up, the
residual, the factors' filter, sort and median, the weights' copy and product: about eleven) and the
sandwich (:meth:`~core.tracking.likelihood_confidence._Confidence.sandwich_launch`: the coefficients up, the
residual and its projections, the autocovariance, its taper, the meat and its copy back: eight) and a step's
moments table where its images are not the recorded step's (:meth:`~core.tracking.engine_likelihood.
LikelihoodEngine.step_launch`: the robust refinement's first step on the last design's images; the table
zeroed, summed and copied back: three).

A piece is a function that only enqueues device work (launches, copies, fills) on the engine's
buffers; the host's own writes (the pinned coefficients, the item table) and state stay outside it.
Its first call with a key runs it as it is (buffers made, launches recorded, the sort's scratch
reserved); its second call with the same key and no buffer of the engine's made since runs it under
:class:`warp.ScopedCapture` and launches the graph; later calls launch the graph. The key holds what
the piece's launches read besides the engine's kept buffers (the images' arrays, the settings and
module switches it reads); a buffer made anywhere in the engine (:class:`Tracked`: its buffer dicts
count their insertions) makes every piece record again. Each output size's buffer set keeps its own
pieces. The same kernels, copies and fills in the same order on the same buffers: the same values to
the bit (on Warp's CPU device its graphs replay the same compiled kernels; tests compare every pose and
covariance with the pieces run one call at a time). A capture the device refuses (its error said once,
:data:`FAILED`) leaves the pieces run one call at a time. A mixin of the engine's."""

from __future__ import annotations

import warnings

import warp as wp

__all__ = ["FAILED", "SEGMENT_GRAPHS", "Tracked"]

#: The stage's set-up, robust factors and sandwich each replayed as one recorded graph (module docs;
#: the same values). None: on CUDA devices only; True: on every device (the CPU's graphs: tests and the
#: CPU's timing, :mod:`core.studies.tracking.stage_host`); False: launched call by call, as before.
SEGMENT_GRAPHS: bool | None = None
#: the first capture that failed (its error; None: none did)
FAILED: str | None = None


class Tracked(dict):
    """A dict of an engine's buffers that counts the buffers put in it (:attr:`made`): a recorded piece
    is valid while the count it was recorded at stands."""

    made = 0

    def __setitem__(self, key, value) -> None:
        self.made += 1
        super().__setitem__(key, value)

    def setdefault(self, key, default=None):
        if key not in self:
            self[key] = default
        return self[key]


class _Segments:
    """:class:`~core.tracking.engine_likelihood.LikelihoodEngine`'s recorded pieces (its attributes:
    ``device``, ``_bufs``, ``_host``)."""

    def _segments_on(self) -> bool:
        on = self.device.is_cuda if SEGMENT_GRAPHS is None else SEGMENT_GRAPHS
        return bool(on) and FAILED is None

    def _segment(self, name: str, key: tuple, enqueue) -> None:
        """``enqueue()`` (device work only, module docs) run as it is, recorded, or replayed as its
        graph: the same work whichever."""
        if not self._segments_on():
            enqueue()
            return
        bufs, host = self._bufs, self._host
        segs = bufs.__dict__.setdefault("segs", {})  # (kept with the buffer set: an output size's)
        made = (bufs.made, host.made)
        hit = segs.get(name)
        same = hit is not None and hit[0] is host and hit[1] == made and hit[2] == key
        if same and hit[3] is not None:
            wp.capture_launch(hit[3])
            return
        if not same:  # (run as it is: its buffers and the launches' records made outside a capture)
            enqueue()
            segs[name] = (host, (bufs.made, host.made), key, None)
            return
        graph = self._capture(enqueue)
        if graph is None:
            return
        wp.capture_launch(graph)
        now = (bufs.made, host.made)
        segs[name] = (host, now, key, graph if now == made else None)  # (a buffer made: not kept)

    def _prep_enqueue(self, made, li, mask, others=None) -> None:
        """:meth:`set_frame`'s device work after the uploads: the regions made (``made``: the arguments of
        :meth:`~core.tracking.likelihood_frames._FrameRegions._roi_enqueue`, or None where done), the
        neighbours' DRRs taken out (``others``: the arguments of :meth:`~core.tracking.likelihood_frames.
        _FrameRegions._others_enqueue`, or None where done or none), the weights and the high-passes."""
        from .likelihood_kernels import highpass_kernel, weights_kernel

        nv, (Hc, Wc) = self.n_views, self._cap
        if made is not None:
            self._roi_enqueue(*made)
        if others is not None:
            self._others_enqueue(*others)
        low = self._blurred("w", li, nv, self._wtaps) if self._wtaps is not None else li
        self._launch("weights", weights_kernel, (nv, Hc, Wc), [low, mask, self._w])
        pairs = ((self._y_raw, self._y), (self._o_raw, self._o)) if self._o_raw is not None else \
            ((self._y_raw, self._y),)
        if self._o_raw is None:  # no neighbours' regressor: its high-pass is 0
            self._o.zero_()
        for i, (src, dst) in enumerate(pairs):
            if self.highpass_px:
                low = self._blurred("y", src, nv)
                self._launch(("highpass", i), highpass_kernel, (nv, Hc, Wc), [src, low, 1.0, dst])
            else:
                wp.copy(dst, src)

    def _moments_enqueue(self, img, low) -> None:
        """:meth:`step_launch`'s moments table of the images ``img`` / ``low`` and its copy to the host."""
        from .engine_buffers import copy_array
        from .likelihood_fast import wls_moments_tri_kernel
        from .likelihood_kernels import regressor_kernels

        nv, (Hc, Wc) = self.n_views, self._cap
        acc, host = self._tables_q()
        acc.zero_()
        chunk = self._moments_chunk()
        n_chunks = -(-Hc * Wc // chunk)
        hp = 1.0 if self.highpass_px else 0.0
        reg = [self._t] if self._q else []
        kernel = wls_moments_tri_kernel if self._tri else regressor_kernels(self._q)[0]
        self._launch(("moments", self._q, self._tri), kernel, (nv, n_chunks),
                     [img, low, hp, self._y, self._w, self._o, *reg, self._ref_hw, nv, chunk, acc,
                      self._diff], self.block_dim)
        copy_array(host, acc)

    def _capture(self, enqueue):
        """``enqueue()`` captured as a graph, or run as it is where the device refused (None)."""
        global FAILED
        dev = self.device
        try:
            with wp.ScopedCapture(device=dev) as cap:
                enqueue()
            return cap.graph
        except Exception as e:  # (a capture the device refused: the pieces call by call, said once)
            if FAILED is None:
                FAILED = repr(e)
                warnings.warn(f"likelihood stage: a piece's graph not captured ({e!r}); its calls made one "
                              f"by one", RuntimeWarning, stacklevel=3)
            if dev.is_cuda:
                wp.synchronize_device(dev)
            enqueue()
            return None
