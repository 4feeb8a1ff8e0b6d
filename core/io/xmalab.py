"""XMALab / DLTdv interop: 11-coefficient DLT CSV files and 2D/3D marker point CSV files.

DLT coefficients (``*_DLTcoefs.csv``, DLTdv / easyWand / XMALab export)
    11 rows (``L1`` .. ``L11``) and one comma-separated column per camera, no header. The DLT is
    expressed in DLTdv image coordinates (1-based, vertical axis up: ``u + 1, height - v`` in
    Talus pixels); see :mod:`core.geometry.conversions`, which does every DLT <-> P conversion.
    A file with one row of 11 values per camera is also accepted.

2D points (XMALab "export 2D points", all markers in one file)
    One row per frame; per marker and camera two columns ``<name>_cam<j>_X, <name>_cam<j>_Y``
    (markers outer, cameras inner), optional header row, ``NaN`` for a marker not located in a
    view. XMALab writes ``" , "`` between values. Its internal coordinates are OpenCV pixels,
    which are Talus pixels (origin at the centre of the top-left pixel, v down); the export
    options "offset 1" (``+1`` to both) and "y invert" (``y -> height - 1 - y``) change that, and
    the same two flags are needed to read such a file back. Both together give DLTdv coordinates.

3D points (XMALab "export 3D points")
    One row per frame, ``<name>_X, <name>_Y, <name>_Z`` per marker (lab units, mm), optional
    header, ``NaN`` for a marker not reconstructed.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..geometry.camera import Rig
from ..geometry.conversions import camera_from_dlt, dlt_from_P
from .atomic import atomic_write
from .errors import reads

__all__ = [
    "dlt_csv_from_rig",
    "read_dlt_csv",
    "read_points_2d",
    "read_points_3d",
    "rig_from_dlt_csv",
    "write_dlt_csv",
    "write_points_2d",
    "write_points_3d",
]


def _rows(path: Path, what: str) -> list[tuple[int, list[str]]]:
    if not path.is_file():
        raise ValueError(f"path: no such {what} file: {path}")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ValueError(
            f"{path}: expected a text {what} file, got undecodable bytes ({exc.reason})"
        ) from None
    out = []
    for i, line in enumerate(text.splitlines(), start=1):
        if line.strip():
            out.append((i, [c.strip() for c in line.split(",")]))
    if not out:
        raise ValueError(f"{path}: empty {what} file")
    return out


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def _to_float(path: Path, lineno: int, cells: list[str], allow_nan: bool) -> np.ndarray:
    vals = np.empty(len(cells))
    for i, c in enumerate(cells):
        try:
            vals[i] = float(c)
        except ValueError:
            raise ValueError(f"{path}: line {lineno}, column {i + 1}: expected a number, got {c!r}") from None
        if math.isinf(vals[i]) or (math.isnan(vals[i]) and not allow_nan):
            raise ValueError(f"{path}: line {lineno}, column {i + 1}: expected a finite number, got {c!r}")
    return vals


# ---------------------------------------------------------------------------- DLT
@reads("an XMALab DLT coefficient CSV")
def read_dlt_csv(path: str | os.PathLike) -> np.ndarray:
    """The DLT coefficients of each camera, ``(n_cameras, 11)``, as stored (DLTdv image coordinates)."""
    path = Path(path)
    rows = _rows(path, "DLT coefficient CSV")
    widths = {len(c) for _, c in rows}
    if len(widths) != 1:
        raise ValueError(f"{path}: rows have different numbers of values {sorted(widths)}; expected a table")
    table = np.array([_to_float(path, ln, c, allow_nan=False) for ln, c in rows])
    if table.shape[0] == 11:
        return table.T.copy()
    if table.shape[1] == 11:
        return table
    raise ValueError(
        f"{path}: {table.shape[0]} rows of {table.shape[1]} values; expected 11 rows (L1..L11) with one "
        "column per camera"
    )


def write_dlt_csv(path: str | os.PathLike, coefficients) -> None:
    """Write ``(n_cameras, 11)`` DLT coefficients as 11 rows x cameras (DLTdv layout), atomically."""
    L = np.asarray(coefficients, dtype=float)
    if L.ndim == 1:
        L = L[None]
    if L.ndim != 2 or L.shape[1] != 11 or not np.all(np.isfinite(L)):
        raise ValueError(
            f"coefficients: expected finite (n_cameras, 11) values, got shape {np.shape(coefficients)}"
        )
    atomic_write(path, "\n".join(",".join(repr(float(x)) for x in row) for row in L.T) + "\n")


def dlt_csv_from_rig(rig: Rig, path: str | os.PathLike, *, convention: str = "dltdv") -> None:
    """Write a rig's cameras as a DLT CSV (``convention`` as in :func:`core.geometry.dlt_from_P`)."""
    if not isinstance(rig, Rig):
        raise ValueError(f"rig: expected a Rig, got {type(rig).__name__}")
    write_dlt_csv(path, [dlt_from_P(c.P, convention=convention, height=c.height) for c in rig])


def rig_from_dlt_csv(
    path: str | os.PathLike,
    image_sizes: Sequence[tuple[int, int]],
    *,
    convention: str = "dltdv",
    pixel_size: float | None = None,
    max_skew_px: float = 0.5,
) -> Rig:
    """Cameras from a DLT CSV: ``image_sizes`` gives ``(width, height)`` per camera (not in the file)."""
    path = Path(path)
    L = read_dlt_csv(path)
    if len(image_sizes) != len(L):
        raise ValueError(
            f"image_sizes: expected {len(L)} (width, height) pairs for {path}, got {len(image_sizes)}"
        )
    cams = []
    for j, (coef, (w, h)) in enumerate(zip(L, image_sizes, strict=True)):
        try:
            cams.append(camera_from_dlt(coef, w, h, convention=convention, pixel_size=pixel_size,
                                        name=f"{path.stem}_cam{j + 1}", max_skew_px=max_skew_px))
        except ValueError as exc:
            raise ValueError(f"{path}: camera {j + 1}: {exc}") from None
    return Rig(tuple(cams))


# ---------------------------------------------------------------------------- points
_HEAD2 = re.compile(r"^(.*)_cam(\d+)_([XY])$")
_HEAD3 = re.compile(r"^(.*)_([XYZ])$")


def _header_and_data(path: Path, rows, per: int, what: str):
    header = None
    if any(not _is_number(c) for c in rows[0][1]):
        header = rows[0][1]
        rows = rows[1:]
    widths = {len(c) for _, c in rows}
    if header is not None:
        widths.add(len(header))
    if len(widths) > 1:
        ln = next(ln for ln, c in rows if len(c) != (len(header) if header else len(rows[0][1])))
        raise ValueError(f"{path}: line {ln}: number of columns differs from the first row")
    width = widths.pop() if widths else 0
    if width == 0 or width % per:
        raise ValueError(f"{path}: {width} columns; expected a multiple of {per} for {what}")
    data = np.array([_to_float(path, ln, c, allow_nan=True) for ln, c in rows]).reshape(len(rows), width)
    return header, data


@reads("an XMALab 2D point CSV")
def read_points_2d(
    path: str | os.PathLike,
    *,
    n_cameras: int | None = None,
    offset1: bool = False,
    yinvert: bool = False,
    heights: Sequence[int] | None = None,
) -> tuple[tuple[str, ...], np.ndarray]:
    """Read an XMALab 2D point file.

    Parameters
    ----------
    path : str or os.PathLike
    n_cameras : int, optional
        Cameras per marker; read from the header when there is one, else required.
    offset1, yinvert : bool
        The XMALab export options the file was written with (see the module docstring).
    heights : sequence of int, optional
        Image height of each camera, required with ``yinvert``.

    Returns
    -------
    names : tuple of str
        Marker names (``marker001``... without a header).
    points : (n_frames, n_markers, n_cameras, 2) array
        ``(u, v)`` Talus pixels (column, row; origin at the centre of the top-left pixel); NaN
        where a marker was not located.
    """
    path = Path(path)
    header, data = _header_and_data(path, _rows(path, "2D point CSV"), 2, "X, Y pairs")
    if header is not None:
        parsed = [_HEAD2.match(h) for h in header]
        if not all(parsed):
            bad = header[[m is None for m in parsed].index(True)]
            raise ValueError(f"{path}: header column {bad!r}; expected <marker>_cam<j>_X / _Y")
        cams = max(int(m.group(2)) for m in parsed)
        if n_cameras is not None and n_cameras != cams:
            raise ValueError(f"n_cameras: {n_cameras} given but the header of {path} names {cams} camera(s)")
        n_cameras = cams
    if n_cameras is None or n_cameras < 1:
        raise ValueError(f"n_cameras: required (>= 1) for {path}, which has no header row")
    if data.shape[1] % (2 * n_cameras):
        raise ValueError(f"{path}: {data.shape[1]} columns is not 2 x {n_cameras} camera(s) x markers")
    n_markers = data.shape[1] // (2 * n_cameras)
    if header is not None:
        names = []
        for m in range(n_markers):
            base = 2 * n_cameras * m
            name = parsed[base].group(1)
            for j in range(n_cameras):
                for a, axis in enumerate("XY"):
                    got = parsed[base + 2 * j + a]
                    if (got.group(1), int(got.group(2)), got.group(3)) != (name, j + 1, axis):
                        raise ValueError(
                            f"{path}: header column {header[base + 2 * j + a]!r}; "
                            f"expected {name}_cam{j + 1}_{axis}"
                        )
            names.append(name)
    else:
        names = [f"marker{m + 1:03d}" for m in range(n_markers)]
    pts = data.reshape(len(data), n_markers, n_cameras, 2)
    half = np.isnan(pts).any(axis=3) & ~np.isnan(pts).all(axis=3)
    if half.any():
        f, m, j = np.argwhere(half)[0]
        raise ValueError(f"{path}: frame {f}: marker {names[m]!r} camera {j + 1} has one NaN coordinate")
    return tuple(names), _convert(pts, offset1, yinvert, heights, n_cameras, inverse=True)


def _convert(pts, offset1, yinvert, heights, n_cameras, *, inverse: bool) -> np.ndarray:
    pts = pts.astype(float).copy()
    if yinvert:
        if heights is None or len(heights) != n_cameras:
            raise ValueError(
                f"heights: expected {n_cameras} image height(s) with yinvert=True, got {heights!r}"
            )
        H = np.asarray(heights, dtype=float)
    if inverse:  # file -> Talus: undo +1, then the inversion (XMALab load2dPoints)
        if offset1:
            pts -= 1.0
        if yinvert:
            pts[..., 1] = H - 1.0 - pts[..., 1]
    else:  # Talus -> file (XMALab save2dPoints)
        if yinvert:
            pts[..., 1] = H - 1.0 - pts[..., 1]
        if offset1:
            pts += 1.0
    return pts


def write_points_2d(
    path: str | os.PathLike,
    names: Sequence[str],
    points,
    *,
    offset1: bool = False,
    yinvert: bool = False,
    heights: Sequence[int] | None = None,
    header: bool = True,
) -> None:
    """Write ``(n_frames, n_markers, n_cameras, 2)`` Talus pixel points as an XMALab 2D file."""
    P = np.asarray(points, dtype=float)
    if P.ndim != 4 or P.shape[3] != 2 or P.shape[1] != len(names):
        raise ValueError(f"points: expected (n_frames, {len(names)} markers, n_cameras, 2), got {P.shape}")
    n_cams = P.shape[2]
    out = _convert(P, offset1, yinvert, heights, n_cams, inverse=False)
    lines = []
    if header:
        lines.append(" , ".join(f"{n}_cam{j + 1}_{a}" for n in names for j in range(n_cams) for a in "XY"))
    for f in range(len(out)):
        lines.append(" , ".join("NaN" if math.isnan(x) else repr(float(x)) for x in out[f].ravel()))
    atomic_write(path, "\n".join(lines) + "\n")


@reads("an XMALab 3D point CSV")
def read_points_3d(path: str | os.PathLike) -> tuple[tuple[str, ...], np.ndarray]:
    """Read an XMALab 3D point file: ``(names, (n_frames, n_markers, 3))``, NaN where missing."""
    path = Path(path)
    header, data = _header_and_data(path, _rows(path, "3D point CSV"), 3, "X, Y, Z triples")
    n_markers = data.shape[1] // 3
    if header is not None:
        names = []
        for m in range(n_markers):
            got = [_HEAD3.match(h) for h in header[3 * m : 3 * m + 3]]
            ok = all(got) and [g.group(2) for g in got] == ["X", "Y", "Z"]
            if not ok or len({g.group(1) for g in got}) != 1:
                raise ValueError(
                    f"{path}: header columns {header[3 * m : 3 * m + 3]}; expected <marker>_X, _Y, _Z"
                )
            names.append(got[0].group(1))
    else:
        names = [f"marker{m + 1:03d}" for m in range(n_markers)]
    pts = data.reshape(len(data), n_markers, 3)
    half = np.isnan(pts).any(axis=2) & ~np.isnan(pts).all(axis=2)
    if half.any():
        f, m = np.argwhere(half)[0]
        raise ValueError(f"{path}: frame {f}: marker {names[m]!r} has some NaN coordinates")
    return tuple(names), pts


def write_points_3d(path: str | os.PathLike, names: Sequence[str], points, *, header: bool = True) -> None:
    """Write ``(n_frames, n_markers, 3)`` lab points (mm) as an XMALab 3D file, atomically."""
    P = np.asarray(points, dtype=float)
    if P.ndim != 3 or P.shape[1:] != (len(names), 3):
        raise ValueError(f"points: expected (n_frames, {len(names)}, 3), got {P.shape}")
    lines = [" , ".join(f"{n}_{a}" for n in names for a in "XYZ")] if header else []
    for f in range(len(P)):
        lines.append(" , ".join("NaN" if math.isnan(x) else repr(float(x)) for x in P[f].ravel()))
    atomic_write(path, "\n".join(lines) + "\n")
