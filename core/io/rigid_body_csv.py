"""XMALab / XROMM rigid-body transformation CSV (read/write), the file Maya's XROMM tools import.

Layout, from XMALab's ``Trial::saveRigidBodyTransformations`` (XROMMPackages/xmalab,
``src/core/Trial.cpp`` lines 941-1033) and ``RigidBody::getTransformationMatrix``
(``src/core/RigidBody.cpp`` lines 2264-2300):

* optional header row: per body the 16 names ``<body>_R11, _R12, _R13, _01, _R21, _R22, _R23,
  _02, _R31, _R32, _R33, _03, _TX, _TY, _TZ, _1``, each followed by ``_<cutoff>Hz`` when the
  poses were filtered (Trial.cpp 975-993); an unnamed body is ``RigidBody001`` …;
* optional first column ``Frame`` holding the 1-based frame number (Trial.cpp 958, 1012);
* per body 16 numbers, ``NaN`` x 16 for a frame without a pose (Trial.cpp 1015-1026).

The 16 numbers are Maya's row-vector matrix: ``trans[4 y + x] = R[y, x]`` and the translation in
``trans[12..14]`` (RigidBody.cpp 2277-2298), i.e. the column-vector ``T_lab_from_body`` written
column by column. Talus reads them into ``(n_frames, n_bodies, 4, 4)`` column-vector matrices.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .atomic import atomic_write
from .errors import reads

__all__ = ["RigidBodyTransforms", "read_rigid_body_csv", "write_rigid_body_csv"]

SUFFIXES = (
    "R11", "R12", "R13", "01", "R21", "R22", "R23", "02", "R31", "R32", "R33", "03", "TX", "TY", "TZ", "1"
)
_HEAD = re.compile(r"^(?P<body>.+)_(?P<col>R\d\d|0[123]|T[XYZ]|1)(?:_(?P<hz>[0-9.eE+-]+)Hz)?$")


@dataclass(frozen=True)
class RigidBodyTransforms:
    """Poses of named rigid bodies: ``poses[f, b]`` = ``T_lab_from_body`` (NaN when untracked)."""

    bodies: tuple[str, ...]
    poses: np.ndarray  # (n_frames, n_bodies, 4, 4)
    frames: np.ndarray  # (n_frames,) 1-based frame numbers
    cutoff_hz: tuple[float | None, ...]


def write_rigid_body_csv(
    path: str | os.PathLike,
    bodies,
    poses,
    *,
    frames=None,
    frame_column: bool = True,
    header: bool = True,
    cutoff_hz=None,
) -> None:
    """Write ``poses`` ``(n_frames, n_bodies, 4, 4)`` as XMALab writes them, atomically.

    ``frames`` are the 1-based numbers of the ``Frame`` column (default 1..n); ``cutoff_hz`` (one
    number, or one per body) adds XMALab's ``_<Hz>Hz`` suffix of filtered poses.
    """
    names = tuple(str(b) for b in bodies)
    P = np.asarray(poses, dtype=float)
    if P.ndim == 3:
        P = P[:, None]
    if P.ndim != 4 or P.shape[1:] != (len(names), 4, 4) or not len(P):
        raise ValueError(f"poses: expected shape (n_frames, {len(names)}, 4, 4), got {np.shape(poses)}")
    for n in names:
        if not n or "," in n or "\n" in n or "\r" in n:
            raise ValueError(f"bodies: expected names without commas or line breaks, got {n!r}")
    fr = np.arange(1, len(P) + 1) if frames is None else np.asarray(frames)
    if fr.shape != (len(P),):
        raise ValueError(f"frames: expected {len(P)} frame numbers, got shape {fr.shape}")
    hz = [cutoff_hz] * len(names) if cutoff_hz is None or np.ndim(cutoff_hz) == 0 else list(cutoff_hz)
    if len(hz) != len(names):
        raise ValueError(f"cutoff_hz: expected one value or {len(names)}, got {len(hz)}")
    lines = []
    if header:
        cols = ["Frame"] if frame_column else []
        for n, h in zip(names, hz, strict=True):
            sfx = "" if h is None else f"_{float(h):g}Hz"
            cols += [f"{n}_{s}{sfx}" for s in SUFFIXES]
        lines.append(",".join(cols))
    for f in range(len(P)):
        vals = [str(int(fr[f]))] if frame_column else []
        for b in range(len(names)):
            T = P[f, b]
            if np.isnan(T).any():
                vals += ["NaN"] * 16
            else:
                vals += [repr(float(x)) for x in T.T.ravel()]
        lines.append(",".join(vals))
    atomic_write(path, "\n".join(lines) + "\n")


def read_rigid_body_csv(path: str | os.PathLike) -> RigidBodyTransforms:
    """Read an XMALab rigid-body transformation CSV (with or without header and Frame column).

    Raises
    ------
    FileError
        Naming the file and line: not 16 numbers per body, a body partly NaN, a matrix whose
        last column is not ``0 0 0 1`` or whose rotation is not orthonormal, a malformed header.
    """
    return _read(Path(path))


def _num(path, lineno, s: str) -> float:
    try:
        v = float(s)
    except ValueError:
        raise ValueError(f"{path}: line {lineno}: expected a number or NaN, got {s.strip()!r}") from None
    if math.isinf(v):
        raise ValueError(f"{path}: line {lineno}: infinite value")
    return v


@reads("an XMALab rigid-body transformation CSV (16 columns R11..R33, 01..03, TX TY TZ 1 per body)")
def _read(path: Path) -> RigidBodyTransforms:
    lines = [ln for ln in path.read_text(encoding="utf-8-sig").splitlines()]
    rows = [(i, ln) for i, ln in enumerate(lines, start=1) if ln.strip()]
    if not rows:
        raise ValueError(f"{path}: empty file (expected one line per frame)")
    first = [c.strip() for c in rows[0][1].split(",")]
    has_header = any(re.search(r"[A-Za-z]", c) and c.lower() != "nan" for c in first)
    names: list[str] = []
    hz: list[float | None] = []
    frame_col = False
    if has_header:
        cols = first
        if cols and cols[0].lower() == "frame":
            frame_col, cols = True, cols[1:]
        if not cols or len(cols) % 16:
            raise ValueError(f"{path}: line {rows[0][0]}: {len(cols)} pose columns, expected 16 per body")
        for b in range(len(cols) // 16):
            block = cols[16 * b : 16 * b + 16]
            ms = [_HEAD.match(c) for c in block]
            if not all(ms) or [m["col"] for m in ms] != list(SUFFIXES) or len({m["body"] for m in ms}) != 1:
                raise ValueError(
                    f"{path}: line {rows[0][0]}: columns {16 * b + 1}-{16 * b + 16} are not one body's "
                    f"<body>_R11 ... <body>_1, got {block[0]!r} ... {block[-1]!r}"
                )
            names.append(ms[0]["body"])
            hz.append(float(ms[0]["hz"]) if ms[0]["hz"] else None)
        data_rows = rows[1:]
    else:
        data_rows = rows
    if not data_rows:
        raise ValueError(f"{path}: no pose lines after the header")
    width = len(data_rows[0][1].split(","))
    if not has_header:
        frame_col = width % 16 == 1
        if width % 16 not in (0, 1) or width < 16:
            raise ValueError(f"{path}: line {data_rows[0][0]}: {width} values, expected 16 per body "
                             "(and an optional frame number first)")
        nb = width // 16
        names = [f"RigidBody{b + 1:03d}" for b in range(nb)]
        hz = [None] * nb
    nb = len(names)
    want = 16 * nb + frame_col
    frames, poses = [], []
    for lineno, ln in data_rows:
        parts = ln.split(",")
        if parts and parts[-1].strip() == "" and len(parts) == want + 1:
            parts = parts[:-1]
        if len(parts) != want:
            raise ValueError(f"{path}: line {lineno}: {len(parts)} values, expected {want}")
        vals = [_num(path, lineno, p) for p in parts]
        if frame_col:
            fnum = vals.pop(0)
            if not float(fnum).is_integer() or fnum < 1:
                raise ValueError(f"{path}: line {lineno}: frame number {fnum!r}, expected an integer >= 1")
            frames.append(int(fnum))
        else:
            frames.append(len(frames) + 1)
        m = np.array(vals).reshape(nb, 4, 4).transpose(0, 2, 1)
        for b in range(nb):
            nan = np.isnan(m[b])
            if nan.any() and not nan.all():
                raise ValueError(f"{path}: line {lineno}: body {names[b]!r} has some NaN and some numbers")
            if not nan.any():
                R = m[b, :3, :3]
                if (np.abs(m[b, 3] - [0, 0, 0, 1]).max() > 1e-6
                        or np.abs(R @ R.T - np.eye(3)).max() > 1e-4 or np.linalg.det(R) < 0):
                    raise ValueError(
                        f"{path}: line {lineno}: body {names[b]!r} is not a rigid transform "
                        "(orthonormal R11..R33, 01 02 03 = 0 and 1 = 1)"
                    )
        poses.append(m)
    return RigidBodyTransforms(tuple(names), np.stack(poses), np.array(frames), tuple(hz))
