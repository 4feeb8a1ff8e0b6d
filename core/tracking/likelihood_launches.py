"""The likelihood final stage's device work (:class:`core.tracking.engine_likelihood.
LikelihoodEngine`'s): its named buffers, its kernels launched from recorded launches while their
arguments stay the same, and the event a result waits for (the engine's own work only, so that
several engines' refinements run side by side). A mixin of the engine's."""

from __future__ import annotations

import warp as wp

from .launch_inputs import same_inputs
from .likelihood_segments import Tracked

#: The engine's device buffers and recorded launches kept per output size (:meth:`_Launches._use_buffers`):
#: a region whose size comes back (the regions' sizes, in 32-pixel steps, changed at 3-12 of 30
#: frames per bone on the acceptance trial at 1024², among 2-5 sizes) reuses them and the step graphs
#: captured on them; the same kernels on the same sizes: the same values. Off: one set, made anew
#: where a size changes (and the step's graph captured again), as first written.
BUFFERS_PER_SIZE = True
#: sizes whose buffers an engine keeps (least recently used out; the step graphs keep as many)
KEEP_SIZES = 4
#: :meth:`_Launches._launch` launches its recorded launch without building the arguments' key where they
#: are the objects of its last call (arrays the same objects, numbers equal: a Warp array's address, shape
#: and strides do not change, so the key would be the same); the same launches. Off: the key built and
#: compared at every launch, as first written (20 launches a one-bone frame; on one NVIDIA H100's host
#: ``_launch`` and its key's generator took 0.17 ms a frame under cProfile, ``profile_one_bone_ad38ce9``).
SAME_OBJECTS = True


class _Launches:
    """:class:`~core.tracking.engine_likelihood.LikelihoodEngine`'s buffers, launches and waits (its
    attributes: ``device``, ``_bufs``, ``_cmds``, ``_done``)."""

    def _view(self, host):
        """``host.numpy()`` of a small pinned host buffer of the engine's (the fit's coefficients, the
        meat, the regions' item table and counts), made once per buffer and kept (the same memory:
        Warp makes the numpy view anew on every call)."""
        views = self.__dict__.setdefault("_views", {})
        hit = views.get(id(host))
        if hit is None or hit[0] is not host:
            if len(views) >= 32:
                views.clear()
            hit = views[id(host)] = (host, host.numpy())
        return hit[1]

    def _use_buffers(self, key) -> None:
        """The device buffers and recorded launches of ``key`` (the frame's output size) from now on:
        each size's kept (the last :data:`KEEP_SIZES`), so that a region that comes back to a size it
        had finds its buffers, its recorded launches and the step graphs made on them
        (:mod:`~core.tracking.likelihood_graph`: keyed by the buffers' addresses) instead of
        allocating, recording and capturing them again (:data:`BUFFERS_PER_SIZE`)."""
        sets = self.__dict__.setdefault("_buf_sets", {})
        cur = self.__dict__.get("_buf_key")
        if cur == key:
            return
        if cur is not None:
            sets[cur] = (self._bufs, self._cmds)
        hit = sets.pop(key, None)
        if hit is None:
            hit = (Tracked(), {})
            while len(sets) >= KEEP_SIZES:
                sets.pop(next(iter(sets)))
        sets[key] = hit  # (most recently used last)
        self._bufs, self._cmds = hit
        self._buf_key = key

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
        hit = self._cmds.get(name)
        if (SAME_OBJECTS and hit is not None and hit[2] == dim and hit[3] == block_dim
                and same_inputs(hit[4], inputs)):  # (the same objects: the same key)
            hit[1].launch()
            return
        key = (tuple(dim), block_dim, *((a.ptr, a.shape, a.strides, a.dtype) if isinstance(a, wp.array) else a
                                        for a in inputs))
        if hit is None or hit[0] != key:
            if block_dim is None:
                cmd = wp.launch(kernel, dim=dim, inputs=inputs, device=self.device, record_cmd=True)
            else:
                cmd = wp.launch_tiled(kernel, dim=dim, block_dim=block_dim, inputs=inputs, device=self.device,
                                      record_cmd=True)
        else:
            cmd = hit[1]
        self._cmds[name] = (key, cmd, dim, block_dim, list(inputs))
        cmd.launch()

    def _record(self) -> None:
        """Mark the work enqueued so far (:meth:`_wait` waits for it and nothing after)."""
        if self.device.is_cuda:
            if self._done is None:
                self._done = wp.Event(self.device)
            self.device.stream.record_event(self._done)  # (the stream its work went on)

    def _wait(self) -> None:
        """Wait for the work enqueued up to the last :meth:`_record` (other engines' work enqueued
        since runs on)."""
        if self._done is not None:
            wp.synchronize_event(self._done)
        else:
            wp.synchronize_device(self.device)
