"""Kinematics from tracked poses: filtering, anatomical frames, joint angles, helical axes,
joint space, exports.

Conventions: poses are ``(n_frames, 4, 4)`` ``T_lab_from_bone`` (mm), NaN for untracked frames;
angles in radians inside, degrees in exports (named ``*_deg``).

* :func:`butterworth` — zero-phase low-pass (``scipy.signal.filtfilt`` of an order-``order``
  Butterworth: the effective order doubles and the −3 dB point of the pass is corrected so the
  *combined* response is −3 dB at ``cutoff_hz``, Winter 2009 §3.4.4); NaN gaps are filled by
  linear interpolation for filtering and put back afterwards. :func:`filter_poses` filters the
  centroid path and the rotation (as rotation vectors relative to a reference, unwrapped).
* :func:`residual_cutoff` — Winter's residual analysis: the RMS difference between raw and
  filtered signal against cutoff; a line fitted to its high-frequency (noise) part meets the
  residual axis at the noise RMS, and the cutoff is where the residual equals it.
* Anatomical frames: :func:`principal_axes_frame` (origin at the centroid, axes = principal
  axes of the bone's voxels or surface, sorted by decreasing extent, right-handed) or
  :func:`frame_from_axes` (user-defined origin and axes).
* :func:`joint_angles` — Grood & Suntay (1983) joint coordinate system: ``e1`` fixed in the
  proximal segment (its ``e1_axis``, default z: flexion), ``e3`` fixed in the distal segment
  (its ``e3_axis``, default y: long-axis rotation), floating axis ``e2 = e3 × e1``. Angles are
  the intrinsic Euler sequence (e1, floating, e3) of the distal frame relative to the proximal
  one, e.g. ``"ZXY"`` for the defaults (ISB ankle: dorsi/plantar-flexion, inversion/eversion,
  internal/external rotation). Translations are the components of the origin displacement along
  (e1, e2, e3) (a non-orthogonal basis, solved exactly).
* :func:`helical_axes` — finite helical (screw) axes between consecutive (or ``step``-apart)
  frames of the relative motion: unit axis, rotation angle, translation along the axis, and the
  point of the axis nearest the origin.
* :func:`min_distance` — the smallest distance between two bone surfaces per frame
  (vertex-to-triangle, exact for the candidate pairs found by a k-d tree), with the closest points.
* Exports: :func:`export_csv` (4×4 or 6-DOF), :func:`export_tra` (Autoscoper ``.tra`` through
  :func:`core.io.autoscoper.write_tra`), :func:`export_json`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
from scipy.spatial.transform import Rotation

from ..geometry.triangles import closest_point_on_triangles

__all__ = ["butterworth", "export_csv", "export_json", "export_tra", "filter_poses", "frame_from_axes",
           "helical_axes", "joint_angles", "min_distance", "principal_axes_frame", "residual_cutoff"]


# ---------------------------------------------------------------------------- filtering
def _check_fs(fs, cutoff) -> tuple[float, float]:
    fs, fc = float(fs), float(cutoff)
    if not (fs > 0 and math.isfinite(fs)):
        raise ValueError(f"fs: expected a positive sampling rate in Hz, got {fs!r}")
    if not (0 < fc < fs / 2):
        raise ValueError(f"cutoff_hz: expected 0 < cutoff < fs/2 = {fs / 2:g} Hz, got {cutoff!r}")
    return fs, fc


def butterworth(x, fs: float, cutoff_hz: float, *, order: int = 2) -> np.ndarray:
    """Zero-phase Butterworth low-pass of ``x (n, ...)`` along axis 0 (see the module docs)."""
    from scipy.signal import butter, filtfilt

    fs, fc = _check_fs(fs, cutoff_hz)
    x = np.asarray(x, dtype=float)
    if x.ndim == 0 or x.shape[0] < 3 * (order + 1) + 1:
        raise ValueError(f"x: expected at least {3 * (order + 1) + 1} samples along axis 0, "
                         f"got shape {x.shape}")
    # correct the cutoff for the two passes (Winter): |H|^4 = 1/2 at fc, with the bilinear
    # transform's frequency warping
    c = (2**0.5 - 1) ** (1 / (2 * order))
    wn = min(2 / math.pi * math.atan(math.tan(math.pi * fc / fs) / c), 0.99)
    b, a = butter(order, wn)
    flat = x.reshape(x.shape[0], -1).copy()
    nan = ~np.isfinite(flat)
    t = np.arange(x.shape[0])
    for j in range(flat.shape[1]):
        ok = ~nan[:, j]
        if ok.sum() < 2:
            continue
        flat[:, j] = np.interp(t, t[ok], flat[ok, j])
    y = filtfilt(b, a, flat, axis=0, padtype="odd", padlen=min(3 * max(len(a), len(b)), x.shape[0] - 1))
    y[nan] = np.nan
    return y.reshape(x.shape)


def residual_cutoff(x, fs: float, *, candidates=None, order: int = 2) -> tuple[float, np.ndarray]:
    """Winter's residual analysis; returns ``(cutoff_hz, residuals (len(candidates),))``.

    ``x`` is ``(n,)`` or ``(n, k)`` (channels pooled); ``candidates`` default to 1 … 0.4·fs/2 Hz
    in 40 steps. The noise line is fitted over the upper half of the candidates.
    """
    x = np.asarray(x, dtype=float)
    fs = float(fs)
    cands = np.linspace(1.0, 0.4 * fs / 2, 40) if candidates is None else np.asarray(candidates, float)
    res = np.array([np.sqrt(np.nanmean((x - butterworth(x, fs, c, order=order)) ** 2)) for c in cands])
    hi = cands >= np.median(cands)
    _, icpt = np.polyfit(cands[hi], res[hi], 1)
    above = np.flatnonzero(res <= icpt)
    return float(cands[above[0]] if above.size else cands[-1]), res


def filter_poses(poses, fs: float, cutoff_hz: float, *, center=None, order: int = 2) -> np.ndarray:
    """Low-pass a pose series (``(n, 4, 4)``): the path of ``center`` (bone frame, mm; default
    the origin) and the rotation (rotation vectors relative to the first valid frame, made
    continuous) are filtered with :func:`butterworth`; NaN frames stay NaN."""
    P = np.asarray(poses, dtype=float)
    if P.ndim != 3 or P.shape[1:] != (4, 4):
        raise ValueError(f"poses: expected shape (n, 4, 4), got {P.shape}")
    c = np.zeros(3) if center is None else np.asarray(center, float)
    ok = np.all(np.isfinite(P), axis=(1, 2))
    if not ok.any():
        return P.copy()
    ref = P[np.flatnonzero(ok)[0], :3, :3]
    pos = np.full((len(P), 3), np.nan)
    rv = np.full((len(P), 3), np.nan)
    pos[ok] = P[ok, :3, :3] @ c + P[ok, :3, 3]
    rv[ok] = Rotation.from_matrix(P[ok, :3, :3] @ ref.T).as_rotvec()
    pos_f = butterworth(pos, fs, cutoff_hz, order=order)
    rv_f = butterworth(rv, fs, cutoff_hz, order=order)
    out = np.full_like(P, np.nan)
    R = Rotation.from_rotvec(rv_f[ok]).as_matrix() @ ref
    out[ok, :3, :3] = R
    out[ok, :3, 3] = pos_f[ok] - R @ c
    out[ok, 3] = [0, 0, 0, 1]
    return out


# ---------------------------------------------------------------------------- anatomical frames
def frame_from_axes(origin, x_axis, y_axis) -> np.ndarray:
    """``T_bone_from_anatomical`` (4×4): origin (bone frame, mm), x along ``x_axis``, y the part
    of ``y_axis`` orthogonal to x, z = x × y (right-handed)."""
    x = np.asarray(x_axis, float)
    y = np.asarray(y_axis, float)
    nx, ny = np.linalg.norm(x), np.linalg.norm(y)
    if nx == 0 or np.linalg.norm(np.cross(x, y)) < 1e-9 * nx * ny:
        raise ValueError("x_axis, y_axis: expected two non-zero, non-parallel directions")
    x = x / np.linalg.norm(x)
    y = y - (y @ x) * x
    y /= np.linalg.norm(y)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, y, np.cross(x, y)])
    T[:3, 3] = origin
    return T


def principal_axes_frame(points, *, long_axis: str = "z") -> np.ndarray:
    """``T_bone_from_anatomical`` from the principal axes of ``points (n, 3)`` (bone frame, mm —
    e.g. the mask's voxel centres or the mesh vertices): origin at their mean, the axis of largest
    extent along ``long_axis`` and the others by decreasing extent on the remaining axes in x, y,
    z order; signs make each axis point towards the side with the farther extreme point, and the
    frame is right-handed."""
    X = np.asarray(points, dtype=float)
    if X.ndim != 2 or X.shape[1] != 3 or len(X) < 4:
        raise ValueError(f"points: expected (n >= 4, 3) points, got shape {X.shape}")
    if long_axis not in ("x", "y", "z"):
        raise ValueError(f"long_axis: expected 'x', 'y' or 'z', got {long_axis!r}")
    m = X.mean(axis=0)
    w, V = np.linalg.eigh(np.cov((X - m).T))
    V = V[:, np.argsort(w)[::-1]]
    for k in range(3):
        proj = (X - m) @ V[:, k]
        if abs(proj.min()) > proj.max():
            V[:, k] = -V[:, k]
    slot = "xyz".index(long_axis)
    others = [i for i in range(3) if i != slot]
    A = np.zeros((3, 3))
    A[:, slot] = V[:, 0]
    A[:, others[0]], A[:, others[1]] = V[:, 1], V[:, 2]
    if np.linalg.det(A) < 0:
        A[:, others[1]] = -A[:, others[1]]
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = A, m
    return T


# ---------------------------------------------------------------------------- joint angles
def joint_angles(prox_poses, dist_poses, *, prox_frame=None, dist_frame=None, e1_axis: str = "z",
                 e3_axis: str = "y") -> dict[str, np.ndarray]:
    """Grood–Suntay JCS angles (radians) and translations (mm) per frame (see the module docs).

    Parameters
    ----------
    prox_poses, dist_poses : (n, 4, 4)
        ``T_lab_from_bone`` of the proximal and distal bones.
    prox_frame, dist_frame : (4, 4), optional
        ``T_bone_from_anatomical`` of each bone (default identity).
    e1_axis, e3_axis : {"x", "y", "z"}
        Anatomical axis of the proximal bone that is e1, and of the distal bone that is e3.

    Returns
    -------
    dict with ``"angles" (n, 3)`` (about e1, e2, e3), ``"translations" (n, 3)``, ``"sequence"``.
    """
    if e1_axis not in "xyz" or e3_axis not in "xyz" or e1_axis == e3_axis or len(e1_axis + e3_axis) != 2:
        raise ValueError(f"e1_axis, e3_axis: expected two different axes of 'x', 'y', 'z', got {e1_axis!r}, "
                         f"{e3_axis!r}")
    Pp, Pd = np.asarray(prox_poses, float), np.asarray(dist_poses, float)
    if Pp.shape != Pd.shape or Pp.ndim != 3 or Pp.shape[1:] != (4, 4):
        raise ValueError(f"prox_poses, dist_poses: expected two (n, 4, 4) series, got {Pp.shape}, {Pd.shape}")
    Ap = Pp @ (np.eye(4) if prox_frame is None else np.asarray(prox_frame, float))
    Ad = Pd @ (np.eye(4) if dist_frame is None else np.asarray(dist_frame, float))
    floating = ({"x", "y", "z"} - {e1_axis, e3_axis}).pop()
    seq = (e1_axis + floating + e3_axis).upper()
    n = len(Pp)
    ang = np.full((n, 3), np.nan)
    tra = np.full((n, 3), np.nan)
    ok = np.all(np.isfinite(Ap), axis=(1, 2)) & np.all(np.isfinite(Ad), axis=(1, 2))
    if ok.any():
        Rrel = np.swapaxes(Ap[ok, :3, :3], 1, 2) @ Ad[ok, :3, :3]
        ang[ok] = Rotation.from_matrix(Rrel).as_euler(seq)
        e1 = Ap[ok, :3, "xyz".index(e1_axis)]
        e3 = Ad[ok, :3, "xyz".index(e3_axis)]
        e2 = np.cross(e3, e1)
        e2 /= np.linalg.norm(e2, axis=1, keepdims=True)
        d = Ad[ok, :3, 3] - Ap[ok, :3, 3]
        B = np.stack([e1, e2, e3], axis=2)
        tra[ok] = np.linalg.solve(B, d[..., None])[..., 0]
    return {"angles": ang, "translations": tra, "sequence": seq}


# ---------------------------------------------------------------------------- helical axes
def helical_axes(prox_poses, dist_poses=None, *, step: int = 1) -> dict[str, np.ndarray]:
    """Finite helical axes of the motion between frames ``i`` and ``i + step``.

    With ``dist_poses`` the motion is the distal bone's relative to the proximal one (in the
    proximal bone's frame); otherwise the bone's own motion in the lab. Returns ``axis (m, 3)``
    (unit), ``angle (m,)`` radians in [0, π], ``translation (m,)`` mm along the axis, ``point
    (m, 3)`` (the axis point nearest the origin) — NaN where a frame is missing or the rotation is
    below 1e-9 rad (pure translation: no axis).
    """
    P = np.asarray(prox_poses, float)
    if dist_poses is not None:
        P = np.linalg.inv(P) @ np.asarray(dist_poses, float)
    if int(step) != step or step < 1:
        raise ValueError(f"step: expected an integer >= 1, got {step!r}")
    A, B = P[:-step], P[step:]
    m = len(A)
    out = {k: np.full((m, 3), np.nan) for k in ("axis", "point")}
    out["angle"] = np.full(m, np.nan)
    out["translation"] = np.full(m, np.nan)
    ok = np.all(np.isfinite(A), axis=(1, 2)) & np.all(np.isfinite(B), axis=(1, 2))
    if not ok.any():
        return out
    D = B[ok] @ np.linalg.inv(A[ok])  # motion in the reference frame
    rv = Rotation.from_matrix(D[:, :3, :3]).as_rotvec()
    th = np.linalg.norm(rv, axis=1)
    good = th > 1e-9
    n = np.full_like(rv, np.nan)
    n[good] = rv[good] / th[good, None]
    t = D[:, :3, 3]
    s = np.einsum("ij,ij->i", n, t)
    # point on the axis nearest the origin: solve (I - R) p = t - s n with p ⟂ n
    pts = np.full_like(rv, np.nan)
    for k in np.flatnonzero(good):
        M = np.vstack([np.eye(3) - D[k, :3, :3], n[k][None]])
        rhs = np.r_[t[k] - s[k] * n[k], 0.0]
        pts[k] = np.linalg.lstsq(M, rhs, rcond=None)[0]
    idx = np.flatnonzero(ok)
    out["axis"][idx], out["angle"][idx], out["translation"][idx], out["point"][idx] = n, th, s, pts
    out["angle"][idx[~good]] = th[~good]
    return out


# ---------------------------------------------------------------------------- joint space
def _one_way(Pa, Va, Fb_tri, Vb, tree, k):
    d, j = tree.query(Pa, k=1)
    cand = np.argsort(d)[:k]
    best = (np.inf, None, None)
    for i in cand:
        tris = Fb_tri[j[i]]
        a, b, c = (Vb[tris[:, m]] for m in range(3))
        p = np.repeat(Pa[i][None], len(tris), axis=0)
        q = closest_point_on_triangles(p, a, b, c)
        dist = np.linalg.norm(q - p, axis=1)
        m = int(np.argmin(dist))
        if dist[m] < best[0]:
            best = (float(dist[m]), Pa[i], q[m])
    return best


def min_distance(mesh_a, mesh_b, poses_a, poses_b, *, candidates: int = 32) -> dict[str, np.ndarray]:
    """Minimum surface-to-surface distance (mm) per frame between two bones.

    ``mesh_a``, ``mesh_b``: ``(vertices (n, 3), faces (m, 3))`` in each bone's CT frame (e.g.
    :class:`~core.tracking.bones.BoneModel` ``.vertices``/``.faces``); ``poses_*``: ``(n, 4, 4)``.
    For each direction the ``candidates`` vertices closest to the other surface's vertices (k-d
    tree) are projected exactly onto the triangles around their nearest vertex; the smaller of
    both directions is returned with its closest points ``point_a``, ``point_b`` (lab, mm).
    """
    from scipy.spatial import cKDTree

    (Va, Fa), (Vb, Fb) = ((np.asarray(v, float), np.asarray(f, np.int64)) for v, f in (mesh_a, mesh_b))
    if len(Va) == 0 or len(Vb) == 0:
        raise ValueError("mesh_a, mesh_b: expected non-empty meshes (build the bone models with mesh=True)")

    def incident(V, F):
        inc = [[] for _ in range(len(V))]
        for t, (i, j, k) in enumerate(F):
            inc[i].append(t)
            inc[j].append(t)
            inc[k].append(t)
        return [F[np.array(x, dtype=np.int64)] if x else np.zeros((0, 3), np.int64) for x in inc]

    inc_a, inc_b = incident(Va, Fa), incident(Vb, Fb)
    PA, PB = np.asarray(poses_a, float), np.asarray(poses_b, float)
    n = len(PA)
    out = {"distance": np.full(n, np.nan), "point_a": np.full((n, 3), np.nan),
           "point_b": np.full((n, 3), np.nan)}
    for f in range(n):
        if not (np.all(np.isfinite(PA[f])) and np.all(np.isfinite(PB[f]))):
            continue
        A = Va @ PA[f, :3, :3].T + PA[f, :3, 3]
        B = Vb @ PB[f, :3, :3].T + PB[f, :3, 3]
        dab = _one_way(A, Va, inc_b, B, cKDTree(B), candidates)
        dba = _one_way(B, Vb, inc_a, A, cKDTree(A), candidates)
        if dab[0] <= dba[0]:
            out["distance"][f], out["point_a"][f], out["point_b"][f] = dab
        else:
            out["distance"][f], out["point_b"][f], out["point_a"][f] = dba
    return out


# ---------------------------------------------------------------------------- exports
def _series(poses: Mapping[str, np.ndarray]) -> tuple[list[str], int]:
    names = list(poses)
    if not names:
        raise ValueError("poses: expected at least one bone")
    n = {np.asarray(poses[b]).shape for b in names}
    if len(n) != 1 or next(iter(n))[1:] != (4, 4):
        raise ValueError(f"poses: expected (n_frames, 4, 4) per bone, all the same length, got {n}")
    return names, next(iter(n))[0]


def export_csv(path, poses: Mapping[str, np.ndarray], *, layout: str = "matrix", euler: str = "xyz") -> None:
    """CSV, one row per frame: ``frame`` then per bone 16 values (``layout="matrix"``, row-major
    ``T_lab_from_bone``, mm) or 6-DOF (``layout="6dof"``: ``tx, ty, tz`` mm and extrinsic
    ``euler`` angles in degrees). Missing frames are empty cells. Written atomically."""
    from ..io.atomic import atomic_write

    names, n = _series(poses)
    if layout not in ("matrix", "6dof"):
        raise ValueError(f"layout: expected 'matrix' or '6dof', got {layout!r}")
    head = ["frame"]
    for b in names:
        head += ([f"{b}_T{r}{c}" for r in range(4) for c in range(4)] if layout == "matrix"
                 else [f"{b}_{k}" for k in ("tx_mm", "ty_mm", "tz_mm")] + [f"{b}_r{a}_deg" for a in euler])
    rows = [",".join(head)]
    for f in range(n):
        vals = [str(f)]
        for b in names:
            T = np.asarray(poses[b][f], float)
            if not np.all(np.isfinite(T)):
                vals += [""] * (16 if layout == "matrix" else 6)
            elif layout == "matrix":
                vals += [repr(float(x)) for x in T.ravel()]
            else:
                ang = Rotation.from_matrix(T[:3, :3]).as_euler(euler, degrees=True)
                vals += [repr(float(x)) for x in (*T[:3, 3], *ang)]
        rows.append(",".join(vals))
    atomic_write(path, "\n".join(rows) + "\n")


def export_tra(path, poses: Mapping[str, np.ndarray], **options) -> None:
    """Autoscoper ``.tra`` of the bones in ``poses`` order (:func:`core.io.autoscoper.write_tra`)."""
    from ..io.autoscoper import write_tra

    names, _ = _series(poses)
    write_tra(path, np.stack([np.asarray(poses[b], float) for b in names], axis=1), **options)


def export_json(path, poses: Mapping[str, np.ndarray], *, scores: Mapping[str, np.ndarray] | None = None,
                extra: dict | None = None) -> None:
    """JSON ``{"bones": {name: {"poses": [16 numbers or null per frame], "scores": [...]}}, ...}``."""
    from ..io.atomic import atomic_write_json

    names, n = _series(poses)
    doc = {"convention": "T_lab_from_bone, row-major 4x4, mm", "n_frames": n, "bones": {}}
    for b in names:
        P = np.asarray(poses[b], float)
        doc["bones"][b] = {"poses": [P[f].ravel().tolist() if np.all(np.isfinite(P[f])) else None
                                     for f in range(n)]}
        if scores is not None and b in scores:
            doc["bones"][b]["scores"] = [None if not np.isfinite(s) else float(s) for s in scores[b]]
    if extra:
        doc.update(extra)
    atomic_write_json(path, doc)
