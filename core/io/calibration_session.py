"""Read a calibration session: the frames a lab records on a collection day, per camera.

Layout (``session.json`` describes it; :func:`core.synthetic.session.write_calibration_session`
writes one for the demo)::

    SESSION/
      session.json            {"format": "talus-calibration-session", "version": 1,
                               "cameras": ["cam1", "cam2"], "bit_depth": 12, "frame_size": [H, W],
                               "groups": {"dark": "dark", "flat": {"70": "flat_70kV"},
                                          "grid": "grid", "cube": "cube", "spiral": "spiral"},
                               "grid": {"kind": "hole", "pitch_mm": 15.0, ...},
                               "objects": {"cube": "cube15", "spiral": "spiral33"}, "notes": "..."}
      cam1/dark/0000.tif ...  raw counts (``bit_depth`` bits) in single-page uint16 TIFFs,
      cam1/flat_70kV/...      one file per frame, frames in file-name order
      cam1/grid/...
      cam1/cube/0000.tif
      cam1/spiral/...         frame i of every camera is one exposure
      cam2/...

Groups: ``"dark"`` (X-rays off), ``"flat"`` (empty field, one folder per tube voltage, keyed by
kV), ``"grid"`` (distortion grid on the intensifier), ``"lattice"`` (optional bead lattice on
the intensifier, an independent check of the distortion correction), ``"glare"`` (optional:
an opaque lead disc on the intensifier, the veiling-glare measurement), ``"cube"`` and
``"spiral"`` (calibration objects). Optional manifest fields: ``"n_frames"`` (frames per group
folder, checked), ``"kv"`` (voltage of the non-flat frames), ``"lattice"``, ``"detector"``.
Other fields are kept in :attr:`CalibrationSession.manifest`.

:func:`read_session` checks the whole layout before returning (every listed view and group
folder exists with frames, every frame is a 2-D integer image of ``frame_size`` whose type can
hold ``bit_depth`` bits, the simultaneous groups have the same number of frames in every view);
each error is a :class:`~core.errors.FileError` (a :class:`ValueError`) naming the file or
folder and what was expected. Only the
files the manifest lists are opened: anything else in the folder (such as a ``truth/`` folder
of a synthetic session) is never read.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import tifffile

from ..errors import FileError

__all__ = ["GROUPS", "SESSION_FORMAT", "CalibrationSession", "read_session"]

SESSION_FORMAT = "talus-calibration-session"
SUPPORTED_VERSIONS = (1,)
#: Group names a session may list (``"flat"`` maps kV -> folder).
GROUPS = ("dark", "flat", "grid", "lattice", "glare", "cube", "spiral")
#: Groups whose frame i is one exposure in every view.
SIMULTANEOUS = ("cube", "spiral")
_SUFFIXES = (".tif", ".tiff")


def _fail(path, message: str) -> FileError:
    """A :class:`~core.errors.FileError` (a ValueError) whose message starts with ``path``."""
    return FileError(f"{path}: {message}", path=path)


def _kv_key(kv) -> float:
    try:
        value = float(kv)
    except (TypeError, ValueError):
        value = float("nan")
    if not np.isfinite(value) or value <= 0:
        raise ValueError(f"kv: expected a positive tube voltage, got {kv!r}")
    return value


@dataclass(frozen=True, eq=False)
class CalibrationSession:
    """A checked calibration session folder (see the module docs for the layout).

    Attributes
    ----------
    root : Path
        The session folder.
    cameras : tuple of str
        View folder names, in the rig's order.
    bit_depth : int
        Bits of the raw counts (12: 0..4095).
    frame_size : (int, int)
        ``(H, W)`` of every frame.
    manifest : dict
        The content of ``session.json``.
    """

    root: Path
    cameras: tuple[str, ...]
    bit_depth: int
    frame_size: tuple[int, int]
    manifest: dict[str, Any]
    _files: dict = field(default_factory=dict, repr=False)

    @property
    def manifest_path(self) -> Path:
        return self.root / "session.json"

    @property
    def kvs(self) -> tuple[float, ...]:
        """Tube voltages (kV) with empty-field frames, ascending."""
        return tuple(sorted(_kv_key(k) for k in self.manifest["groups"].get("flat", {})))

    @property
    def groups(self) -> tuple[str, ...]:
        """Group keys present: ``"dark"``, ``"flat:<kV>"`` per voltage, ``"grid"``, …"""
        return tuple(self._files[self.cameras[0]])

    @property
    def objects(self) -> dict[str, str]:
        """Object names by group (``{"cube": ..., "spiral": ...}``; may be empty)."""
        return dict(self.manifest.get("objects") or {})

    def _group_key(self, group: str) -> str:
        if not isinstance(group, str):
            raise ValueError(f"group: expected a group name such as 'grid' or 'flat:70', got {group!r}")
        if group == "flat" or group.startswith("flat:"):
            kvs = self.kvs
            if group == "flat":
                if len(kvs) != 1:
                    raise ValueError(f"group: {self.manifest_path} has empty-field frames at "
                                     f"{[f'{k:g}' for k in kvs]} kV; ask for one as 'flat:<kV>'")
                return f"flat:{kvs[0]:g}"
            want = _kv_key(group[5:])
            for k in kvs:
                if abs(k - want) < 1e-9:
                    return f"flat:{k:g}"
            raise ValueError(f"group: {self.manifest_path} has no empty-field frames at {want:g} kV "
                             f"(it has {[f'{k:g}' for k in kvs]} kV)")
        if group not in GROUPS:
            raise ValueError(f"group: expected one of {list(GROUPS)} or 'flat:<kV>', got {group!r}")
        if group not in self.manifest["groups"]:
            raise ValueError(f"group: {self.manifest_path} lists no {group!r} group (it has "
                             f"{sorted(self.manifest['groups'])})")
        return group

    def frames(self, camera: str, group: str) -> list[Path]:
        """The frame files of ``camera`` in ``group`` (``"dark"``, ``"flat:<kV>"``, ``"grid"``,
        ``"lattice"``, ``"cube"``, ``"spiral"``; ``"flat"`` when there is one kV), in order."""
        if camera not in self._files:
            raise ValueError(f"camera: expected one of {list(self.cameras)} "
                             f"({self.manifest_path}), got {camera!r}")
        return list(self._files[camera][self._group_key(group)])

    def has(self, group: str) -> bool:
        """Whether the session holds frames of ``group``."""
        try:
            self._group_key(group)
        except ValueError:
            return False
        return True

    def require(self, *groups: str) -> None:
        """Raise a :class:`ValueError` naming ``session.json`` unless every group is present."""
        missing = [g for g in groups if not self.has(g)]
        if missing:
            raise _fail(self.manifest_path, f"the session lacks {missing} frames (it has "
                             f"{list(self.groups)})")

    def read(self, path) -> np.ndarray:
        """One frame as float32 raw counts ``(H, W)``; checked against the session's size and
        bit depth."""
        p = Path(path)
        try:
            img = tifffile.imread(p)
        except (OSError, ValueError, tifffile.TiffFileError) as exc:
            raise _fail(p, f"cannot read the frame as TIFF ({exc})") from exc
        _check_frame(p, img.shape, img.dtype, self.frame_size, self.bit_depth)
        top = int(img.max()) if img.size else 0
        if top > 2**self.bit_depth - 1:
            raise _fail(p, f"counts up to {top} exceed the {self.bit_depth}-bit range "
                             f"(0..{2**self.bit_depth - 1}) of {self.manifest_path}")
        return img.astype(np.float32)

    def stack(self, camera: str, group: str) -> np.ndarray:
        """Every frame of ``camera`` in ``group`` as ``(n, H, W)`` float32 raw counts."""
        return np.stack([self.read(p) for p in self.frames(camera, group)])


def _check_frame(p: Path, shape, dtype, size: tuple[int, int], bits: int) -> None:
    """A frame file's array shape and type against the manifest's frame size and bit depth."""
    if len(shape) != 2:
        raise _fail(p, f"expected one 2-D grey frame of {size[0]}x{size[1]} (H x W), got an "
                         f"array of shape {tuple(shape)}")
    if tuple(shape) != tuple(size):
        raise _fail(p, f"frame of {shape[0]}x{shape[1]} (H x W); expected {size[0]}x{size[1]} "
                         "as frame_size in session.json says (frames of different sizes): export "
                         "every frame at the detector's full resolution, or remove this one")
    if dtype is None or not np.issubdtype(np.dtype(dtype), np.unsignedinteger):
        raise _fail(p, f"expected raw unsigned integer counts (uint16), got {dtype}")
    if np.iinfo(np.dtype(dtype)).bits < bits:
        raise _fail(p, f"{dtype} holds {np.iinfo(np.dtype(dtype)).bits} bits, fewer than the "
                         f"bit_depth {bits} of session.json (wrong bit depth)")


def _load_manifest(path: Path) -> dict:
    if not path.is_file():
        raise _fail(path, "missing; a calibration session folder holds session.json")
    try:
        m = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise _fail(path, f"not readable JSON ({exc})") from exc
    if not isinstance(m, dict):
        raise _fail(path, "expected a JSON object")
    if m.get("format") != SESSION_FORMAT:
        raise _fail(path, f"format {m.get('format')!r}; expected {SESSION_FORMAT!r}")
    if m.get("version") not in SUPPORTED_VERSIONS:
        raise _fail(path, f"version {m.get('version')!r}; this Talus reads versions "
                         f"{list(SUPPORTED_VERSIONS)}")
    cams = m.get("cameras")
    if (not isinstance(cams, list) or not cams or not all(isinstance(c, str) and c for c in cams)
            or len(set(cams)) != len(cams)):
        raise _fail(path, f"'cameras' must list distinct view folder names, got {cams!r}")
    for c in cams:
        if Path(c).name != c or c in (".", ".."):
            raise _fail(path, f"camera {c!r} is not a plain folder name")
    bits = m.get("bit_depth")
    if isinstance(bits, bool) or not isinstance(bits, int) or not 1 <= bits <= 16:
        raise _fail(path, f"'bit_depth' must be an integer in 1..16 (12 for a 12-bit "
                         f"camera), got {bits!r}")
    size = m.get("frame_size")
    if (not isinstance(size, list) or len(size) != 2
            or not all(isinstance(s, int) and not isinstance(s, bool) and s > 0 for s in size)):
        raise _fail(path, f"'frame_size' must be [H, W] in pixels, got {size!r}")
    groups = m.get("groups")
    if not isinstance(groups, dict) or not groups:
        raise _fail(path, f"'groups' must map group names {list(GROUPS)} to folders")
    for g, d in groups.items():
        if g not in GROUPS:
            raise _fail(path, f"unknown group {g!r} in 'groups'; expected names among "
                             f"{list(GROUPS)}")
        folders = d if g == "flat" else {g: d}
        if g == "flat":
            if not isinstance(d, dict) or not d:
                raise _fail(path, f"groups.flat must map kV to folders, e.g. "
                                 f"{{\"70\": \"flat_70kV\"}}, got {d!r}")
            for kv in d:
                try:
                    _kv_key(kv)
                except ValueError:
                    raise _fail(path, f"groups.flat key {kv!r} is not a tube voltage "
                                     "in kV") from None
        for f in folders.values():
            if not isinstance(f, str) or not f or Path(f).name != f or f in (".", ".."):
                raise _fail(path, f"groups.{g} folder must be a plain folder name, got {f!r}")
    return m


def _group_folders(m: dict) -> dict[str, str]:
    out = {}
    for g, d in m["groups"].items():
        if g == "flat":
            for kv, f in sorted(d.items(), key=lambda kv: _kv_key(kv[0])):
                out[f"flat:{_kv_key(kv):g}"] = f
        else:
            out[g] = d
    return out


def read_session(path) -> CalibrationSession:
    """Open and check a calibration session folder (see the module docs).

    Parameters
    ----------
    path : str or Path
        The session folder (or its ``session.json``).

    Returns
    -------
    CalibrationSession

    Raises
    ------
    ValueError
        Naming the file or folder at fault: no or a malformed ``session.json``, a missing view
        or group folder, a group without frames, a frame that is not a 2-D integer image of
        ``frame_size`` or whose type cannot hold ``bit_depth`` bits, a frame count that differs
        from ``n_frames`` or between the views of a simultaneous group.
    """
    root = Path(path)
    if root.name == "session.json" and root.is_file():
        root = root.parent
    if not root.is_dir():
        raise _fail(root, "not a calibration session folder (expected a folder holding session.json)")
    mpath = root / "session.json"
    m = _load_manifest(mpath)
    size = (int(m["frame_size"][0]), int(m["frame_size"][1]))
    bits = int(m["bit_depth"])
    counts = m.get("n_frames") if isinstance(m.get("n_frames"), dict) else {}
    folders = _group_folders(m)
    files: dict[str, dict[str, tuple[Path, ...]]] = {}
    for cam in m["cameras"]:
        cdir = root / cam
        if not cdir.is_dir():
            raise _fail(cdir, f"missing view folder; {mpath} lists cameras {m['cameras']}: copy the "
                              "view's frames into it (a biplane calibration needs both views) or "
                              "correct the camera list")
        files[cam] = {}
        for key, folder in folders.items():
            gdir = cdir / folder
            if not gdir.is_dir():
                raise _fail(gdir, f"missing {key} group folder of view {cam!r} "
                                 f"(listed in {mpath}): record or copy the view's {key} frames "
                                 f"into it, or remove the group from 'groups' when it is optional "
                                 "(lattice, cube)")
            paths = tuple(sorted((p for p in gdir.iterdir()
                                  if p.suffix.lower() in _SUFFIXES and not p.name.startswith(".")),
                                 key=lambda p: p.name))
            if not paths:
                raise _fail(gdir, f"no frames (.tif) in the {key} group of view {cam!r}: copy the "
                                 "view's frames into it as one TIFF per frame")
            want = counts.get(folder)
            if isinstance(want, int) and len(paths) != want:
                raise _fail(gdir, f"{len(paths)} frames; {mpath} says n_frames {want}: add the "
                                 "missing frames or correct n_frames")
            for p in paths:
                try:
                    with tifffile.TiffFile(p) as tf:
                        page = tf.pages[0]
                        shape, dtype, n_pages = page.shape, page.dtype, len(tf.pages)
                except (OSError, ValueError, IndexError, tifffile.TiffFileError) as exc:
                    raise _fail(p, f"cannot read the frame as TIFF ({exc})") from exc
                if n_pages != 1:
                    raise _fail(p, f"{n_pages} pages; expected one frame per file")
                _check_frame(p, shape, dtype, size, bits)
            files[cam][key] = paths
    for g in SIMULTANEOUS:
        if g in folders:
            n = {cam: len(files[cam][g]) for cam in m["cameras"]}
            if len(set(n.values())) > 1:
                raise _fail(root, f"the {g} group has {n} frames per view; frame i of every "
                                 "view must be one exposure, so the counts must match: remove the "
                                 "frames one view has without the other")
    return CalibrationSession(root=root, cameras=tuple(m["cameras"]), bit_depth=bits,
                              frame_size=size, manifest=m, _files=files)
