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

__all__ = ["OutsideViewError", "pixel_mm", "search_roi", "snap_roi", "support_points"]


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
    cameras, max(fx, fy) per view, each view's R[2] and t[2] (the depth of Camera.project), (width,
    height) per view)``; kept per renderer and views while its cameras (frozen) are the same."""
    cams = renderer.cameras
    key = (id(renderer), views)
    hit = _CAM_TABLES.get(key)
    if hit is not None and hit[0] is cams:
        return hit[1]
    sel = tuple(cams[v] for v in views)
    f = np.array([[c.fx, c.fy] for c in sel])[:, :, None]
    cc = np.array([[c.cu, c.cv] for c in sel])[:, :, None]
    table = (np.concatenate([c.R for c in sel]), np.concatenate([c.t for c in sel])[:, None], f, cc, sel,
             tuple(max(c.fx, c.fy) for c in sel), tuple(c.R[2] for c in sel), tuple(c.t[2] for c in sel),
             tuple((c.width, c.height) for c in sel))
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
    zmin = np.fmin.reduce(z, axis=2).ravel().tolist()  # a point at or behind a view's source: its whole image
    behind = [a <= 0 for a in zmin]
    uv = xc[:, :2] * f  # (V, 2, n): fx x / z + cu, fy y / z + cv
    if all(a > 0 for a in zmin):
        uv /= z
    else:
        with np.errstate(divide="ignore", invalid="ignore"):
            uv /= z
    uv += cc
    # (the reductions' ufuncs themselves: the values of uv.min / uv.max without their wrappers)
    lows, highs = np.minimum.reduce(uv, axis=2).tolist(), np.maximum.reduce(uv, axis=2).tolist()
    out = []
    floor, ceil = math.floor, math.ceil
    for (W, H), bad, a, b in zip(table[8], behind, lows, highs, strict=True):
        if bad:
            out.append((0, 0, W, H))
            continue
        lo0, lo1 = min(max(floor(a[0]), 0), W), min(max(floor(a[1]), 0), H)
        hi0, hi1 = min(max(ceil(b[0]) + 1, 0), W), min(max(ceil(b[1]) + 1, 0), H)
        out.append((lo0, lo1, max(hi0 - lo0, 0), max(hi1 - lo1, 0)))
    return out


def search_roi(renderer, pose: np.ndarray, bone: int, *, views: Sequence[int], center: np.ndarray,
               reach_mm: float, margin_px: int = 4, points=None, grid: int = 0) -> np.ndarray:
    """``(n_views, 4)`` ROIs ``(u0, v0, w, h)``: the bone's projected box at ``pose`` grown by the
    image displacement of a ``reach_mm`` move of its centre (plus ``margin_px``), clipped to the
    image. The box is that of ``points`` (``(n, 3)`` in the bone's CT frame, mm; e.g.
    :attr:`core.tracking.bones.BoneModel.outline`) when given, else of the volume's box.
    ``grid`` > 0: snapped as :func:`snap_roi` snaps them (the same numbers).
    Raises :class:`OutsideViewError` when a view's ROI is empty.

    The views' cameras are projected together (their numbers kept per renderer,
    :func:`_camera_table`; the volume box's corners too, :data:`BOX_CORNERS`): on the tracker's
    path, a few calls per frame."""
    pose = np.asarray(pose, float)
    views = tuple([int(v) for v in views])
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
    ceil = math.ceil
    for cam, v, (u0, v0, w0, h0), f_px, r2, t2, (W, H) in zip(cams, views, box, reach_px, table[6], table[7],
                                                                table[8], strict=True):
        depth = float(r2 @ c_lab + t2)  # the depth of Camera.project
        grow = margin_px + (ceil(reach_mm * f_px / max(depth, 1e-6)) if depth > 0 else 0)
        u0, v0, w0, h0 = int(u0), int(v0), int(w0), int(h0)
        if w0 <= 0 or h0 <= 0:
            raise OutsideViewError(f"views: the bone projects outside view {v} ({cam.name})")
        lo0, lo1 = max(u0 - grow, 0), max(v0 - grow, 0)
        hi0, hi1 = min(u0 + w0 + grow, W), min(v0 + h0 + grow, H)
        if hi0 <= lo0 or hi1 <= lo1:
            raise OutsideViewError(f"views: the bone projects outside view {v} ({cam.name})")
        out.append((lo0, lo1, hi0 - lo0, hi1 - lo1) if grid <= 0 else _snapped(lo0, lo1, hi0 - lo0, hi1 - lo1,
                                                                              W, H, grid))
    return np.array(out, dtype=np.int64).reshape(len(views), 4)


def _snapped(u0: int, v0: int, w: int, h: int, W: int, H: int, grid: int) -> tuple:
    """One region grown outwards to the ``grid``-pixel lattice inside a ``W`` × ``H`` image (snap_roi)."""
    a0, b0 = (u0 // grid) * grid, (v0 // grid) * grid
    a1 = min(-(-(u0 + w) // grid) * grid, W)
    b1 = min(-(-(v0 + h) // grid) * grid, H)
    return (a0, b0, a1 - a0, b1 - b0)


def pixel_mm(renderer, pose: np.ndarray, center: np.ndarray, views: Sequence[int] | None = None) -> float:
    """Mean size (mm) of a full-resolution pixel at the bone's centre over ``views``
    (:func:`core.tracking.cost.mm_per_pixel`; the cameras' numbers of :func:`_camera_table`, the
    same arithmetic)."""
    views = tuple(range(len(renderer.cameras))) if views is None else tuple([int(v) for v in views])
    table = _camera_table(renderer, views)
    c = pose[:3, :3] @ center + pose[:3, 3]
    out = [float(r2 @ c + t2) / f for r2, t2, f in zip(table[6], table[7], table[5], strict=True)]
    if len(out) == 2:  # (np.mean of two: their sum, halved)
        return (out[0] + out[1]) / 2
    return float(np.mean(out))


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
        out.append(_snapped(u0, v0, w, h, cam.width, cam.height, grid))
    return np.array(out, dtype=np.int64).reshape(rows.shape)
