r"""MayaCam 1.0 / 2.0 camera files (XMALab, Autoscoper) <-> :class:`~core.geometry.Camera`.

Sources read (public code): Autoscoper ``libautoscoper/src/Camera.cpp`` (``loadMayaCam1``,
``loadMayaCam2``) and ``libautoscoper/src/CoordFrame.cpp`` (``from_xyzypr``), and XMALab
``src/core/Camera.cpp`` (``saveMayaCamVersion2``, ``getMayaCam``, ``getDLT``), the program that
writes these files. Autoscoper's ``Documentation/file-specifications/camera-calibration.md``
disagrees with both programs on two points (see below); the code is what is followed here.

MayaCam 2.0 (text, sections separated by blank lines)::

    image size              width,height           (pixels; the docs say "height,width", but
    <w>,<h>                                        XMALab writes width,height and Autoscoper pairs
                                                   the first value with cx/fx)
    camera matrix           fx,0,cx / 0,fy,cy / 0,0,1   (OpenCV camera matrix, pixels)
    rotation                3 rows of 3            (OpenCV R = Rodrigues(rvec): lab -> camera)
    translation             3 lines of 1           (OpenCV tvec, lab units = mm)
    [undistortion]          optional, 1 line of 8 OpenCV distortion coefficients (MATLAB
                            ``saveMayaCam.m`` helper); Autoscoper ignores it.

XMALab calibrates with OpenCV and writes ``cameramatrix``, ``Rodrigues(rvec)`` and ``tvec`` as
they are, so a 2.0 file *is* an OpenCV pinhole camera ``x ~ K [R | t] X``: R maps lab -> camera,
the camera looks along **+z** (source -> detector), u = column to the right, v = row
**downwards**, and pixel (0, 0) is the **centre** of the top-left pixel. Autoscoper's loader
confirms the pixel-centre origin: it flips rows with ``cy' = (height - 1) - cy`` (not
``height - cy``) and converts to its OpenGL frame ``[x, -y, -z]`` (looking along -z, y up,
rows counted from the bottom). These are exactly Talus's conventions, so
``Camera(K, R, t, width, height)`` is read unchanged; the only sign conversions live in
Autoscoper's internals, not in the file. (Autoscoper's viewport uses ``width/2 - cx`` for the
image centre, i.e. a corner origin horizontally; that sub-pixel inconsistency is Autoscoper's
and is not reproduced.)

MayaCam 1.0 (CSV, exactly 5 lines of 3 numbers; written by XMALab ``getMayaCam``)::

    1: Cx, Cy, Cz           X-ray source (camera centre) in the lab, mm
    2: rx, ry, rz           degrees; Autoscoper builds the camera -> lab rotation
                            A = Rz(rz) Ry(ry) Rx(rx) (from_xyzypr with yaw=rz, pitch=ry, roll=rx;
                            = scipy ``from_euler("xyz", (rx, ry, rz), degrees=True)``)
    3: image plane x, y, z  derived from lines 4-5; ignored by Autoscoper and here
    4: u0, v0, z            principal point, 1-based with v0 counted from the bottom edge,
                            and z = -f (negative focal length in pixels)
    5: scale, width, height scale ignored; width/height 0 mean 1024 (Autoscoper's default);
                            the docs' "height, width" is again contradicted by both programs

The columns of ``A`` are Autoscoper's camera axes in the lab: ``[x, -y, -z]`` of the OpenCV
camera (XMALab writes the angles of ``R^T diag(-1, 1, -1)`` with 180 deg added to the roll,
which is the same frame). Hence, in Talus terms::

    R  = diag(1, -1, -1) @ A.T          t = -R @ C
    fx = fy = -z        cu = u0 - 1     cv = height - v0

Version 1.0 stores one focal length: a camera with ``fx != fy`` is written with their mean only
when ``average_focal=True`` (as XMALab does). Lab units are whatever the calibration used; Talus
reads them as mm (XMALab's cube/wand calibrations are in mm; old Maya-era files in cm must be
scaled by the caller).
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from .._files import fsync_dir, new_file_mode
from .._validate import positive
from ..errors import reads
from .camera import Camera, Rig
from .transforms import _quiet_euler

__all__ = ["read_mayacam", "rig_from_mayacam", "write_mayacam"]

_FLIP_YZ = np.diag([1.0, -1.0, -1.0])  # OpenCV camera axes <-> Autoscoper/OpenGL camera axes
_V2_SECTIONS = {  # name -> (rows, values per row)
    "image size": (1, 2),
    "camera matrix": (3, 3),
    "rotation": (3, 3),
    "translation": (3, 1),
    "undistortion": (1, None),
}
_V2_REQUIRED = ("image size", "camera matrix", "rotation", "translation")


# ---------------------------------------------------------------------------- parsing
def _numbers(path: Path, lineno: int, line: str, count: int | None, what: str) -> list[float]:
    parts = [p.strip() for p in line.split(",")]
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        vals = None
    if vals is None or (count is not None and len(vals) != count) or not all(np.isfinite(v) for v in vals):
        n = "comma-separated numbers" if count is None else f"{count} comma-separated number(s)"
        raise ValueError(f"{path}: line {lineno} ({what}): expected {n}, got {line!r}")
    return vals


def _image_size(path: Path, lineno: int, vals: Sequence[float], what: str) -> tuple[int, int]:
    out = []
    for v in vals:
        if v != int(v) or v < 1:
            raise ValueError(
                f"{path}: line {lineno} ({what}): expected positive integer width,height in "
                f"pixels, got {vals}"
            )
        out.append(int(v))
    return out[0], out[1]


def _lines(path: Path) -> list[tuple[int, str]]:
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: expected a text MayaCam file, got undecodable bytes ({exc})") from None
    return [(i + 1, ln.strip()) for i, ln in enumerate(text.splitlines())]


def _make_camera(path: Path, K, R, t, w, h, pixel_size, name, *, where: dict[str, str]):
    """Build the Camera; a validation error is re-raised naming the file and the section/line."""
    try:
        return Camera(K, R, t, w, h, pixel_size, name)
    except ValueError as exc:
        label = where.get(str(exc).split(":", 1)[0], "camera")
        raise ValueError(f"{path}: {label}: {exc}") from None


def _read_v2(path, lines, pixel_size, name, ignore_distortion) -> Camera:
    found: dict[str, tuple[int, list[list[float]]]] = {}
    i = 0
    while i < len(lines):
        lineno, ln = lines[i]
        if not ln:
            i += 1
            continue
        key = ln.lower()
        if key not in _V2_SECTIONS:
            raise ValueError(
                f"{path}: line {lineno}: expected a section header "
                f"({', '.join(repr(s) for s in _V2_SECTIONS)}), got {ln!r}"
            )
        if key in found:
            raise ValueError(f"{path}: line {lineno}: section {ln!r} appears twice")
        nrows, ncols = _V2_SECTIONS[key]
        rows = []
        for r in range(nrows):
            j = i + 1 + r
            if j >= len(lines) or not lines[j][1]:
                at = f"line {lines[j][0]}" if j < len(lines) else "end of file"
                raise ValueError(
                    f"{path}: section {key!r} (line {lineno}): expected {nrows} row(s) of "
                    f"{ncols or 'comma-separated'} value(s), found only {r} before {at}"
                )
            rows.append(_numbers(path, lines[j][0], lines[j][1], ncols, f"section {key!r}"))
        found[key] = (lineno, rows)
        i += 1 + nrows
    missing = [s for s in _V2_REQUIRED if s not in found]
    if missing:
        raise ValueError(f"{path}: MayaCam 2.0: missing section(s) {missing}")
    size_line, (size,) = found["image size"]
    w, h = _image_size(path, size_line + 1, size, "section 'image size' (width,height)")
    K = np.array(found["camera matrix"][1])
    R = np.array(found["rotation"][1])
    t = np.array(found["translation"][1]).ravel()
    if "undistortion" in found and not ignore_distortion:
        dist = np.array(found["undistortion"][1][0])
        if np.any(dist != 0):
            raise ValueError(
                f"{path}: section 'undistortion' (line {found['undistortion'][0]}): non-zero lens "
                f"distortion coefficients {dist.tolist()} cannot be represented by the pinhole "
                "Camera; undistort the images and pass ignore_distortion=True"
            )
    sections = {
        "K": "section 'camera matrix'",
        "R": "section 'rotation'",
        "t": "section 'translation'",
        "width": "section 'image size'",
        "height": "section 'image size'",
    }
    return _make_camera(path, K, R, t, w, h, pixel_size, name, where=sections)


def _read_v1(path, lines, pixel_size, name) -> Camera:
    content = [(n, ln) for n, ln in lines if ln]
    if len(content) != 5:
        raise ValueError(
            f"{path}: MayaCam 1.0: expected 5 non-empty lines of 3 comma-separated numbers "
            "(source position; rotation angles; image plane; u0,v0,z; scale,width,height), "
            f"got {len(content)} line(s)"
        )
    what = (
        "source position",
        "rotation angles (deg)",
        "image plane position",
        "u0,v0,z",
        "scale,width,height",
    )
    vals = [_numbers(path, n, ln, 3, w) for (n, ln), w in zip(content, what, strict=True)]
    C, angles, _plane, (u0, v0, z), (_scale, w, h) = vals
    ln5 = content[4][0]
    w = 1024.0 if w == 0 else w  # Autoscoper's default for a 0 image size
    h = 1024.0 if h == 0 else h
    w, h = _image_size(path, ln5, (w, h), "scale,width,height")
    if not z < 0:
        raise ValueError(
            f"{path}: line {content[3][0]} (u0,v0,z): expected z = -(focal length in pixels) < 0, got z = {z}"
        )
    f = -z
    K = np.array([[f, 0.0, u0 - 1.0], [0.0, f, h - v0], [0.0, 0.0, 1.0]])
    A = Rotation.from_euler("xyz", angles, degrees=True).as_matrix()  # camera(GL) -> lab
    R = _FLIP_YZ @ A.T
    t = -R @ np.asarray(C)
    sections = {
        "K": f"line {content[3][0]} (u0,v0,z)",
        "R": f"line {content[1][0]} (angles)",
        "t": f"line {content[0][0]} (source)",
        "width": f"line {ln5}",
        "height": f"line {ln5}",
    }
    return _make_camera(path, K, R, t, w, h, pixel_size, name, where=sections)


def read_mayacam(
    path,
    *,
    pixel_size: float | None = None,
    name: str | None = None,
    ignore_distortion: bool = False,
) -> Camera:
    """Read a MayaCam 1.0 or 2.0 camera file (version detected from the content).

    A file whose first line is ``image size`` is 2.0 (Autoscoper's rule), anything else 1.0.
    See the module docstring for the formats and the conversion to Talus conventions.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.txt`` (2.0) or ``.csv`` (1.0) file.
    pixel_size : float, optional
        Detector pixel pitch in mm (not stored in MayaCam files).
    name : str, optional
        Camera label; defaults to the file's stem.
    ignore_distortion : bool
        Accept a 2.0 ``undistortion`` section with non-zero coefficients (they are dropped).

    Returns
    -------
    Camera
        ``x ~ K [R | t] X`` in Talus pixels (``(column, row)``, origin at the centre of the
        top-left pixel), lab in mm.

    Raises
    ------
    FileError
        (a ``ValueError``, :mod:`core.errors`) On a missing, unreadable or malformed file; the
        message names the file, the line/section and what was expected.
    """
    if pixel_size is not None:
        pixel_size = positive(pixel_size, "pixel_size")
    path = Path(path)
    return _read_mayacam(path, pixel_size, path.stem if name is None else name, ignore_distortion)


@reads("a MayaCam 1.0 (.csv) or 2.0 (.txt) camera file")
def _read_mayacam(path: Path, pixel_size, name, ignore_distortion) -> Camera:
    lines = _lines(path)
    first = next((ln for _, ln in lines if ln), None)
    if first is None:
        raise ValueError(f"{path}: empty file, expected a MayaCam 1.0 or 2.0 camera")
    if first.lower() == "image size":
        return _read_v2(path, lines, pixel_size, name, ignore_distortion)
    return _read_v1(path, lines, pixel_size, name)


# ---------------------------------------------------------------------------- writing
def _fmt(x: float) -> str:
    x = float(x)
    if x.is_integer() and abs(x) < 1e15:
        return str(int(x))
    return repr(x)


def _row(values) -> str:
    return ",".join(_fmt(v) for v in values)


def _v2_text(cam: Camera) -> str:
    parts = ["image size", f"{cam.width},{cam.height}", "", "camera matrix"]
    parts += [_row(r) for r in cam.K]
    parts += ["", "rotation"] + [_row(r) for r in cam.R]
    parts += ["", "translation"] + [_fmt(v) for v in cam.t]
    return "\n".join(parts) + "\n"


def _v1_text(cam: Camera, average_focal: bool) -> str:
    if not np.isclose(cam.fx, cam.fy, rtol=1e-12, atol=0) and not average_focal:
        raise ValueError(
            f"camera: MayaCam 1.0 stores a single focal length but fx={cam.fx!r} != fy={cam.fy!r};"
            " use version=2, or average_focal=True to write their mean"
        )
    f = 0.5 * (cam.fx + cam.fy)
    w, h = cam.width, cam.height
    A = cam.R.T @ _FLIP_YZ  # Autoscoper camera -> lab
    angles = np.degrees(_quiet_euler(A, "xyz"))
    u0 = cam.cu + 1.0
    v0 = h - cam.cv
    scale = 0.1  # XMALab's "_near"; ignored on reading by Autoscoper and Talus
    plane = ((0.5 * w - u0) * scale, (0.5 * h - v0) * scale, -f * scale)
    rows = [cam.source, angles, plane, (u0, v0, -f), (scale, w, h)]
    return "\n".join(_row(r) for r in rows) + "\n"


def _atomic_write(path: Path, text: str) -> None:
    """Temporary file + fsync + rename + folder fsync, with the mode a plain ``open()`` gives
    (like :func:`core.io.atomic.atomic_write`, which this layer below ``core.io`` cannot import)."""
    folder = path.parent if str(path.parent) else Path(".")
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=f".{path.name}.", suffix=".tmp")
    try:
        if hasattr(os, "fchmod"):
            os.fchmod(fd, new_file_mode(path))
        with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    fsync_dir(folder)  # the rename itself survives a power cut


def write_mayacam(camera: Camera, path, *, version: int = 2, average_focal: bool = False) -> None:
    """Write a camera as a MayaCam file, atomically (temporary file + rename).

    Numbers are written with full precision (``repr``), so reading the file back reproduces the
    camera to machine precision (2.0 exactly; 1.0 up to the angle conversion, ~1e-12).

    Parameters
    ----------
    camera : Camera
    path : str or os.PathLike
        Destination; an existing file is replaced only once the new one is complete.
    version : {2, 1}
        MayaCam version. 1.0 keeps a single focal length (see ``average_focal``).
    average_focal : bool
        For version 1: write ``(fx + fy) / 2`` when ``fx != fy`` instead of raising.

    Raises
    ------
    ValueError
        If ``camera`` is not a Camera, ``version`` is not 1 or 2, or version 1 cannot represent
        the camera (``fx != fy`` without ``average_focal``).
    """
    if not isinstance(camera, Camera):
        raise ValueError(f"camera: expected a Camera, got {type(camera).__name__}")
    if version == 2:
        text = _v2_text(camera)
    elif version == 1:
        text = _v1_text(camera, average_focal)
    else:
        raise ValueError(f"version: expected 1 or 2, got {version!r}")
    _atomic_write(Path(path), text)


def rig_from_mayacam(
    paths,
    *,
    pixel_size: float | Sequence[float | None] | None = None,
    ignore_distortion: bool = False,
) -> Rig:
    """A :class:`Rig` from one MayaCam file per camera (see :func:`read_mayacam`).

    Parameters
    ----------
    paths : sequence of str or os.PathLike
        One file per camera, in camera order; each camera is named after its file's stem.
    pixel_size : float or sequence of float, optional
        Detector pixel pitch in mm, one for all cameras or one per camera.
    ignore_distortion : bool
        Passed to :func:`read_mayacam`.
    """
    if isinstance(paths, str | os.PathLike) or not isinstance(paths, Sequence) or not paths:
        raise ValueError(f"paths: expected a non-empty sequence of MayaCam file paths, got {paths!r}")
    if pixel_size is None or np.ndim(pixel_size) == 0:
        sizes = [pixel_size] * len(paths)
    else:
        sizes = list(pixel_size)
        if len(sizes) != len(paths):
            raise ValueError(
                f"pixel_size: expected one value or {len(paths)} (one per path), got {len(sizes)}"
            )
    return Rig(
        tuple(
            read_mayacam(p, pixel_size=s, ignore_distortion=ignore_distortion)
            for p, s in zip(paths, sizes, strict=True)
        )
    )
