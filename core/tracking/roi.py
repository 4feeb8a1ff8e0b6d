"""The search regions of a registration: each view's box of the bone's projection grown by the
reach of the search (:func:`search_roi`), snapped to a pixel lattice (:func:`snap_roi`), and the
error of a bone outside a view (:class:`OutsideViewError`). Re-exported by
:mod:`core.tracking.cost`, whose fluoroscope regions (:func:`~core.tracking.cost.fluoro_rois`) and
costs take these regions.
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Sequence

import numpy as np

__all__ = ["OutsideViewError", "search_roi", "snap_roi", "support_points"]


class OutsideViewError(ValueError):
    """The bone's search region does not overlap a view's image (or its usable pixels)."""


_HULLS: dict[int, tuple[np.ndarray, np.ndarray]] = {}


def _hull_points(points) -> np.ndarray:
    """The vertices of the convex hull of ``(n, 3)`` points (all points when degenerate): a
    perspective projection maps the hull onto the hull of the projections, so their image box is
    that of all the points. Kept per array for the next frames."""
    key = id(points)
    hit = _HULLS.get(key)
    if hit is not None and hit[0] is points:
        return hit[1]
    P = np.asarray(points, dtype=float)
    if P.ndim != 2 or P.shape[1] != 3 or not len(P):
        raise ValueError(f"points: expected (n, 3) bone-frame points, got shape {P.shape}")
    V = P
    if len(P) > 16:
        from scipy.spatial import ConvexHull, QhullError

        try:
            V = P[ConvexHull(P).vertices]
        except (QhullError, ValueError):
            V = P
    if isinstance(points, np.ndarray):
        if len(_HULLS) >= 64:
            _HULLS.pop(next(iter(_HULLS)))
        _HULLS[key] = (points, V)
    return V


#: :func:`search_roi` without ``points``: the volume box's eight corners projected by
#: :func:`_boxes` with the views' camera table (the same numbers as
#: :meth:`core.render.DRRRenderer.auto_roi`, whose per-view projection took ~0.6 ms a call under
#: cProfile on the likelihood stage's path). Off: ``auto_roi``, as first written.
BOX_CORNERS = True

_CORNERS: dict = {}  # search_roi: per renderer, its volumes' box corners as homogeneous columns


def _box_lab(renderer, bone: int, pose: np.ndarray) -> np.ndarray:
    """The lab positions ``(8, 3)`` of the corners of ``bone``'s volume box at ``pose`` (the
    renderer's ``_corners``; the arithmetic of :meth:`~core.render.DRRRenderer.auto_roi`)."""
    corners = renderer._corners
    key = (id(renderer), int(bone))
    hit = _CORNERS.get(key)
    if hit is None or hit[0] is not corners:
        if len(_CORNERS) >= 64:
            _CORNERS.clear()
        hit = _CORNERS[key] = (corners, np.c_[corners[bone], np.ones(8)])
    return np.einsum("bij,kj->bki", pose[None], hit[1])[0, :, :3]


_CAM_TABLES: dict = {}  # search_roi: per renderer and views, its cameras' numbers (_camera_table)


def _camera_table(renderer, views: tuple) -> tuple:
    """The cameras of ``views`` as arrays for :func:`search_roi`'s projection of all views at once:
    ``(rows (3 V, 3): the views' R stacked, t (3 V, 1), f (V, 2, 1): fx, fy, c (V, 2, 1): cu, cv,
    cameras, max(fx, fy) per view)``; kept per renderer and views while its cameras (frozen) are the
    same."""
    cams = renderer.cameras
    key = (id(renderer), views)
    hit = _CAM_TABLES.get(key)
    if hit is not None and hit[0] is cams:
        return hit[1]
    sel = tuple(cams[v] for v in views)
    f = np.array([[c.fx, c.fy] for c in sel])[:, :, None]
    cc = np.array([[c.cu, c.cv] for c in sel])[:, :, None]
    table = (np.concatenate([c.R for c in sel]), np.concatenate([c.t for c in sel])[:, None], f, cc, sel,
             tuple(max(c.fx, c.fy) for c in sel))
    if len(_CAM_TABLES) >= 64:
        _CAM_TABLES.clear()
    _CAM_TABLES[key] = (cams, table)
    return table


def _boxes(cams, lab: np.ndarray, table) -> list:
    """The image boxes ``(u0, v0, w, h)`` of lab points ``(n, 3)`` in each camera of a
    :func:`_camera_table`: one product for all views, each view's coordinates contiguous (the same
    numbers as :meth:`core.geometry.Camera.project` per view)."""
    rows, t, f, cc = table[:4]
    xc = rows @ lab.T
    xc += t
    xc = xc.reshape(len(cams), 3, len(lab))
    z = xc[:, 2:]
    zmin = np.fmin.reduce(z, axis=2).ravel()  # a point at or behind a view's source: its whole image
    uv = xc[:, :2] * f  # (V, 2, n): fx x / z + cu, fy y / z + cv
    if (zmin > 0).all():
        uv /= z
    else:
        with np.errstate(divide="ignore", invalid="ignore"):
            uv /= z
    uv += cc
    behind = (zmin <= 0).tolist()
    lows, highs = uv.min(axis=2).tolist(), uv.max(axis=2).tolist()
    out = []
    for cam, bad, a, b in zip(cams, behind, lows, highs, strict=True):
        W, H = cam.width, cam.height
        if bad:
            lo, hi = (0, 0), (W, H)
        else:
            lo = (min(max(math.floor(a[0]), 0), W), min(max(math.floor(a[1]), 0), H))
            hi = (min(max(math.ceil(b[0]) + 1, 0), W), min(max(math.ceil(b[1]) + 1, 0), H))
        out.append((lo[0], lo[1], max(hi[0] - lo[0], 0), max(hi[1] - lo[1], 0)))
    return out


def search_roi(renderer, pose: np.ndarray, bone: int, *, views: Sequence[int], center: np.ndarray,
               reach_mm: float, margin_px: int = 4, points=None) -> np.ndarray:
    """``(n_views, 4)`` ROIs ``(u0, v0, w, h)``: the bone's projected box at ``pose`` grown by the
    image displacement of a ``reach_mm`` move of its centre (plus ``margin_px``), clipped to the
    image. The box is that of ``points`` (``(n, 3)`` in the bone's CT frame, mm; e.g.
    :attr:`core.tracking.bones.BoneModel.outline`) when given, else of the volume's box.
    Raises :class:`OutsideViewError` when a view's ROI is empty.

    The views' cameras are projected together (their numbers kept per renderer,
    :func:`_camera_table`; the volume box's corners too, :data:`BOX_CORNERS`): on the tracker's
    path, a few calls per frame."""
    pose = np.asarray(pose, float)
    views = tuple(int(v) for v in views)
    table = _camera_table(renderer, views)
    cams, reach_px = table[4], table[5]
    if points is None and BOX_CORNERS and hasattr(renderer, "_corners"):
        box = _boxes(cams, _box_lab(renderer, bone, pose), table)
    elif points is None:
        box = renderer.auto_roi(pose[None, None], views=views, bones=[bone], margin=0)[0, :, 0].tolist()
    else:
        P = _hull_points(points)
        box = _boxes(cams, P @ pose[:3, :3].T + pose[:3, 3], table)
    c_lab = pose[:3, :3] @ center + pose[:3, 3]
    out = []
    for cam, v, (u0, v0, w0, h0), f_px in zip(cams, views, box, reach_px, strict=True):
        depth = float(cam.R[2] @ c_lab + cam.t[2])  # the depth of Camera.project
        grow = margin_px + (math.ceil(reach_mm * f_px / max(depth, 1e-6)) if depth > 0 else 0)
        u0, v0, w0, h0 = int(u0), int(v0), int(w0), int(h0)
        if w0 <= 0 or h0 <= 0:
            raise OutsideViewError(f"views: the bone projects outside view {v} ({cam.name})")
        lo = (max(u0 - grow, 0), max(v0 - grow, 0))
        hi = (min(u0 + w0 + grow, cam.width), min(v0 + h0 + grow, cam.height))
        if hi[0] <= lo[0] or hi[1] <= lo[1]:
            raise OutsideViewError(f"views: the bone projects outside view {v} ({cam.name})")
        out.append((lo[0], lo[1], hi[0] - lo[0], hi[1] - lo[1]))
    return np.array(out, dtype=np.int64).reshape(len(views), 4)


_SUPPORT: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def support_points(renderer, bone: int) -> np.ndarray | None:
    """``(n, 3)`` points (the volume's physical frame, mm) whose convex hull holds every voxel of the
    renderer's volume ``bone`` with a positive attenuation, each moved by ±1 voxel along every axis
    (trilinear support): the support of the bone's DRR (:attr:`core.tracking.bones.BoneModel.outline`'s
    construction, of ``μ > 0`` instead of the bone's mask). Kept per renderer; None where the volume
    has no such voxel."""
    per = _SUPPORT.setdefault(renderer, {})
    if int(bone) in per:
        return per[int(bone)]
    from scipy.ndimage import binary_erosion
    from scipy.spatial import ConvexHull, QhullError

    vol = renderer.volumes[int(bone)]
    data, tr = np.asarray(vol.data), getattr(renderer, "transfer", None)
    mask = (data if vol.units != "HU" or tr is None else tr(data)) > 0  # (μ as the renderer has it)
    out = None
    if mask.any():
        shell = mask & ~binary_erosion(mask)
        k, j, i = np.nonzero(shell)
        P = np.column_stack([i, j, k]).astype(float)
        try:
            P = P[ConvexHull(P).vertices]
        except (QhullError, ValueError):  # flat or tiny supports: every shell voxel
            pass
        corners = np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)], float)
        out = vol.index_to_physical((P[:, None, :] + corners[None]).reshape(-1, 3))
        out.setflags(write=False)
    per[int(bone)] = out
    return out


def snap_roi(roi: np.ndarray, renderer, views, grid: int = 16) -> np.ndarray:
    """ROIs grown outwards to a ``grid``-pixel lattice (inside the image): a bone that moves
    little keeps its region from round to round and frame to frame (the frame's line integrals
    of a region are computed once, :meth:`core.tracking.cost.FrameImages.region`)."""
    rows = np.array(roi, dtype=np.int64)
    out = []
    for (u0, v0, w, h), v in zip(rows.tolist(), views, strict=True):  # (Python integers: the same numbers)
        cam = renderer.cameras[v]
        a0, b0 = (u0 // grid) * grid, (v0 // grid) * grid
        a1 = min(-(-(u0 + w) // grid) * grid, cam.width)
        b1 = min(-(-(v0 + h) // grid) * grid, cam.height)
        out.append((a0, b0, a1 - a0, b1 - b0))
    return np.array(out, dtype=np.int64).reshape(rows.shape)
