r"""Autoscoper interop: trial ``.cfg`` (read/write), ``.tra`` pose files (read/write), ``.vie`` (read).

Sources: Autoscoper ``libautoscoper/src/Trial.cpp`` (``parse``, ``save``), ``CoordFrame.cpp``
(``from_xyzypr``, ``to_xyzypr``, ``to_matrix``), ``AutoscoperMainWindow.cpp``
(``save_tracking_results``, ``load_tracking_results``) and the documentation's file specifications
(config, filter file). MayaCam camera files are read by :mod:`core.geometry.mayacam`.

Trial configuration (``.cfg``)
    ``key value`` lines; blank lines and lines starting with ``#`` are skipped; Windows line
    endings are read like Unix ones (Autoscoper reads lines with ``SystemTools::GetLineFromStream``,
    ``Trial.cpp`` line 215, which drops the ``\r``). Keys:
    ``Version`` (``1.2``, ``1.1``; missing means 1.0), ``mayaCam_csv`` and ``CameraRootDir`` (one
    each per camera, in camera order), per volume ``VolumeFile``, ``VolumeFlip x y z`` (0/1) and
    ``VoxelSize sx sy sz`` (mm), and from version 1.2 ``MeshFile`` (the volume's surface model:
    none at all or one per volume, in volume order — ``Trial.cpp`` lines 147-149 and 302-309;
    read only from 1.2 on, as Autoscoper does), ``RenderResolution w h``, ``OptimizationOffsets``
    (6 numbers), ``TrackingFolder``, ``FilterFolder``. Version 1.1+ paths may be relative to the
    ``.cfg``'s folder; version 1.0 files normally hold absolute paths (a relative one is also
    resolved against the ``.cfg``'s folder here). Backslashes are read as ``/``.

Tracking results (``.tra``)
    See :mod:`core.io.autoscoper_tra` (re-exported here).

View settings (``.vie``)
    ``RadFilters_begin`` ... ``RadFilters_end``, ``DrrRenderer_begin`` ... (``SampleDistance``,
    ``RayIntensity``, ``Cutoff``), ``DrrFilters_begin`` ... where each filter block is one of
    ``SobelFilter`` (``Scale``, ``Blend``), ``ContrastFilter`` (``Alpha``, ``Beta``),
    ``GaussianFilter`` (``Radius``), ``SharpenFilter`` (``Radius``, ``Contrast``).
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType

from .atomic import atomic_write
from .autoscoper_tra import _text_lines, matrix_to_xyzypr, read_tra, write_tra, xyzypr_to_matrix
from .errors import reads

__all__ = [
    "AutoscoperFilter",
    "AutoscoperTrial",
    "AutoscoperViewSettings",
    "AutoscoperVolume",
    "matrix_to_xyzypr",
    "read_autoscoper_cfg",
    "read_tra",
    "read_vie",
    "write_autoscoper_cfg",
    "write_tra",
    "xyzypr_to_matrix",
]


def _numbers(path: Path, lineno: int, text: str, n: int, what: str, kind=float) -> list:
    parts = text.replace(",", " ").split()
    try:
        vals = [kind(p) for p in parts]
    except ValueError:
        vals = []
    if len(vals) != n or not all(math.isfinite(v) for v in vals):
        raise ValueError(f"{path}: line {lineno} ({what}): expected {n} number(s), got {text!r}")
    return vals


# ---------------------------------------------------------------------------- .cfg
@dataclass(frozen=True)
class AutoscoperVolume:
    """One ``VolumeFile`` of a trial: TIFF stack, voxel size (mm, x y z), flips and (1.2) mesh."""

    path: Path
    voxel_size: tuple[float, float, float]
    flip: tuple[bool, bool, bool] = (False, False, False)
    mesh: Path | None = None


@dataclass(frozen=True)
class AutoscoperTrial:
    """An Autoscoper trial configuration (paths absolute after reading)."""

    cameras: tuple[Path, ...]
    camera_root_dirs: tuple[Path, ...]
    volumes: tuple[AutoscoperVolume, ...]
    render_resolution: tuple[int, int] = (512, 512)
    optimization_offsets: tuple[float, ...] = (0.1, 0.1, 0.1, 0.1, 0.1, 0.1)
    version: tuple[int, int] = (1, 1)
    tracking_folder: str = "Tracking"
    filter_folder: str = "xParameters"


def _cfg_path(value: str, base: Path) -> Path:
    value = re.sub(r"/+", "/", value.replace("\\", "/"))
    if len(value) > 1 and value.endswith("/") and not re.fullmatch(r"[A-Za-z]:/", value):
        value = value[:-1]
    p = Path(value)
    return p if p.is_absolute() or re.match(r"^[A-Za-z]:/", value) else base / p


@reads("an Autoscoper trial .cfg")
def read_autoscoper_cfg(path: str | os.PathLike) -> AutoscoperTrial:
    """Read an Autoscoper trial ``.cfg`` (versions 1.0 to 1.2; see the module docstring).

    Raises
    ------
    ValueError
        Unknown key, malformed value, or inconsistent counts (cameras vs camera folders, volume
        files vs voxel sizes); the message names the file and line.
    """
    path = Path(path)
    base = path.parent.absolute()
    keys = ("mayaCam_csv", "CameraRootDir", "VolumeFile", "VolumeFlip", "VoxelSize", "MeshFile")
    lists: dict[str, list] = {k: [] for k in keys}
    version, resolution, offsets = None, (512, 512), (0.1,) * 6
    folders = {"TrackingFolder": "Tracking", "FilterFolder": "xParameters"}
    for lineno, raw in enumerate(_text_lines(path, "Autoscoper .cfg"), start=1):
        line = raw.rstrip("\r\n")
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        key, _, value = line.strip().partition(" ")
        value = value.strip()
        if key in ("mayaCam_csv", "CameraRootDir", "VolumeFile", "MeshFile"):
            if not value:
                raise ValueError(f"{path}: line {lineno} ({key}): expected a path, got nothing")
            lists[key].append(_cfg_path(value, base))
        elif key == "VolumeFlip":
            flips = _numbers(path, lineno, value, 3, key, int)
            if any(f not in (0, 1) for f in flips):
                raise ValueError(f"{path}: line {lineno} ({key}): expected three 0/1 flags, got {value!r}")
            lists[key].append(tuple(bool(f) for f in flips))
        elif key == "VoxelSize":
            vs = _numbers(path, lineno, value, 3, key)
            if min(vs) <= 0:
                raise ValueError(
                    f"{path}: line {lineno} ({key}): expected three positive sizes (mm), got {value!r}"
                )
            lists[key].append(tuple(vs))
        elif key == "RenderResolution":
            resolution = tuple(_numbers(path, lineno, value, 2, key, int))
            if min(resolution) < 1:
                raise ValueError(
                    f"{path}: line {lineno} ({key}): expected two positive integers, got {value!r}"
                )
        elif key == "OptimizationOffsets":
            offsets = tuple(_numbers(path, lineno, value, 6, key))
        elif key == "Version":
            m = re.fullmatch(r"(\d+)\.(\d+)", value)
            if not m:
                raise ValueError(
                    f"{path}: line {lineno} (Version): expected MAJOR.MINOR such as 1.1, got {value!r}"
                )
            version = (int(m.group(1)), int(m.group(2)))
            if version[0] != 1:
                raise ValueError(f"{path}: line {lineno}: Version {value} is not supported (expected 1.x)")
        elif key in folders:
            folders[key] = value
        else:
            raise ValueError(
                f"{path}: line {lineno}: unknown key {key!r}; expected one of Version, mayaCam_csv, "
                "CameraRootDir, VolumeFile, VolumeFlip, VoxelSize, MeshFile, RenderResolution, "
                "OptimizationOffsets, TrackingFolder, FilterFolder"
            )
    cams, dirs = lists["mayaCam_csv"], lists["CameraRootDir"]
    if not cams or len(cams) != len(dirs):
        raise ValueError(
            f"{path}: expected one CameraRootDir per mayaCam_csv (at least one camera), got {len(cams)} "
            f"camera(s) and {len(dirs)} folder(s)"
        )
    files, sizes, flips = lists["VolumeFile"], lists["VoxelSize"], lists["VolumeFlip"]
    if not files or len(files) != len(sizes) or len(flips) > len(files):
        raise ValueError(
            f"{path}: expected one VoxelSize (and at most one VolumeFlip) per VolumeFile (at least one "
            f"volume), got {len(files)} file(s), {len(sizes)} voxel size(s), {len(flips)} flip(s)"
        )
    flips = flips + [(False, False, False)] * (len(files) - len(flips))
    meshes = lists["MeshFile"] if (version or (1, 0)) >= (1, 2) else []
    if meshes and len(meshes) != len(files):
        raise ValueError(
            f"{path}: expected a MeshFile for each VolumeFile or none at all, got {len(files)} volume(s) "
            f"and {len(meshes)} mesh file(s)"
        )
    meshes = meshes or [None] * len(files)
    vols = tuple(AutoscoperVolume(*v) for v in zip(files, sizes, flips, meshes, strict=True))
    return AutoscoperTrial(
        cameras=tuple(cams), camera_root_dirs=tuple(dirs), volumes=vols, render_resolution=resolution,
        optimization_offsets=offsets, version=version or (1, 0),
        tracking_folder=folders["TrackingFolder"], filter_folder=folders["FilterFolder"],
    )


def _rel(p: Path, base: Path) -> str:
    try:
        return Path(os.path.relpath(Path(p).absolute(), base)).as_posix()
    except ValueError:  # another drive on Windows
        return Path(p).absolute().as_posix()


def _g(x: float) -> str:
    return f"{float(x):.12g}"


def write_autoscoper_cfg(trial: AutoscoperTrial, path: str | os.PathLike, *, newline: str = "\n") -> None:
    """Write a ``.cfg`` (paths relative to its folder), atomically: version 1.2 with a ``MeshFile``
    per volume when the volumes have meshes, else 1.1. ``newline="\r\n"`` writes Windows line
    endings (as Autoscoper does on Windows)."""
    if not isinstance(trial, AutoscoperTrial):
        raise ValueError(f"trial: expected an AutoscoperTrial, got {type(trial).__name__}")
    if newline not in ("\n", "\r\n"):
        raise ValueError(f"newline: expected '\\n' or '\\r\\n', got {newline!r}")
    has_mesh = [v.mesh is not None for v in trial.volumes]
    if any(has_mesh) and not all(has_mesh):
        raise ValueError("trial: expected a mesh for every volume or for none (as Autoscoper 1.2 reads them)")
    path = Path(path)
    base = path.parent.absolute()
    version = "1.2" if all(has_mesh) else "1.1"
    lines = [f"Version {version}", f"FilterFolder {trial.filter_folder}",
             f"TrackingFolder {trial.tracking_folder}"]
    lines += [f"mayaCam_csv {_rel(p, base)}" for p in trial.cameras]
    lines += [f"CameraRootDir {_rel(p, base)}" for p in trial.camera_root_dirs]
    for v in trial.volumes:
        lines.append(f"VolumeFile {_rel(v.path, base)}")
        lines.append("VolumeFlip " + " ".join(str(int(f)) for f in v.flip))
        lines.append("VoxelSize " + " ".join(_g(s) for s in v.voxel_size))
        if v.mesh is not None:
            lines.append(f"MeshFile {_rel(v.mesh, base)}")
    lines.append("RenderResolution {} {}".format(*trial.render_resolution))
    lines.append("OptimizationOffsets " + " ".join(_g(o) for o in trial.optimization_offsets))
    atomic_write(path, newline.join(lines) + newline)
    read_autoscoper_cfg(path)  # what was written must read back


# ---------------------------------------------------------------------------- .vie
_FILTERS = {
    "SobelFilter": ("Scale", "Blend"),
    "ContrastFilter": ("Alpha", "Beta"),
    "GaussianFilter": ("Radius",),
    "SharpenFilter": ("Radius", "Contrast"),
}
_RENDERER = ("SampleDistance", "RayIntensity", "Cutoff")


@dataclass(frozen=True)
class AutoscoperFilter:
    """One image filter: ``name`` (e.g. ``"SobelFilter"``) and its parameters."""

    name: str
    params: MappingProxyType = field(default_factory=lambda: MappingProxyType({}))


@dataclass(frozen=True)
class AutoscoperViewSettings:
    """The content of a ``.vie`` file: radiograph filters, DRR ray-caster settings, DRR filters."""

    rad_filters: tuple[AutoscoperFilter, ...]
    drr_renderer: MappingProxyType
    drr_filters: tuple[AutoscoperFilter, ...]


@reads("an Autoscoper .vie filter settings file")
def read_vie(path: str | os.PathLike) -> AutoscoperViewSettings:
    """Read an Autoscoper ``.vie`` filter/renderer settings file.

    Raises
    ------
    ValueError
        Unknown tag or parameter, unbalanced ``_begin``/``_end``, or a non-numeric value; the
        message names the file and line.
    """
    path = Path(path)
    blocks: dict[str, list] = {"RadFilters": [], "DrrFilters": []}
    renderer: dict[str, float] = {}
    stack: list[str] = []
    params: dict[str, float] = {}
    for lineno, raw in enumerate(_text_lines(path, "Autoscoper .vie"), start=1):
        line = raw.strip()
        if not line:
            continue
        where = f"{path}: line {lineno}"
        tok = line.split()
        if len(tok) == 1 and tok[0].endswith("_begin"):
            tag = tok[0][: -len("_begin")]
            if not stack and tag in ("RadFilters", "DrrRenderer", "DrrFilters"):
                pass
            elif stack and stack[-1] in blocks and len(stack) == 1 and tag in _FILTERS:
                params = {}
            else:
                inside = stack[-1] if stack else "the top level"
                raise ValueError(f"{where}: unexpected {tok[0]!r} inside {inside}")
            stack.append(tag)
        elif len(tok) == 1 and tok[0].endswith("_end"):
            tag = tok[0][: -len("_end")]
            if not stack or stack[-1] != tag:
                want = f"{stack[-1]}_end" if stack else "a *_begin line"
                raise ValueError(f"{where}: {tok[0]!r} does not close the open block; expected {want}")
            stack.pop()
            if tag in _FILTERS:
                blocks[stack[-1]].append(AutoscoperFilter(tag, MappingProxyType(dict(params))))
        elif len(tok) == 2 and stack:
            key = tok[0]
            try:
                value = float(tok[1])
            except ValueError:
                value = math.nan
            if not math.isfinite(value):
                raise ValueError(f"{where}: {key}: expected a number, got {tok[1]!r}")
            block = stack[-1]
            allowed = _FILTERS.get(block) or (_RENDERER if block == "DrrRenderer" else ())
            if key not in allowed:
                raise ValueError(
                    f"{where}: unknown parameter {key!r} in {block} (expected {', '.join(allowed)})"
                )
            (renderer if block == "DrrRenderer" else params)[key] = value
        else:
            raise ValueError(f"{where}: expected 'Tag_begin', 'Tag_end' or 'Parameter value', got {line!r}")
    if stack:
        raise ValueError(f"{path}: end of file inside {stack[-1]} (missing {stack[-1]}_end)")
    return AutoscoperViewSettings(
        tuple(blocks["RadFilters"]), MappingProxyType(renderer), tuple(blocks["DrrFilters"])
    )
