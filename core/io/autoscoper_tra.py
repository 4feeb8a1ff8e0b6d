"""Autoscoper ``.tra`` tracking-result files (read/write) and the ``xyzypr`` pose convention.

One line per frame; on each line the values of every volume one after the other, separated by
commas or spaces (Autoscoper ``AutoscoperMainWindow::save_tracking_results`` /
``load_tracking_results``). Per volume either 16 values (a 4x4 matrix, written row by row —
"row" order, Autoscoper's default — or column by column) or 6 values ``x y z yaw pitch roll``
with ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (``CoordFrame::from_xyzypr``; degrees unless radians
were chosen). Translations are in mm or cm. ``NaN`` values mark an untracked frame.

The matrices are read and written as they are. Autoscoper's files hold the pose of its *volume
frame* (the TIFF stack turned 180° about x, after its flips; no pivot): convert them to and from
Talus's ``T_lab_from_bone`` with :func:`core.io.autoscoper_pose.lab_from_bone_from_tra` and
:func:`~core.io.autoscoper_pose.tra_from_lab_from_bone` (re-exported here), whose docs cite the
lines of Autoscoper's source that settled each convention.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from .atomic import atomic_write
from .autoscoper_pose import lab_from_bone_from_tra, tra_from_lab_from_bone
from .errors import reads

__all__ = [
    "lab_from_bone_from_tra",
    "matrix_to_xyzypr",
    "read_tra",
    "tra_from_lab_from_bone",
    "write_tra",
    "xyzypr_to_matrix",
]


def _text_lines(path: Path, what: str) -> list[str]:
    if not path.is_file():
        raise ValueError(f"path: no such {what} file: {path}")
    try:
        return path.read_text(encoding="utf-8-sig").splitlines()
    except UnicodeDecodeError as exc:
        raise ValueError(
            f"{path}: expected a text {what} file, got undecodable bytes ({exc.reason})"
        ) from None


def xyzypr_to_matrix(xyzypr, *, degrees: bool = True) -> np.ndarray:
    """4x4 matrices ``(..., 4, 4)`` from ``(..., 6)`` ``x, y, z, yaw, pitch, roll``.

    ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (Autoscoper ``CoordFrame::from_xyzypr``).
    """
    a = np.asarray(xyzypr, dtype=float)
    if a.shape[-1:] != (6,):
        raise ValueError(f"xyzypr: expected shape (..., 6), got {a.shape}")
    ang = np.radians(a[..., 3:]) if degrees else a[..., 3:]
    cz, sz = np.cos(ang[..., 0]), np.sin(ang[..., 0])
    cy, sy = np.cos(ang[..., 1]), np.sin(ang[..., 1])
    cx, sx = np.cos(ang[..., 2]), np.sin(ang[..., 2])
    T = np.zeros((*a.shape[:-1], 4, 4))
    T[..., 0, 0], T[..., 0, 1], T[..., 0, 2] = cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx
    T[..., 1, 0], T[..., 1, 1], T[..., 1, 2] = sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx
    T[..., 2, 0], T[..., 2, 1], T[..., 2, 2] = -sy, cy * sx, cy * cx
    T[..., :3, 3] = a[..., :3]
    T[..., 3, 3] = 1.0
    return T


def matrix_to_xyzypr(T, *, degrees: bool = True) -> np.ndarray:
    """Inverse of :func:`xyzypr_to_matrix` (Autoscoper ``CoordFrame::to_xyzypr``), pitch in [-90, 90]."""
    T = np.asarray(T, dtype=float)
    if T.shape[-2:] != (4, 4):
        raise ValueError(f"T: expected shape (..., 4, 4), got {T.shape}")
    R = T[..., :3, :3]
    yaw = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    pitch = np.arctan2(-R[..., 2, 0], np.hypot(R[..., 2, 1], R[..., 2, 2]))
    roll = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    ang = np.stack([yaw, pitch, roll], axis=-1)
    return np.concatenate([T[..., :3, 3], np.degrees(ang) if degrees else ang], axis=-1)


_TRA_OPTS = {
    "layout": ("auto", "matrix", "xyzypr"),
    "order": ("auto", "row", "column"),
    "units": ("mm", "cm"),
    "angles": ("deg", "rad"),
}


def _opt(name: str, value: str, allow_auto: bool = True) -> str:
    allowed = _TRA_OPTS[name] if allow_auto else tuple(v for v in _TRA_OPTS[name] if v != "auto")
    if value not in allowed:
        raise ValueError(f"{name}: expected one of {allowed}, got {value!r}")
    return value


def _split_values(path: Path, lineno: int, line: str) -> np.ndarray:
    parts = [p for p in re.split(r"[,\s]+", line.strip()) if p]
    vals = np.empty(len(parts))
    for i, p in enumerate(parts):
        try:
            vals[i] = float(p)
        except ValueError:
            raise ValueError(f"{path}: line {lineno}: expected numbers or NaN, got {p!r}") from None
    if np.isinf(vals).any():
        raise ValueError(f"{path}: line {lineno}: infinite value")
    return vals


def _matrices(vals: np.ndarray, order: str) -> np.ndarray:
    m = vals.reshape(-1, 4, 4)
    return m if order == "row" else m.transpose(0, 2, 1)


def _rigid_ok(m: np.ndarray, tol: float = 1e-4) -> np.ndarray:
    R = m[:, :3, :3]
    orth = np.abs(R @ R.transpose(0, 2, 1) - np.eye(3)).max(axis=(1, 2)) < tol
    last = np.abs(m[:, 3] - [0, 0, 0, 1]).max(axis=1) < tol
    return orth & last & (np.linalg.det(R) > 0)


def read_tra(
    path: str | os.PathLike,
    *,
    n_volumes: int | None = None,
    layout: str = "auto",
    order: str = "auto",
    units: str = "mm",
    angles: str = "deg",
) -> np.ndarray:
    """Read an Autoscoper ``.tra`` file.

    Parameters
    ----------
    path : str or os.PathLike
    n_volumes : int, optional
        Volumes per line; inferred from the value count when unambiguous.
    layout : {"auto", "matrix", "xyzypr"}
        16 or 6 values per volume; ``"auto"`` decides from the count (and, for counts that fit
        both, from which reading gives valid rigid transforms).
    order : {"auto", "row", "column"}
        Matrix value order; ``"auto"`` takes the one whose last row is ``0 0 0 1``.
    units : {"mm", "cm"}
        Translation units in the file (returned in mm).
    angles : {"deg", "rad"}
        xyzypr angle units.

    Returns
    -------
    (n_frames, n_volumes, 4, 4) array
        Poses (mm); NaN matrices for untracked frames.

    Raises
    ------
    ValueError
        Non-numeric values, inconsistent counts, partly-NaN poses, non-rigid matrices or an
        ambiguous layout/order; the message names the file and line.
    """
    for name, value in (("layout", layout), ("order", order), ("units", units), ("angles", angles)):
        _opt(name, value)
    return _read_tra(Path(path), n_volumes, layout, order, units, angles)


@reads("an Autoscoper .tra pose file (one line of 16 or 6 numbers per volume and frame)")
def _read_tra(path: Path, n_volumes, layout, order, units, angles) -> np.ndarray:
    rows = []
    for lineno, line in enumerate(_text_lines(path, "Autoscoper .tra"), start=1):
        if not line.strip():
            continue
        rows.append((lineno, _split_values(path, lineno, line)))
    if not rows:
        raise ValueError(f"{path}: no pose lines (expected one line of numbers per frame)")
    counts = {len(v) for _, v in rows}
    if len(counts) != 1:
        lineno, v = next((ln, v) for ln, v in rows if len(v) != len(rows[0][1]))
        raise ValueError(
            f"{path}: line {lineno}: {len(v)} values, expected {len(rows[0][1])} like line {rows[0][0]}"
        )
    nval = counts.pop()
    data = np.stack([v for _, v in rows])
    layouts = [layout] if layout != "auto" else ["matrix", "xyzypr"]
    candidates = []
    for lay in layouts:
        per = 16 if lay == "matrix" else 6
        if nval % per or (n_volumes is not None and nval != per * n_volumes):
            continue
        candidates.append(lay)
    if not candidates:
        want = f"{n_volumes} volume(s) x " if n_volumes else "a multiple of "
        raise ValueError(f"{path}: {nval} values per line; expected {want}16 (matrix) or 6 (xyzypr) values")
    errors = []
    for lay in candidates:
        try:
            return _decode_tra(path, rows, data, lay, order, units, angles)
        except ValueError as exc:
            errors.append(exc)
    raise errors[0] if len(errors) == 1 else ValueError(
        f"{path}: {nval} values per line fit neither 16-value matrices nor 6-value xyzypr poses "
        f"({errors[0]}; {errors[1]})"
    )


def _decode_tra(path, rows, data, layout, order, units, angles) -> np.ndarray:
    per = 16 if layout == "matrix" else 6
    n_frames, nv = data.shape[0], data.shape[1] // per
    vals = data.reshape(n_frames, nv, per)
    nan = np.isnan(vals)
    partial = nan.any(axis=2) & ~nan.all(axis=2)
    if partial.any():
        f, v = np.argwhere(partial)[0]
        raise ValueError(
            f"{path}: line {rows[f][0]}: volume {v} has some NaN and some numbers; expected all or none"
        )
    tracked = ~nan.any(axis=2)
    out = np.full((n_frames, nv, 4, 4), np.nan)
    scale = 10.0 if units == "cm" else 1.0
    if layout == "xyzypr":
        T = xyzypr_to_matrix(vals[tracked], degrees=angles == "deg")
    else:
        flat = vals[tracked]
        orders = [order] if order != "auto" else ["row", "column"]
        ok = {o: _rigid_ok(_matrices(flat, o)) for o in orders}
        if order == "auto":
            if ok["row"].all() and ok["column"].all() and len(flat):
                raise ValueError(
                    f"{path}: matrix order is ambiguous (every pose reads as rigid both row- and "
                    "column-wise); pass order='row' or order='column'"
                )
            order = "row" if ok["row"].all() else "column"
        if len(flat) and not ok[order].all():
            bad = np.argwhere(tracked)[np.flatnonzero(~ok[order])[0]]
            raise ValueError(
                f"{path}: line {rows[bad[0]][0]}: volume {bad[1]} is not a rigid 4x4 matrix in {order} order "
                "(orthonormal rotation, last row 0 0 0 1)"
            )
        T = _matrices(flat, order).copy()
    T[:, :3, 3] *= scale
    out[tracked] = T
    return out


def write_tra(
    path: str | os.PathLike,
    poses,
    *,
    layout: str = "matrix",
    order: str = "row",
    separator: str = ",",
    units: str = "mm",
    angles: str = "deg",
) -> None:
    """Write poses as an Autoscoper ``.tra`` file, atomically.

    Parameters
    ----------
    poses : (n_frames, 4, 4) or (n_frames, n_volumes, 4, 4) array
        Rigid transforms (mm); a frame whose matrix holds any NaN is written as NaNs.
    layout, order, units, angles
        As in :func:`read_tra` (no ``"auto"``).
    separator : {",", " "}
        Value separator.
    """
    P = np.asarray(poses, dtype=float)
    if P.ndim == 3:
        P = P[:, None]
    if P.ndim != 4 or P.shape[2:] != (4, 4) or P.shape[0] < 1:
        raise ValueError(f"poses: expected shape (n_frames, [n_volumes,] 4, 4), got {np.shape(poses)}")
    layout = _opt("layout", layout, False)
    order = _opt("order", order, False)
    units = _opt("units", units, False)
    angles = _opt("angles", angles, False)
    if separator not in (",", " "):
        raise ValueError(f'separator: expected "," or " ", got {separator!r}')
    valid = ~np.isnan(P).any(axis=(2, 3))
    good = P[valid]
    if good.size and not _rigid_ok(good, 1e-6).all():
        f, v = np.argwhere(valid)[np.flatnonzero(~_rigid_ok(good, 1e-6))[0]]
        raise ValueError(f"poses[{f}, {v}]: expected a rigid 4x4 transform")
    per = 16 if layout == "matrix" else 6
    lines = []
    for f in range(P.shape[0]):
        vals = []
        for v in range(P.shape[1]):
            if not valid[f, v]:
                vals += ["NaN"] * per
                continue
            T = P[f, v].copy()
            T[:3, 3] /= 10.0 if units == "cm" else 1.0
            if layout == "matrix":
                nums = (T if order == "row" else T.T).ravel()
            else:
                nums = matrix_to_xyzypr(T, degrees=angles == "deg")
            vals += [repr(float(x)) for x in nums]
        lines.append(separator.join(vals))
    atomic_write(path, "\n".join(lines) + "\n")


