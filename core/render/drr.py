"""Batched DRR rendering with Warp.

Model
-----
A DRR pixel is the line integral ``∫ μ(x) dl`` (unitless) of linear attenuation (1/mm) along the
ray from the camera's X-ray source through the pixel centre. ``μ`` is the trilinear interpolant
of the voxel values (after :class:`~core.render.HUTransfer`) with zeros outside the volume; each
ray is clipped to the volume box (one voxel of zero padding included) and integrated with
samples at ``(k + 0.5) * step_mm`` from the source (default step: the smallest voxel spacing).
The sample grid belongs to the ray, not the volume, so a DRR changes continuously with the pose.

Batching
--------
One launch renders every (pose, view, bone) *item*: ``poses`` has shape ``(B, n_bones, 4, 4)``
(``T_lab_from_bone``), and the result holds ``B × n_views × n_bones`` images. Each item covers a
*region of interest* of the full image — by default the bone's projected bounding box plus a
margin — optionally at reduced resolution (``scale`` > 1: one ray per ``scale × scale`` block,
through the block centre). All volumes live in one 3D atlas on the device, uploaded once.

Interpolation
-------------
``"texture"`` samples a ``wp.Texture3D`` with hardware trilinear filtering. CUDA texture units
compute the interpolation weights in 9-bit fixed point (8 fractional bits): each weight is
quantised to 1/256, so a sample can differ from exact trilinear interpolation by up to ~0.4 % of
the local voxel difference; along a ray these errors average out (``talus bench drr`` reports
the largest per-pixel difference to the exact path: 0.05 % of the brightest pixel on an H100).
``"trilinear"`` does the interpolation in float32 arithmetic on a plain ``wp.array3d`` — slower
on the GPU but exact. The default is ``"texture"`` on CUDA and ``"trilinear"`` on the CPU (where
Warp's texture filter is emulated in software with exact weights).

Speed
-----
Threads render 8 × 8 pixel tiles (texture-cache locality) and issue two samples per loop
iteration. Empty space is skipped *exactly*: a per-voxel chessboard distance map (voxels to the
nearest non-zero voxel) proves how many of the following samples are zero, and the ray jumps
over them without fetching (see ``_kernels._zero_run``); results equal those with skipping off
up to float32 summation order.

On the CPU
----------
Warp runs a CPU kernel on one core. With ``cpu_threads`` > 1 (default: the machine's cores,
``TALUS_CPU_THREADS`` overrides) a launch of several items is split into that many contiguous
runs of items, each its own recorded launch on views of the same item table and output buffer,
run in parallel threads (a Warp CPU launch is a ctypes call, which releases the GIL). Every
pixel is computed by the same code from the same inputs, so the images are bit-identical to
those of one thread; the output buffer is the same one. CUDA launches are not affected. (The
DRR kernels use no tiles: Warp 1.19 keeps a CPU module's tile scratch memory behind one static,
not thread-local, pointer, which kernels without tiles never read.)
"""

from __future__ import annotations

import itertools
import math
import os
import threading
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import warp as wp
from scipy.ndimage import distance_transform_cdt

from .._validate import as_float_array, positive
from ..geometry.camera import Camera, Rig
from . import _kernels
from .volume import CTVolume, HUTransfer

__all__ = ["DRRBatch", "DRRRenderer", "default_cpu_threads", "default_device", "run_parallel"]

wp.config.log_level = wp.LOG_WARNING  # keep Warp's start-up banner off stdout (the CLI prints JSON)


def _clip_box_corners(vol: CTVolume) -> np.ndarray:
    """(8, 3) physical corners of the box a ray is clipped to: index -1 .. n on each axis."""
    n = np.array(vol.shape_ijk, dtype=float)
    c = np.array([[a, b, d] for a in (0, 1) for b in (0, 1) for d in (0, 1)], dtype=float)
    return vol.index_to_physical(c * (n + 1.0) - 1.0)


def default_cpu_threads() -> int:
    """Threads a CPU launch is split over: ``TALUS_CPU_THREADS`` if set, else the machine's cores."""
    env = os.environ.get("TALUS_CPU_THREADS", "").strip()
    if env:
        try:
            n = int(env)
        except ValueError:
            raise ValueError(f"TALUS_CPU_THREADS: expected a whole number >= 1, got {env!r}") from None
        if n < 1:
            raise ValueError(f"TALUS_CPU_THREADS: expected a whole number >= 1, got {env!r}")
        return n
    try:
        return max(1, len(os.sched_getaffinity(0)))  # the cores this process may run on
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


_POOL_LOCK = threading.Lock()
_POOL: dict[int, object] = {}


def _forget_pools_after_fork() -> None:
    """A forked child has none of its parent's threads: it makes pools of its own."""
    global _POOL_LOCK
    _POOL_LOCK = threading.Lock()
    _POOL.clear()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_pools_after_fork)


def _pool(workers: int):
    """The process-wide thread pool, of at least ``workers`` threads (created on first use, and
    replaced by a larger one when more are asked for: one pool, never one per size)."""
    from concurrent.futures import ThreadPoolExecutor

    with _POOL_LOCK:
        pool = _POOL.get(0)
        if pool is None or pool._max_workers < workers:
            if pool is not None:
                pool.shutdown(wait=False)  # work already submitted still runs
            pool = _POOL[0] = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="talus-drr")
        return pool


def run_parallel(cmds: Sequence) -> None:
    """Launch recorded CPU launches ``cmds`` in parallel: the first in this thread, the others
    in a process-wide pool; returns when all are done (the first error is raised)."""
    if len(cmds) == 1:
        cmds[0].launch()
        return
    futures = [_pool(len(cmds) - 1).submit(c.launch) for c in cmds[1:]]
    err = None
    try:
        cmds[0].launch()
    except BaseException as e:  # wait for the others before raising: they write the same buffer
        err = e
    for f in futures:
        try:
            f.result()
        except BaseException as e:
            err = err or e
    if err is not None:
        raise err


def default_device() -> str:
    """``"cuda:0"`` when a CUDA device is present, otherwise ``"cpu"``."""
    wp.init()
    return "cuda:0" if wp.is_cuda_available() else "cpu"


@dataclass(frozen=True, eq=False)
class DRRBatch:
    """Images from one :meth:`DRRRenderer.render` launch.

    Attributes
    ----------
    images : wp.array, shape (n_items, H, W), float32, on the renderer's device
        Item ``(b, v, n)`` is at index ``(b * n_views + v) * n_bones + n``. Pixels beyond an
        item's own ROI size are 0. The buffer belongs to the renderer and is reused by the next
        render of the same batch and image size (so an optimizer loop allocates nothing): use
        or copy it before rendering again.
    roi : (B, n_views, n_bones, 4) int array
        ``(u0, v0, w, h)`` of each item in full-resolution pixels; output pixel ``[r, c]`` of an
        item is the ray through ``(u, v) = (u0 + (c + 0.5) s - 0.5, v0 + (r + 0.5) s - 0.5)``.
    scale : float
        ``s``, full-resolution pixels per output pixel.
    views, bones : tuple of int
        Which cameras and which bones were rendered (in that order).
    """

    images: wp.array
    roi: np.ndarray
    scale: float
    views: tuple[int, ...]
    bones: tuple[int, ...]

    @property
    def shape(self) -> tuple[int, int, int]:
        """``(B, n_views, n_bones)``."""
        return tuple(self.roi.shape[:3])

    def numpy(self) -> np.ndarray:
        """Copy to the host as ``(B, n_views, n_bones, H, W)`` float32."""
        arr = self.images.numpy()
        return arr.reshape(*self.shape, *arr.shape[1:])

    def item(self, b: int, v: int, n: int) -> np.ndarray:
        """One item's image cropped to its ROI size, on the host ``(h_out, w_out)``."""
        k = (b * len(self.views) + v) * len(self.bones) + n
        w, h = self.roi[b, v, n, 2:]
        ho, wo = math.ceil(h / self.scale), math.ceil(w / self.scale)
        return self.images[k].numpy()[:ho, :wo]


class DRRRenderer:
    """Batched DRR renderer for a camera rig and a set of bone volumes.

    Parameters
    ----------
    cameras : Rig or sequence of Camera
    volumes : sequence of CTVolume
        In HU (converted through ``transfer``) or already in ``"1/mm"``.
    transfer : HUTransfer, optional
        HU -> μ map for volumes in HU (default ``HUTransfer()``).
    device : str, optional
        Warp device (``"cpu"``, ``"cuda"``, ``"cuda:1"``…); default :func:`default_device`.
    step_mm : float, optional
        Ray-marching step in mm; default the smallest voxel spacing of all volumes.
    interpolation : {"texture", "trilinear"}, optional
        See the module docs; default ``"texture"`` on CUDA, ``"trilinear"`` on the CPU.
    texture_dtype : {"float32", "uint16", "float16"}, optional
        Storage of the texture atlas (``"texture"`` only). The default ``"uint16"`` stores
        μ / max(μ) as 16-bit normalised integers (resolution 1/65535 of the largest μ): half the
        memory of float32 and ~4 % faster on an H100 (``talus bench drr``).
    empty_space_skipping : bool
        In empty space, advance the ray over the samples that a per-voxel chessboard distance
        map proves to be zero, without fetching them (default True); results agree up to
        float32 summation order.
    cpu_threads : int, optional
        On the CPU, the threads a launch of several items is split over (module docs; default
        :func:`default_cpu_threads`; 1 = one thread). Ignored on CUDA. The attribute of the
        same name may be changed later.
    """

    def __init__(
        self,
        cameras: Rig | Sequence[Camera],
        volumes: Sequence[CTVolume],
        *,
        transfer: HUTransfer | None = None,
        device: str | None = None,
        step_mm: float | None = None,
        interpolation: str | None = None,
        texture_dtype: str = "uint16",
        empty_space_skipping: bool = True,
        cpu_threads: int | None = None,
    ) -> None:
        cams = tuple(cameras.cameras if isinstance(cameras, Rig) else cameras)
        if not cams or not all(isinstance(c, Camera) for c in cams):
            raise ValueError("cameras: expected a Rig or a non-empty sequence of Camera")
        vols = tuple(volumes)
        if not vols or not all(isinstance(v, CTVolume) for v in vols):
            raise ValueError("volumes: expected a non-empty sequence of CTVolume")
        wp.init()
        self.device = wp.get_device(device or default_device())
        if interpolation is None:
            interpolation = "texture" if self.device.is_cuda else "trilinear"
        if interpolation not in ("texture", "trilinear"):
            raise ValueError(f"interpolation: expected 'texture' or 'trilinear', got {interpolation!r}")
        self.interpolation = interpolation
        if texture_dtype not in ("float32", "uint16", "float16"):
            raise ValueError(
                f"texture_dtype: expected 'float32', 'uint16' or 'float16', got {texture_dtype!r}"
            )
        self.texture_dtype = texture_dtype
        self.empty_space_skipping = bool(empty_space_skipping)
        self.cameras = cams
        self.volumes = vols
        tr = self.transfer = transfer or HUTransfer()  # (HU volumes' μ: roi.support_points too)
        for v in vols:
            if v.units not in ("HU", "1/mm"):
                raise ValueError(
                    f"volumes: {v.name or 'a volume'} has units {v.units!r}, expected HU or 1/mm"
                )
        mus = [v.data.astype(np.float32) if v.units == "1/mm" else tr(v.data) for v in vols]
        for v, mu in zip(vols, mus, strict=True):
            if not np.all(np.isfinite(mu)):
                raise ValueError(f"volumes: {v.name or 'a volume'} has non-finite attenuation")
            if mu.min() < 0:
                raise ValueError(
                    f"volumes: {v.name or 'a volume'} has negative attenuation ({mu.min():.3g} /mm); "
                    "expected μ >= 0 (convert HU through an HUTransfer)"
                )
        self.step_mm = (
            positive(step_mm, "step_mm") if step_mm is not None
            else float(min(v.spacing.min() for v in vols))
        )
        self._upload(mus)
        # per-camera M = R^T K^-1 and source positions
        M = np.stack([c.R.T @ np.linalg.inv(c.K) for c in cams]).astype(np.float32)
        self._cam_M = wp.array(M, dtype=wp.mat33f, device=self.device)
        # corners of the clipping box (index -1 and n: the interpolant reaches into the zero
        # padding) in bone coordinates, for automatic ROIs
        self._corners = [_clip_box_corners(v) for v in vols]
        self._T_idx = np.stack([v.T_index_from_physical for v in vols])
        self._launches: dict[tuple[int, int, int], tuple] = {}
        self._tables: dict[tuple, np.ndarray] = {}
        self._src_h = np.array([[*c.source, 1.0] for c in cams])  # homogeneous sources (n_cams, 4)
        self.block_dim = 128  # CUDA threads per block: two 8x8 tiles (fastest on an H100)
        if cpu_threads is not None and (int(cpu_threads) != cpu_threads or cpu_threads < 1):
            raise ValueError(f"cpu_threads: expected a whole number >= 1, got {cpu_threads!r}")
        if cpu_threads is None:  # TALUS_CPU_THREADS is read (and checked) for CPU renderers only
            cpu_threads = 1 if self.device.is_cuda else default_cpu_threads()
        self.cpu_threads = int(cpu_threads)

    # ------------------------------------------------------------------ set-up
    def _upload(self, mus: list[np.ndarray]) -> None:
        ny = max(m.shape[1] for m in mus) + 2
        nx = max(m.shape[2] for m in mus) + 2
        nz = sum(m.shape[0] + 2 for m in mus)
        atlas = np.zeros((nz, ny, nx), dtype=np.float32)
        zoff, z = [], 0
        for m in mus:
            atlas[z + 1 : z + 1 + m.shape[0], 1 : 1 + m.shape[1], 1 : 1 + m.shape[2]] = m
            zoff.append(z)
            z += m.shape[0] + 2
        dims = np.array([[m.shape[2], m.shape[1], m.shape[0]] for m in mus], dtype=np.int32)
        self._vol_dims = wp.array(dims, dtype=wp.vec3i, device=self.device)
        self._vol_zoff = wp.array(np.array(zoff, dtype=np.int32), dtype=wp.int32, device=self.device)
        self._value_scale = 1.0
        if self.interpolation == "texture":
            tex_data = atlas
            if self.texture_dtype == "uint16":
                amax = float(atlas.max()) or 1.0
                tex_data = np.rint(atlas * (65535.0 / amax)).astype(np.uint16)
                self._value_scale = amax  # the texture returns q / 65535
            elif self.texture_dtype == "float16":
                tex_data = atlas.astype(np.float16)
            self._atlas = wp.Texture3D(
                tex_data,
                filter_mode=wp.TextureFilterMode.LINEAR,
                address_mode=wp.TextureAddressMode.CLAMP,
                normalized_coords=False,
                device=self.device,
            )
            self._kernel = _kernels.drr_texture_kernel
        else:
            self._atlas = wp.array(atlas, dtype=wp.float32, device=self.device)
            self._kernel = _kernels.drr_trilinear_kernel
        # empty-space skipping: chessboard distance (voxels) to the nearest non-zero voxel
        if self.empty_space_skipping:
            dist = np.minimum(distance_transform_cdt(atlas == 0, metric="chessboard"), 255)
        else:
            dist = np.zeros(atlas.shape, dtype=np.uint8)
        self._dist = wp.array(dist.astype(np.uint8), dtype=wp.uint8, device=self.device)
        self.atlas_shape = atlas.shape

    def _table(self, B: int, views: tuple[int, ...], bones: tuple[int, ...]) -> np.ndarray:
        """Reusable host item table with the camera/volume columns filled in."""
        key = (B, views, bones)
        table = self._tables.get(key)
        if table is None:
            nv, nb = len(views), len(bones)
            table = np.zeros((B * nv * nb, _kernels.ITEM_COLS), dtype=np.float32)
            t = table.reshape(B, nv, nb, _kernels.ITEM_COLS)
            t[..., 0] = np.array(views, dtype=np.float32)[None, :, None]
            t[..., 1] = np.array(bones, dtype=np.float32)[None, None, :]
            if len(self._tables) >= 8:
                self._tables.pop(next(iter(self._tables)))
            self._tables[key] = table
        return table

    def _launch(self, table: np.ndarray, H: int, W: int, scale: float) -> wp.array:
        """Upload the item table (one copy) and launch; buffers and the recorded launch are
        reused while the batch size and output size stay the same. On the CPU the items are
        split over ``cpu_threads`` threads (module docs)."""
        n_items = table.shape[0]
        dev = self.device
        parts = 1 if dev.is_cuda else max(1, min(int(self.cpu_threads), n_items))
        key = (n_items, H, W, parts)
        cached = self._launches.pop(key, None)
        if cached is not None:  # most recently used last: the least recently used goes first
            self._launches[key] = cached
        else:
            pinned = dev.is_cuda
            host = wp.empty((n_items, _kernels.ITEM_COLS), dtype=wp.float32, device="cpu", pinned=pinned)
            items = wp.empty((n_items, _kernels.ITEM_COLS), dtype=wp.float32, device=dev)
            out = wp.empty((n_items, H, W), dtype=wp.float32, device=dev)
            bounds = np.linspace(0, n_items, parts + 1).round().astype(int)
            cmds = []
            for a, b in itertools.pairwise(bounds):
                it, o = (items, out) if parts == 1 else (items[int(a):int(b)], out[int(a):int(b)])
                cmds.append(wp.launch(
                    self._kernel,
                    dim=_kernels.tiled_threads(int(b - a), H, W),
                    inputs=[self._atlas, self._dist, float(scale), float(self.step_mm),
                            float(self._value_scale), it,
                            self._cam_M, self._vol_dims, self._vol_zoff, o],
                    device=dev,
                    block_dim=self.block_dim,
                    record_cmd=True,
                ))
            if len(self._launches) >= 32:  # keep a few shapes (optimiser steps of several bones, display)
                self._launches.pop(next(iter(self._launches)))
            event = wp.Event(dev) if dev.is_cuda else None
            cached = self._launches[key] = (host, host.numpy(), items, out, cmds, event)
        host, host_np, items, out, cmds, event = cached
        if event is not None:  # the previous upload from this pinned buffer must be done
            wp.synchronize_event(event)
        host_np[...] = table
        wp.copy(items, host)
        if event is not None:  # (on the stream the copy went on: the device's own, not the current device's)
            dev.stream.record_event(event)
        for cmd in cmds:
            cmd.set_param_at_index(2, float(scale))
        run_parallel(cmds)
        return out

    # ------------------------------------------------------------------ ROIs
    def auto_roi(self, poses: np.ndarray, *, views: Sequence[int], bones: Sequence[int],
                 margin: int = 4) -> np.ndarray:
        """``(B, n_views, n_bones, 4)`` projected bounding boxes of each bone's volume box."""
        B = poses.shape[0]
        roi = np.zeros((B, len(views), len(bones), 4), dtype=np.int64)
        for n, bone in enumerate(bones):
            c = np.c_[self._corners[bone], np.ones(8)]
            lab = np.einsum("bij,kj->bki", poses[:, n], c)[..., :3]  # (B, 8, 3)
            for vi, view in enumerate(views):
                cam = self.cameras[view]
                uv, z = cam.project(lab, return_depth=True)
                lo = np.floor(uv.min(axis=1)) - margin
                hi = np.ceil(uv.max(axis=1)) + margin + 1
                lo = np.clip(lo, 0, [cam.width, cam.height])
                hi = np.clip(hi, 0, [cam.width, cam.height])
                behind = np.any(z <= 0, axis=1)
                lo[behind] = 0
                hi[behind] = [cam.width, cam.height]
                roi[:, vi, n, :2] = lo
                roi[:, vi, n, 2:] = np.maximum(hi - lo, 0)
        return roi

    # ------------------------------------------------------------------ render
    def render(
        self,
        poses,
        *,
        views: Sequence[int] | None = None,
        bones: Sequence[int] | None = None,
        roi=None,
        scale: float = 1.0,
        margin: int = 4,
        out_shape: tuple[int, int] | None = None,
    ) -> DRRBatch:
        """Render every (pose, view, bone) item in one launch.

        Parameters
        ----------
        poses : (B, n_bones, 4, 4) or (n_bones, 4, 4) array
            ``T_lab_from_bone`` for each rendered bone (in the order of ``bones``).
        views : sequence of int, optional
            Cameras to render (default all).
        bones : sequence of int, optional
            Volume indices (default all); ``poses`` has one matrix per entry.
        roi : None, "full", or array broadcastable to (B, n_views, n_bones, 4)
            ``(u0, v0, w, h)`` regions in full-resolution pixels; ``None`` = projected bounding
            box of each bone's volume + ``margin`` pixels; ``"full"`` = whole image.
        scale : float
            Full-resolution pixels per output pixel (1 = full resolution).
        out_shape : (H, W), optional
            Least size of the output items (default: that of the largest ROI at ``scale``). A
            fixed size keeps the output buffer — and everything recorded on it, e.g. a CUDA
            graph of the metric — the same while the ROIs change from frame to frame.

        Returns
        -------
        DRRBatch
            Images stay on the renderer's device.
        """
        views = tuple(range(len(self.cameras))) if views is None else tuple(int(v) for v in views)
        bones = tuple(range(len(self.volumes))) if bones is None else tuple(int(b) for b in bones)
        for v in views:
            if not 0 <= v < len(self.cameras):
                raise ValueError(f"views: index {v} out of range for {len(self.cameras)} cameras")
        for b in bones:
            if not 0 <= b < len(self.volumes):
                raise ValueError(f"bones: index {b} out of range for {len(self.volumes)} volumes")
        P = as_float_array(poses, "poses")
        if P.ndim == 3:
            P = P[None]
        if P.ndim != 4 or P.shape[1:] != (len(bones), 4, 4):
            raise ValueError(
                f"poses: expected shape (B, {len(bones)}, 4, 4) or ({len(bones)}, 4, 4), "
                f"got {np.shape(poses)}"
            )
        R = P[..., :3, :3]
        if (np.abs(R @ np.swapaxes(R, -1, -2) - np.eye(3)).max(initial=0.0) > 1e-6
                or np.abs(P[..., 3, :] - [0.0, 0.0, 0.0, 1.0]).max(initial=0.0) > 1e-12
                or np.linalg.det(R).min(initial=1.0) <= 0):
            raise ValueError("poses: expected rigid transforms (orthonormal rotation with det +1, "
                             "last row (0, 0, 0, 1))")
        scale = positive(scale, "scale")
        B, nv, nb = P.shape[0], len(views), len(bones)
        if roi is None:
            rois = self.auto_roi(P, views=views, bones=bones, margin=margin)
        elif isinstance(roi, str) and roi == "full":
            rois = np.zeros((B, nv, nb, 4), dtype=np.int64)
            for vi, v in enumerate(views):
                rois[:, vi, :, 2:] = [self.cameras[v].width, self.cameras[v].height]
        else:
            r = np.asarray(roi)
            if r.shape[-1] != 4 or not np.issubdtype(r.dtype, np.integer):
                raise ValueError(f"roi: expected integer (u0, v0, w, h) boxes, got shape {r.shape} {r.dtype}")
            rois = np.broadcast_to(r, (B, nv, nb, 4)).astype(np.int64)
            if np.any(rois[..., 2:] < 0):
                raise ValueError("roi: widths and heights must be >= 0")

        # per-item table (host, float64 -> float32); item (b, v, n) is row (b * nv + v) * nb + n
        n_items = B * nv * nb
        Tidx = np.einsum("nij,bnjk->bnik", self._T_idx[list(bones)], np.linalg.inv(P))
        table = self._table(B, views, bones)
        t = table.reshape(B, nv, nb, _kernels.ITEM_COLS)
        # X-ray source in index space: Tidx @ (C, 1) for every (pose, view, bone)
        t[..., 2:5] = np.einsum("bnij,vj->bvni", Tidx[..., :3, :], self._src_h[list(views)])
        t[..., 5:14] = Tidx[:, None, :, :3, :3].reshape(B, 1, nb, 9)
        t[..., 14:18] = rois
        H = max(1, math.ceil(int(rois[..., 3].max()) / scale)) if n_items else 1
        W = max(1, math.ceil(int(rois[..., 2].max()) / scale)) if n_items else 1
        if out_shape is not None:
            H, W = max(H, int(out_shape[0])), max(W, int(out_shape[1]))
        out = self._launch(table, H, W, scale)
        return DRRBatch(images=out, roi=rois, scale=scale, views=views, bones=bones)

    def render_full(self, poses, view: int, *, bones: Sequence[int] | None = None) -> np.ndarray:
        """Full-image DRR of view ``view``: the sum over ``bones`` at ``poses (n_bones, 4, 4)``."""
        batch = self.render(poses, views=[view], bones=bones, roi="full")
        return batch.numpy()[0, 0].sum(axis=0).astype(np.float32)
