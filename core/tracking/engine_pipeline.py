"""The Gauss–Newton engine's metric pipeline (:class:`_Pipeline`): for one DRR buffer of
:class:`core.tracking.engine.GaussNewtonCost` (``n_poses`` poses × views items of a fixed size)
its device buffers and the recorded launches of the metric — two blur passes, per-item
statistics, the scores, the Gauss–Newton moments and the copies to (pinned) host memory —
replayed as one CUDA graph on the GPU, split over threads on the CPU
(:mod:`core.tracking.cpu_threads`). With ``render`` (a CUDA device,
:class:`core.tracking.engine_render.DeviceRender`) the pipeline renders its own DRRs: the copy of
the parameter rows, the item table and the DRR launch come first in the same graph."""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from ..similarity import _kernels as K
from ..similarity.batched import RecordedWork
from .cpu_threads import split_cpu_launches
from .engine_kernels import N_POSES, moments_kernel

_KIND = {"ncc": K.K_NCC, "gc": K.K_GC}


class _Pipeline(RecordedWork):
    """Device buffers and recorded launches of the metric for one DRR buffer (``n_poses``
    poses × views items of a fixed size) of the engine ``c`` (a
    :class:`~core.tracking.engine.GaussNewtonCost`); a CUDA graph on the GPU."""

    def __init__(self, c, images: wp.array | None, n_poses: int, render=None) -> None:
        dev = c.device
        nv = c.n_views
        self.x_host = self.x_dev = None
        self.render: list = []
        if render is not None:  # the poses' item table and the DRRs in the graph too
            Hc, Wc = c._cap
            self.x_host, self.x_dev, images, self.render = render.record(c, n_poses, Hc, Wc)
            self.x_np = self.x_host.numpy()
        n, H, W = images.shape
        self.images = images
        self.stats = wp.zeros((n, 6), dtype=wp.float64, device=dev)
        self.extra = wp.zeros((n, 6), dtype=wp.float64, device=dev)
        self.count = wp.zeros(n, dtype=wp.float64, device=dev)
        self.out = wp.zeros(n_poses * (1 + nv), dtype=wp.float32, device=dev)
        self.host_out = wp.zeros(self.out.shape, dtype=wp.float32, device="cpu", pinned=dev.is_cuda)
        # moments per view; GC of the gradient components: the u components' rows, then the v's
        nq = 2 if c.components else 1
        self.gn = wp.zeros((nq * nv, 81), dtype=wp.float64, device=dev) if n_poses == N_POSES else None
        self.host_gn = (wp.zeros((nq * nv, 81), dtype=wp.float64, device="cpu", pinned=dev.is_cuda)
                        if self.gn is not None else None)
        self.zero = [self.stats, self.extra, self.count] + ([self.gn] if self.gn is not None else [])
        launches = []
        img = images
        if c._blur is not None:
            self.tmp = wp.zeros(images.shape, dtype=wp.float32, device=dev)
            self.blurred = wp.zeros(images.shape, dtype=wp.float32, device=dev)
            for src, dst, axis in ((images, self.tmp, 1), (self.tmp, self.blurred, 0)):
                launches.append(wp.launch(K.blur_kernel, dim=(n, H, W), device=dev, record_cmd=True,
                                          inputs=[src, dst, c._blur, c._ref_hw, nv, axis]))
            img = self.blurred
        n_chunks = math.ceil(H * W / c.chunk)
        # (mode, statistics, moments' first row) per quantity: GC of the components has two
        quantities = ([(2, self.stats, 0), (3, self.extra, nv)] if c.components
                      else [(c.mode, self.stats, 0)])
        for mode, acc, _ in quantities:
            launches.append(wp.launch_tiled(K.stats_kernel, dim=(n, n_chunks), block_dim=c.block_dim,
                                            device=dev, record_cmd=True,
                                            inputs=[img, c._fluoro, c._fgrad, c._fmask, c._ref_hw, c._fshift,
                                                    nv, c.threshold, c.dilate, mode, c._ku, c._kv, c.chunk,
                                                    acc]))
        code = K.K_GCC if c.components else _KIND[c.kind]
        launches.append(wp.launch(K.finalize_kernel, dim=n_poses, device=dev, record_cmd=True,
                                  inputs=[code, nv, self.stats, self.extra, self.count, c._fshift,
                                          nv, 0.25, c._weights, self.out]))
        if self.gn is not None:
            for mode, _, row in quantities:
                launches.append(wp.launch_tiled(moments_kernel, dim=(nv, n_chunks), block_dim=c.block_dim,
                                                device=dev, record_cmd=True,
                                                inputs=[img, c._fluoro, c._fgrad, c._fmask, c._ref_hw,
                                                        c._fshift, nv, c.threshold, c.dilate, mode, c._ku,
                                                        c._kv, c.chunk, self.gn[row:row + nv]]))
        # on the CPU the blur passes split by items and the moments beside the statistics, on threads
        self.launches = launches if dev.is_cuda else split_cpu_launches(launches, c.renderer.cpu_threads)
        self.copies = [(self.host_out, self.out)] + ([(self.host_gn, self.gn)] if self.gn is not None else [])
        # the host buffers' numpy views, made once (a view per fetch cost more than the copy)
        self.host_out_np = self.host_out.numpy()
        self.host_gn_np = None if self.gn is None else self.host_gn.numpy()
        self.capture(dev)

    def _enqueue(self) -> None:
        if self.render:
            self.enqueue_render()
        super()._enqueue()

    def enqueue_render(self) -> None:
        """Enqueue the copy of the parameter rows (:attr:`x_np`), the item table and the DRRs."""
        wp.copy(self.x_dev, self.x_host)
        for cmd in self.render:
            cmd.launch()

    def enqueue_metric(self) -> None:
        """Enqueue the metric alone, launch by launch (after :meth:`enqueue_render`: the DRR and
        metric times apart)."""
        super()._enqueue()

    def launch(self) -> None:
        """Enqueue the work (its results are on the host after the next synchronisation)."""
        self.replay()

    def fetch(self) -> tuple[np.ndarray, np.ndarray | None]:
        """The scores (and moments) once the device has synchronised."""
        return self.host_out_np.copy(), None if self.gn is None else self.host_gn_np.copy()

    def run(self) -> tuple[np.ndarray, np.ndarray | None]:
        self.launch()
        if self.graph is not None:
            wp.synchronize_device(self.images.device)
        return self.fetch()
