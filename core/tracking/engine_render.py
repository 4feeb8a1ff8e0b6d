"""The DRRs of the Gauss–Newton engine's poses (:mod:`core.tracking.engine`).

:func:`host_poses` maps parameter rows to poses and :func:`render_items` fills the renderer's item
table on the host and launches it (:meth:`core.render.DRRRenderer.render`'s images without its
checks: the neighbours subtracted from the fluoroscope regions, the CPU's steps).

On a CUDA device a step's poses never pass through the host: :class:`DeviceRender` keeps the
engine's geometry on the device (the base pose, the centre, the ROIs — uploaded by
:meth:`~core.tracking.engine.GaussNewtonCost.set_frame` when they change) and records, per
batch size, the copy of the parameter rows from pinned memory, the item table computed from them
(:func:`~core.tracking.engine_kernels.pose_table_kernel`: the same arithmetic in float64, the same
float32 table) and the renderer's launch into a DRR buffer of the pipeline's own; the engine's
metric pipeline (:mod:`core.tracking.engine_pipeline`) captures them with its own launches as one
CUDA graph, so a step is one copy of 13 × 6 numbers into pinned memory and one graph launch.
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from ..render import _kernels as RK
from ..render._kernels import ITEM_COLS
from .engine_buffers import copy_array
from .engine_kernels import GEO_LEN, pose_table_kernel

__all__ = ["DeviceRender", "host_poses", "render_items"]


_EYE3 = np.eye(3)


def host_poses(X: np.ndarray, base: np.ndarray, center: np.ndarray) -> np.ndarray:
    """:func:`core.geometry.transforms.pose_from_params` of ``(mm, degrees)`` rows ``X``."""
    B = len(X)
    r = np.radians(X[:, 3:])
    th = np.sqrt(np.add.reduce(r * r, axis=1))  # (np.linalg.norm(r, axis=1)'s arithmetic, without its checks)
    small = th < 1e-8
    any_small = bool(np.logical_or.reduce(small))
    k = r / (np.where(small, 1.0, th) if any_small else th)[:, None]
    # the cross-product matrices of the axes (the values np.stack gave): a row or two from Python floats (a
    # negation is exact), more filled in place
    if B <= 2:
        Kx = np.array([((0.0, -c, b), (c, 0.0, -a), (-b, a, 0.0)) for a, b, c in k.tolist()]).reshape(B, 3, 3)
    else:
        Kx = np.zeros((B, 3, 3))
        Kx[:, 0, 1] = -k[:, 2]
        Kx[:, 0, 2] = k[:, 1]
        Kx[:, 1, 0] = k[:, 2]
        Kx[:, 1, 2] = -k[:, 0]
        Kx[:, 2, 0] = -k[:, 1]
        Kx[:, 2, 1] = k[:, 0]
    s, c = np.sin(th)[:, None, None], (1.0 - np.cos(th))[:, None, None]
    Rd = _EYE3 + s * Kx + c * (Kx @ Kx)
    if any_small:
        Rd[small] = _EYE3
    Rb, tb = base[:3, :3], base[:3, 3]
    c_lab = Rb @ center + tb
    R = Rd @ Rb
    out = np.zeros((B, 4, 4))
    out[:, :3, :3] = R
    out[:, :3, 3] = c_lab + X[:, :3] - R @ center
    out[:, 3, 3] = 1.0
    return out


def item_table(self, P: np.ndarray, bones: tuple) -> np.ndarray:
    """The item table ``(B, n_views, n_bones, ITEM_COLS)`` of the DRRs of ``bones`` at poses ``P (B,
    n_bones, 4, 4)`` in the views and ROIs of the engine ``self``, filled without the checks of poses
    the engine made rigid itself (the inverse in closed form); kept per ``(B, bones)`` and refilled."""
    r = self.renderer
    B, nb = P.shape[:2]
    nv = self.n_views
    key = (B, bones)
    hit = self._tables.get(key)
    if hit is None:
        table = np.zeros((B, nv, nb, ITEM_COLS), dtype=np.float32)
        table[..., 0] = np.array(self.views, dtype=np.float32)[None, :, None]
        table[..., 1] = np.array(bones, dtype=np.float32)[None, None, :]
        if len(self._tables) >= 8:
            self._tables.pop(next(iter(self._tables)))
        # the table, the bones' index-from-physical transforms, the sources, the ROIs filled in
        hit = self._tables[key] = [table, r._T_idx[list(bones)], r._src_h[list(self.views)], None]
    table, T, S, roi_in = hit
    # index-from-physical ∘ inverse pose, the inverse in closed form: rotation M, translation tt
    M = T[:, :3, :3] @ np.swapaxes(P[..., :3, :3], -1, -2)  # (B, nb, 3, 3)
    tt = T[:, :3, 3] - (M @ P[..., :3, 3:4])[..., 0]
    table[..., 2:5] = (M @ S[:, :3].T).transpose(0, 3, 1, 2) + tt[:, None] * S[None, :, None, 3:4]
    table[..., 5:14] = M.reshape(B, 1, nb, 9)
    if roi_in is None or not np.array_equal(roi_in, self.roi):
        table[..., 14:18] = self.roi[None, :, None, :]
        hit[3] = self.roi.copy()
    return table


def render_items(self, P: np.ndarray, bones: tuple) -> wp.array:
    """The DRRs of ``bones`` at poses ``P (B, n_bones, 4, 4)`` in the views and ROIs of the engine
    ``self`` at its output size: the images of :meth:`core.render.DRRRenderer.render` (item
    ``(b · n_views + v) · n_bones + n``), its item table (:func:`item_table`), one launch."""
    table = item_table(self, P, bones)
    Hc, Wc = self._cap
    H = max(Hc, math.ceil(int(self.roi[:, 3].max()) / self.scale))
    W = max(Wc, math.ceil(int(self.roi[:, 2].max()) / self.scale))
    return self.renderer._launch(table.reshape(-1, ITEM_COLS), H, W, self.scale)


class DeviceRender:
    """The device geometry of one engine (its bone and views): the base pose, centre and the
    bone's index-from-physical rows (``geo``, :data:`~core.tracking.engine_kernels.GEO_LEN`
    float64) and the ROIs after them, the views' sources; uploaded from pinned memory (one copy) when
    they change."""

    def __init__(self, c) -> None:
        r = c.renderer
        dev = c.device
        nv = c.n_views
        self.device = dev
        n = int(GEO_LEN) + 4 * nv  # the ROIs after the poses' geometry: one copy
        self._host_geo = wp.zeros(n, dtype=wp.float64, device="cpu", pinned=dev.is_cuda)
        self.geo = wp.zeros(n, dtype=wp.float64, device=dev)
        self.src = wp.array(np.ascontiguousarray(r._src_h[list(c.views)], dtype=np.float64), dtype=wp.float64,
                            device=dev)
        self.view_ids = wp.array(np.array(c.views, dtype=np.int32), dtype=wp.int32, device=dev)
        self._geo_np = self._host_geo.numpy()
        self._geo_np[15:27] = np.asarray(r._T_idx[c.bone], dtype=np.float64)[:3].ravel()
        self._last = None

    def upload(self, base: np.ndarray, center: np.ndarray, roi: np.ndarray, copy=copy_array) -> bool:
        """Enqueue the copies of a new base pose, centre and ROIs (True when something was copied:
        the pinned buffers must not change until the device has taken them; ``copy``: how, the
        engine's own where it records its preparation)."""
        key = (base.tobytes(), center.tobytes(), roi.tobytes())
        if key == self._last:
            return False
        g = self._geo_np
        g[0:9] = base[:3, :3].ravel()
        g[9:12] = base[:3, 3]
        g[12:15] = center
        g[27:] = roi.ravel()
        copy(self.geo, self._host_geo)
        self._last = key
        return True

    def record(self, c, B: int, H: int, W: int) -> tuple:
        """For a batch of ``B`` poses of the engine ``c`` at output size ``(H, W)``: the pinned
        parameter rows, their device copy, the DRR buffer and the recorded launches (the item
        table, the renderer's launch)."""
        r = c.renderer
        dev = self.device
        nv = c.n_views
        x_host = wp.zeros((B, 6), dtype=wp.float64, device="cpu", pinned=dev.is_cuda)
        x_dev = wp.zeros((B, 6), dtype=wp.float64, device=dev)
        items = wp.zeros((B * nv, ITEM_COLS), dtype=wp.float32, device=dev)
        images = wp.zeros((B * nv, H, W), dtype=wp.float32, device=dev)
        table = wp.launch(pose_table_kernel, dim=(B, nv), device=dev, record_cmd=True,
                          inputs=[x_dev, self.geo, self.src, self.view_ids, int(c.bone), items])
        drr = wp.launch(r._kernel, dim=RK.tiled_threads(B * nv, H, W), device=dev, block_dim=r.block_dim,
                        record_cmd=True,
                        inputs=[r._atlas, r._dist, float(c.scale), float(r.step_mm), float(r._value_scale),
                                items, r._cam_M, r._vol_dims, r._vol_zoff, images])
        return x_host, x_dev, images, [table, drr]
