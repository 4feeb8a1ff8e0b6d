"""The likelihood final stage's device work (:class:`core.tracking.engine_likelihood.
LikelihoodEngine`'s): its named buffers, its kernels launched from recorded launches while their
arguments stay the same, and the event a result waits for (the engine's own work only, so that
several engines' refinements run side by side). A mixin of the engine's."""

from __future__ import annotations

import warp as wp


class _Launches:
    """:class:`~core.tracking.engine_likelihood.LikelihoodEngine`'s buffers, launches and waits (its
    attributes: ``device``, ``_bufs``, ``_cmds``, ``_done``)."""

    def _buffer(self, name: str, shape: tuple, dtype=wp.float32):
        """The engine's device buffer ``name`` of ``shape`` (made anew where its shape changed)."""
        b = self._bufs.get(name)
        if b is None or b.shape != shape:
            b = self._bufs[name] = wp.zeros(shape, dtype=dtype, device=self.device)
        return b

    def _launch(self, name, kernel, dim: tuple, inputs: list, block_dim: int | None = None) -> None:
        """``kernel`` launched on ``inputs`` (``block_dim``: tiled), the launch recorded under
        ``name`` and launched again as recorded while its arguments (arrays by address, shape and
        strides; numbers by value) stay the same: the same kernel on the same arguments, without
        building the launch's parameters each time."""
        key = (tuple(dim), block_dim, *((a.ptr, a.shape, a.strides, a.dtype) if isinstance(a, wp.array) else a
                                        for a in inputs))
        hit = self._cmds.get(name)
        if hit is None or hit[0] != key:
            if block_dim is None:
                cmd = wp.launch(kernel, dim=dim, inputs=inputs, device=self.device, record_cmd=True)
            else:
                cmd = wp.launch_tiled(kernel, dim=dim, block_dim=block_dim, inputs=inputs, device=self.device,
                                      record_cmd=True)
            hit = self._cmds[name] = (key, cmd)
        hit[1].launch()

    def _record(self) -> None:
        """Mark the work enqueued so far (:meth:`_wait` waits for it and nothing after)."""
        if self.device.is_cuda:
            if self._done is None:
                self._done = wp.Event(self.device)
            wp.record_event(self._done)

    def _wait(self) -> None:
        """Wait for the work enqueued up to the last :meth:`_record` (other engines' work enqueued
        since runs on)."""
        if self._done is not None:
            wp.synchronize_event(self._done)
        else:
            wp.synchronize_device(self.device)
