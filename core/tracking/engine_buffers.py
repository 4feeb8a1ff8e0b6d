"""The Gauss–Newton engine's device buffers (:class:`core.tracking.engine.GaussNewtonCost`): one set
per output size with the pipelines recorded on it (:class:`_Buffers`, at most :data:`_BUFFER_SETS`
kept), the recorded launches of a frame's preparation, the pinned uploads, the blur taps per pixel
size, and the siblings that share a cost's prepared regions: :class:`_EngineBuffers`, a mixin of the
engine's cost.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Self

import numpy as np
import warp as wp
import warp._src.context as _wp_context

from .cost import CostTimer, _in_pixels
from .launch_inputs import same_inputs  # (the same shortcut as the stage's recorded launches)

#: Buffer sets (output sizes) an engine keeps with their pipelines (:meth:`_EngineBuffers._allocate`):
#: over the 100-frame walking trial at 1024² the tracking frames' search regions take 2-4 sizes per
#: bone (32-pixel steps), the first frame and its restarts two more.
_BUFFER_SETS = 6


_SERIAL = itertools.count()

#: Switch (on since the H200 measurement below; CUDA devices): a frame's preparation in
#: :meth:`~core.tracking.engine.GaussNewtonCost.set_frame` (full resolution, the regions read from the
#: shared upload of the frame, no neighbours subtracted: one bone) — the pose geometry and blur taps
#: uploaded from pinned memory, the statistics zeroed, the regions prepared, smoothed and differentiated,
#: the usable-pixel count copied back: about twelve runtime calls, 10-20 us of host time each on one
#: NVIDIA H100's host (cProfile at ad38ce9) — recorded and replayed as one CUDA graph, one per sequence of
#: operations (kept per engine, :data:`PREP_GRAPHS`); the same operations in the same order on the same
#: buffers, so the same results to the bit. On the CPU the recorded operations run in order (a test's path).
#: Timed on one NVIDIA H100 at f4f4b08 (frame_profile --bones one --variants, 4 alternated rounds, ms a frame
#: after the first): off 7.52/8.57/7.91/7.20, on 5.74/7.62/7.43/8.08, captured without a warning; left off
#: then. Its host time alone on one NVIDIA H200's host at 4f533f9
#: (``python -m core.studies.tracking.search_host --device cuda:0 --prep-graph off,on,off,on``, the bench's
#: one-bone trial at 1024², 100 frames; ``resources/benchmarks/tracking_search_host_h200.json``):
#: set_frame 462 / 514 us a frame off, 304 / 272 us on.
PREP_GRAPH = True
PREP_GRAPHS = 16
_CAPTURE_CPU = False  # (tests: the CPU's recorded operations captured too, as Warp's CPU graphs)


def copy_array(dst: wp.array, src: wp.array, count: int = 0) -> None:
    """``wp.copy(dst, src, 0, 0, count)`` of contiguous arrays: between a CUDA array and host memory
    the runtime's copy on the CUDA side's current stream (``wp_memcpy_h2d`` / ``wp_memcpy_d2h``, what
    ``wp.copy`` calls there) without ``wp.copy``'s argument checks and dispatch, the same bytes; any
    other pair (host to host, device to device, strided arrays) through ``wp.copy``. The engine's
    per-frame uploads (:meth:`~core.tracking.engine.GaussNewtonCost.set_frame`): ``wp.copy`` took
    18.6 us of host time per call on one NVIDIA H100's host (bae210d, 16 copies a frame of the
    talus with the likelihood stage; in ``resources/benchmarks/tracking_bench_final_bae210d_h100.json``'s
    diagnostic every such copy bypassed so gave the two fastest of twelve runs, 6.55 and 6.64 ms a
    frame after the first, its third 7.33, the other arms' 6.67-9.27; not timed on its own).
    ``count``: elements of ``src`` (0: all of it), at most ``dst``'s."""
    if type(dst) is wp.array and type(src) is wp.array and dst.is_contiguous and src.is_contiguous:
        n = int(count) or src.size
        if n < 0 or n > src.size or n > dst.size or wp.types.type_size_in_bytes(dst.dtype) != \
                wp.types.type_size_in_bytes(src.dtype):  # (a negative count: a huge size_t at the runtime)
            raise ValueError(f"copy_array: {n} elements do not fit the arrays ({src.size}, {dst.size})")
        nbytes = n * wp.types.type_size_in_bytes(src.dtype)
        runtime = _wp_context.runtime  # (set by wp.init: looked up now, not imported at each call)

        if dst.device.is_cuda and src.device.is_cpu:
            if not runtime.core.wp_memcpy_h2d(dst.device.context, dst.ptr, src.ptr, nbytes,
                                              dst.device.stream.cuda_stream):
                raise RuntimeError(f"Warp copy error: {runtime.get_error_string()}")
            return
        if src.device.is_cuda and dst.device.is_cpu:
            if not runtime.core.wp_memcpy_d2h(src.device.context, dst.ptr, src.ptr, nbytes,
                                              src.device.stream.cuda_stream):
                raise RuntimeError(f"Warp copy error: {runtime.get_error_string()}")
            return
    wp.copy(dst, src, 0, 0, count)


@dataclass(eq=False)
class _Buffers:
    """The fluoroscope buffers of one output size of an engine, the pipelines recorded on them
    (its own by batch size, and its siblings') and the host preparation's pinned buffers."""

    cap: tuple
    raw0: object
    raw: object
    ftmp: object
    fluoro: object
    fgrad: object
    fmask: object
    blur: object
    blur_taps: object
    ys: object = None  # the noise correction's smoothed, unsubtracted line integrals (joint tracking)
    serial: int = field(default_factory=lambda: next(_SERIAL))  # which buffers (stage)
    pipes: dict = field(default_factory=dict)
    sibling_pipes: dict = field(default_factory=dict)
    host_raw_wp: object = None
    host_mask_wp: object = None


def _run_op(op: tuple) -> None:
    """One recorded operation (:meth:`_EngineBuffers._copy`, ``_zero``, ``_launch``)."""
    if op[0] == 0:
        copy_array(op[1], op[2], op[3])
    elif op[0] == 1:
        op[1].zero_()
    else:
        op[1].launch()


class _EngineBuffers:
    """The buffer handling of :class:`core.tracking.engine.GaussNewtonCost` (module docs)."""

    _rec = None  # the operations recorded (PREP_GRAPH), or None: each runs as it is asked for
    _prep_graphs = None  # key -> (graph, operations): the recorded preparations captured
    _prep_failed = False  # a capture failed: this engine's preparations run one by one

    def _copy(self, dst: wp.array, src: wp.array, count: int = 0) -> None:
        """:func:`copy_array` now, or recorded (:data:`PREP_GRAPH`)."""
        if self._rec is None:
            copy_array(dst, src, count)
        else:
            self._rec.append((0, dst, src, count))

    def _zero(self, a: wp.array) -> None:
        if self._rec is None:
            a.zero_()
        else:
            self._rec.append((1, a, None, 0))

    def _record(self) -> None:
        """Record the operations asked for from here on (:data:`PREP_GRAPH`, a CUDA device; on the CPU too
        where the switch is set, to run them in order at :meth:`_replay`)."""
        if PREP_GRAPH and not self._prep_failed:
            self._rec = []

    def _flush(self) -> None:
        """Run the operations recorded so far, in order, and record no more (a path no graph takes)."""
        ops, self._rec = self._rec, None
        for op in ops or ():
            _run_op(op)

    def _replay(self) -> None:
        """The recorded operations enqueued: as one CUDA graph (captured the first time this sequence of
        operations on these buffers is seen), or in order."""
        ops, self._rec = self._rec, None
        if not ops:
            return
        if not (self.device.is_cuda or _CAPTURE_CPU):
            for op in ops:
                _run_op(op)
            return
        if self._prep_graphs is None:
            self._prep_graphs = {}
        key = tuple((op[0], id(op[1]), id(op[2]), op[3]) for op in ops)
        hit = self._prep_graphs.get(key)
        if hit is None:
            try:
                with wp.ScopedCapture(device=self.device) as cap:
                    for op in ops:
                        _run_op(op)
            except Exception as e:  # (a capture the device refused: this engine's operations one by one)
                import warnings

                self._prep_failed = True
                warnings.warn(f"Gauss-Newton engine: a frame's preparation not captured as a CUDA graph "
                              f"({e!r}); its operations run one by one", RuntimeWarning, stacklevel=2)
                wp.synchronize_device(self.device)
                for op in ops:
                    _run_op(op)
                return
            while len(self._prep_graphs) >= PREP_GRAPHS:
                self._prep_graphs.pop(next(iter(self._prep_graphs)))
            hit = self._prep_graphs[key] = (cap.graph, ops)  # (the operations' objects kept with it)
        wp.capture_launch(hit[0])

    def _launch(self, name: str, kernel, dim: tuple, inputs: list) -> None:
        """Launch ``kernel`` through a recorded launch, kept while its dimensions, arrays and
        values stay the same (the frame preparation's launches from frame to frame)."""
        last = self._cmd_last.get(name)
        if last is not None and last[0] == dim and same_inputs(last[1], inputs):  # this name's last launch
            if self._rec is None:
                last[2].launch()
            else:
                self._rec.append((2, last[2], None, 0))
            return
        key = (name, dim, tuple([(a.ptr, a.shape) if isinstance(a, wp.array)
                                 else a if isinstance(a, (int, float)) else id(a) for a in inputs]))
        cmd = self._cmds.get(key)
        if cmd is None:  # kept per buffer set too (the arrays' addresses are in the key)
            cmd = wp.launch(kernel, dim=dim, inputs=inputs, device=self.device, record_cmd=True)
            if len(self._cmds) >= 8 * _BUFFER_SETS:
                self._cmds.pop(next(iter(self._cmds)))
            self._cmds[key] = cmd
        self._cmd_last[name] = (dim, list(inputs), cmd)
        if self._rec is None:
            cmd.launch()
        else:
            self._rec.append((2, cmd, None, 0))

    def _put(self, name: str, dst: wp.array, values: np.ndarray) -> None:
        """Copy ``values`` into the device array ``dst`` through a pinned buffer of this cost's
        (no allocation; :meth:`set_frame` synchronises before it writes a pinned buffer again)."""
        hit = self._pinned.get(name)
        if hit is None or hit[0].shape != dst.shape:
            buf = wp.zeros(dst.shape, dtype=dst.dtype, device="cpu", pinned=self.device.is_cuda)
            hit = self._pinned[name] = (buf, buf.numpy())
        hit[1][:] = values
        self._copy(dst, hit[0])

    def _taps(self, px_mm: float):
        """The DRR and fluoroscope blur taps at this pixel size (kept for the next frames)."""
        from ..similarity.batched import gaussian_weights

        opts = _in_pixels({k: v for k, v in self.term.options.items()
                           if k in ("fluoro_sigma", "drr_sigma", "fluoro_sigma_mm", "drr_sigma_mm")}, px_mm)
        key = (float(opts.get("fluoro_sigma", 0.0)), float(opts.get("drr_sigma", 0.0)))
        self._f_sig = key[0]
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
                cap=cap, raw0=wp.zeros((nv, *cap), dtype=wp.float32, device=dev),
                raw=wp.zeros((nv, *cap), dtype=wp.float32, device=dev),
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
        self._raw0, self._raw, self._ftmp, self._fluoro = b.raw0, b.raw, b.ftmp, b.fluoro
        self._fgrad, self._fmask = b.fgrad, b.fmask
        self._blur, self._blur_taps = b.blur, b.blur_taps
        self._pipes = b.pipes

    def sibling(self, k: int) -> Self:
        """The ``k``-th sibling of this cost: its own launches, buffers of results and timer, the
        regions prepared by this cost's last :meth:`set_frame` (shared, read only), so that
        several searches of the same bone in the same frame (the restarts of
        :func:`core.tracking.verify.verify_start`) can have steps in flight together."""
        import copy

        sib = self._siblings.get(k)
        if sib is None:
            sib = copy.copy(self)
            sib._siblings, sib._pipes, sib._tables, sib._cmds, sib._cmd_last = {}, {}, {}, {}, {}
            sib._rec, sib._prep_graphs = None, None
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
