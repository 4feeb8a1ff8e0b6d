"""A likelihood final-stage step as one recorded piece of device work (:class:`core.tracking.
engine_likelihood.LikelihoodEngine`'s, :data:`~core.tracking.engine_likelihood.STEP_GRAPH`): the copy
of the design's 13 parameter rows from pinned memory, their DRR item table computed on the device
(:class:`~core.tracking.engine_render.DeviceRender`, the tracker's engine's: the same arithmetic as
the host's table in float64, the same float32 table), the DRR launch into the engine's own images,
the design's centre and differences (:func:`~core.tracking.likelihood_fast.design_diff_kernel`),
the two blur passes of the high-pass, the moments table and its copy to pinned host memory —
captured as one CUDA graph on a CUDA device (enqueued launch by launch elsewhere). A step is then a
copy of 78 numbers into pinned memory and one graph launch, where the plain step filled the item
table on the host, uploaded it through the renderer's pinned buffer (waiting for that buffer's
previous upload: the device's work on every step enqueued before it, the bones' stages side by
side sharing it) and made 7 launches. The same values as the plain step's (its kernels, buffers of
its own). With it the frame's neighbours' DRRs (:meth:`_StepGraphs._render_own`) go up through the
engine's own pinned item table, not the renderer's shared one. A mixin of the engine's."""

from __future__ import annotations

import math
import warnings

import warp as wp

from ..render import _kernels as RK
from ..render._kernels import ITEM_COLS
from .engine_buffers import copy_array
from .engine_render import DeviceRender, item_table
from .likelihood_fast import blur_block_dim, blur_block_kernel, design_diff_kernel, wls_moments_tri_kernel
from .likelihood_kernels import wls_moments_kernel

__all__ = ["StepWork"]

#: the first capture that failed (its error; None: none did)
FAILED: str | None = None
#: graphs an engine keeps (by output size and the frame buffers they read; least recently used out)
KEEP = 4
#: a step's work captured on Warp's CPU device too (its CPU graphs: the path a CUDA device takes, for
#: :mod:`core.studies.tracking.stage_host`'s timing and tests); off: launched one by one there
CAPTURE_CPU = False


class StepWork:
    """One step's recorded device work for one output size and set of frame buffers (module docs):
    ``x_np`` the design's pinned parameter rows, ``dd`` / ``low`` its centre-and-differences images
    and their low-pass (the plain step's ``img`` and ``low`` with ``diff`` 1)."""

    def __init__(self, eng, cap: tuple, render: tuple, key: tuple) -> None:
        dev = eng.device
        nv = eng.n_views
        Hc, Wc = cap
        self.key = key
        self.x_host, self.x_dev, self.images, self.render = render  # (the graph's buffers kept alive)
        images = self.images
        self.x_np = self.x_host.numpy()
        self.dd = wp.zeros((7 * nv, Hc, Wc), dtype=wp.float32, device=dev)
        self.tmp = wp.zeros(self.dd.shape, dtype=wp.float32, device=dev)
        self.low = wp.zeros(self.dd.shape, dtype=wp.float32, device=dev)
        acc, host = eng._acc, eng._host_acc
        self.acc = acc
        cmds = [wp.launch(design_diff_kernel, dim=self.dd.shape, device=dev, record_cmd=True,
                          inputs=[images, nv, eng._ref_hw, self.dd, 0])]
        for a, b, axis in ((self.dd, self.tmp, 1), (self.tmp, self.low, 0)):
            cmds.append(wp.launch(blur_block_kernel, dim=blur_block_dim(self.dd.shape, axis), device=dev,
                                  record_cmd=True, inputs=[a, b, eng._taps, eng._ref_hw, nv, axis]))
        chunk = eng._moments_chunk()
        self.tri = bool(eng._moments_tri())
        kernel = wls_moments_tri_kernel if self.tri else wls_moments_kernel
        self.moments = wp.launch_tiled(kernel, dim=(nv, math.ceil(Hc * Wc / chunk)), block_dim=eng.block_dim,
                                       device=dev, record_cmd=True,
                                       inputs=[self.dd, self.low, 1.0, eng._y, eng._w, eng._o, eng._ref_hw,
                                               nv, chunk, acc, 1])
        self.cmds = cmds
        self.copy = (host, acc)
        self.graph = None
        if dev.is_cuda or CAPTURE_CPU:
            try:
                with wp.ScopedCapture(device=dev) as cap_:
                    self._enqueue()
                self.graph = cap_.graph
            except Exception as e:  # (a capture the device refused: the launches one by one, said once)
                global FAILED
                if FAILED is None:
                    FAILED = repr(e)
                    warnings.warn(f"likelihood stage: a step's CUDA graph not captured ({e!r}); "
                                  f"its launches made one by one", RuntimeWarning, stacklevel=2)
                wp.synchronize_device(dev)

    def _enqueue(self) -> None:
        wp.copy(self.x_dev, self.x_host)
        for cmd in self.render:
            cmd.launch()
        for cmd in self.cmds:
            cmd.launch()
        self.acc.zero_()
        self.moments.launch()
        wp.copy(*self.copy)

    def replay(self) -> None:
        """Enqueue the step (its rows written into :attr:`x_np` first)."""
        if self.graph is not None:
            wp.capture_launch(self.graph)
        else:
            self._enqueue()


class _StepGraphs:
    """:class:`~core.tracking.engine_likelihood.LikelihoodEngine`'s recorded steps (its attributes:
    the frame's buffers ``_y``, ``_w``, ``_o``, ``_ref_hw``, ``_cap``, the geometry ``base``,
    ``center``, ``roi``)."""

    def _step_work(self) -> StepWork:
        """The recorded step for the frame's output size and buffers (made and, on CUDA, captured
        where there is none yet); the device geometry uploaded where it changed. Kept for the frame
        (:meth:`~core.tracking.engine_likelihood.LikelihoodEngine.set_frame` drops it: its geometry and
        buffers are the frame's), for the moments' settings it was made with."""
        settings = (self._moments_chunk(), self._moments_tri(), self.block_dim, bool(CAPTURE_CPU))
        fw = self.__dict__.get("_frame_work")
        if fw is not None and fw[0] == settings:
            return fw[1]
        dr = self.__dict__.get("_dev_render")
        if dr is None:
            dr = self._dev_render = DeviceRender(self)
            self._graphs, self._renders = {}, {}
        dr.upload(self.base, self.center, self.roi)
        cap = tuple(self._cap)
        key = (cap, *(a.ptr for a in (self._y, self._w, self._o, self._ref_hw, self._taps, self._acc)),
               self._moments_chunk(), self._moments_tri(), self.block_dim, bool(CAPTURE_CPU))
        hit = self._graphs.pop(key, None)
        if hit is None:
            render = self._renders.get(cap)
            if render is None:
                if len(self._renders) >= KEEP:
                    self._renders.pop(next(iter(self._renders)))
                render = self._renders[cap] = dr.record(self, 13, *cap)
            if len(self._graphs) >= KEEP:
                self._graphs.pop(next(iter(self._graphs)))
            hit = StepWork(self, cap, render, key)
        self._graphs[key] = hit  # (most recently used last)
        self._frame_work = (settings, hit)
        return hit

    def _render_own(self, P, bones: tuple, launch: bool = True):
        """:func:`~core.tracking.engine_render.render_items` (the same item table, the same launch)
        through the engine's own pinned buffer, item table and images instead of the renderer's
        shared ones: no wait for another engine's upload from them (the neighbours' DRRs of
        :meth:`set_frame`; its wait for the engine's last uploads covers this buffer's). ``launch`` False:
        the item table written into the pinned buffer, its copy and the launch not enqueued; the pinned
        buffer, its numpy view, the device's table, the images and the recorded launch returned."""
        r = self.renderer
        table = item_table(self, P, bones)
        H, W = self._cap  # (render_items' size: the ROIs fit the cap)
        n = table.shape[0] * table.shape[1] * table.shape[2]
        own = self.__dict__.setdefault("_own_renders", {})
        got = own.get((n, H, W))
        if got is None:
            dev = self.device
            if len(own) >= KEEP:
                own.pop(next(iter(own)))
            host = wp.zeros((n, ITEM_COLS), dtype=wp.float32, device="cpu", pinned=dev.is_cuda)
            items = wp.zeros((n, ITEM_COLS), dtype=wp.float32, device=dev)
            out = wp.zeros((n, H, W), dtype=wp.float32, device=dev)
            cmd = wp.launch(r._kernel, dim=RK.tiled_threads(n, H, W), device=dev, block_dim=r.block_dim,
                            record_cmd=True,
                            inputs=[r._atlas, r._dist, float(self.scale), float(r.step_mm),
                                    float(r._value_scale), items, r._cam_M, r._vol_dims, r._vol_zoff, out])
            got = own[(n, H, W)] = (host, host.numpy(), items, out, cmd)
        host, host_np, items, out, cmd = got
        host_np[...] = table.reshape(n, ITEM_COLS)
        if not launch:
            return got
        copy_array(items, host)
        cmd.launch()
        return out
