"""CT volumes from DICOM series, NIfTI, NRRD, MHA/MHD and TIFF stacks; label maps to bone sub-volumes.

Reading uses SimpleITK (ITK/GDCM), which applies DICOM rescale slope/intercept and returns the
image geometry in ITK's physical frame: **LPS** millimetres for DICOM, and NIfTI/NRRD/MHA
converted to the same frame. That physical frame is what a Talus pose ``T_lab_from_bone`` maps
into the lab. Volumes are returned as :class:`core.render.CTVolume` (``data[k, j, i]``, origin
= centre of voxel (0, 0, 0), direction columns = i, j, k axes) in Hounsfield units.

A DICOM folder is checked before reading (:func:`inspect_dicom_folder`): several series in one
folder, slices of different size or orientation in one series, duplicate or missing slices
(gaps in the slice positions), slices not stacked along their normal (gantry tilt) and files that
look like slices but cannot be read (a truncated first or last slice would otherwise shift the
volume silently) raise :class:`~core.io.errors.FileError` naming the files. Slices are ordered by
their position along the slice normal, whatever the file names or instance numbers say (an
unsorted folder is reported in the series info, not misread).
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._validate import as_float_array
from ..render.volume import CTVolume
from .errors import FileError, reading
from .tiff_volume import read_tiff_volume

__all__ = ["DicomSeriesInfo", "inspect_dicom_folder", "read_ct", "split_labels"]

_ITK_SUFFIXES = (".nii", ".nii.gz", ".nrrd", ".nhdr", ".mha", ".mhd")
_DICOM_SUFFIXES = (".dcm", ".dicom", ".ima")
_TAGS = {
    "uid": "0020|000e",
    "position": "0020|0032",
    "orientation": "0020|0037",
    "rows": "0028|0010",
    "cols": "0028|0011",
    "spacing": "0028|0030",
    "instance": "0020|0013",
    "description": "0008|103e",
    "modality": "0008|0060",
}


@dataclass(frozen=True, eq=False)
class DicomSeriesInfo:
    """One DICOM series found in a folder, slices ordered along their normal.

    Attributes
    ----------
    uid : str
        SeriesInstanceUID.
    files : tuple of Path
        Slice files ordered by position along the slice normal.
    positions : (n, 3) array
        ImagePositionPatient of each slice (LPS mm), same order.
    normal : (3,) array
        Unit slice normal (row direction x column direction).
    slice_spacing_mm : float
        Median distance between consecutive slices (NaN for a single slice).
    rows, cols : int
        Slice size.
    pixel_spacing_mm : (2,) tuple
        DICOM PixelSpacing (row spacing, column spacing).
    unsorted : bool
        True when the files' name order differs from the position order.
    description, modality : str
    """

    uid: str
    files: tuple[Path, ...]
    positions: np.ndarray
    normal: np.ndarray
    slice_spacing_mm: float
    rows: int
    cols: int
    pixel_spacing_mm: tuple[float, float]
    unsorted: bool
    description: str
    modality: str


def _sitk():
    import SimpleITK as sitk

    return sitk


def _floats(text: str, n: int, what: str, path: Path) -> np.ndarray:
    try:
        vals = np.array([float(x) for x in text.strip().split("\\")])
    except ValueError:
        vals = np.array([])
    if vals.shape != (n,) or not np.all(np.isfinite(vals)):
        raise ValueError(f"{path}: DICOM {what}: expected {n} numbers, got {text!r}")
    return vals


def _header(path: Path) -> dict | None:
    sitk = _sitk()
    r = sitk.ImageFileReader()
    r.SetFileName(str(path))
    r.SetImageIO("GDCMImageIO")
    try:
        r.ReadImageInformation()
    except RuntimeError:
        return None  # not a DICOM image (DICOMDIR, notes, ...)
    keys = set(r.GetMetaDataKeys())
    h = {k: (r.GetMetaData(t).strip() if t in keys else "") for k, t in _TAGS.items()}
    if not h["uid"] or not h["position"] or not h["orientation"]:
        raise ValueError(
            f"{path}: DICOM image without SeriesInstanceUID/ImagePositionPatient/ImageOrientationPatient; "
            "expected a CT slice"
        )
    h["path"] = path
    return h


def inspect_dicom_folder(folder, *, tolerance: float = 0.05) -> tuple[DicomSeriesInfo, ...]:
    """List and check the DICOM series in ``folder`` (headers only).

    Parameters
    ----------
    folder : str or os.PathLike
    tolerance : float
        Relative tolerance on the slice spacing (a step differing from the median by more than
        this fraction is a gap or an irregular series) and absolute tolerance (mm) on positions
        off the stacking line.

    Raises
    ------
    FileError
        (a ``ValueError``) No DICOM images, a file that looks like a slice (``.dcm`` suffix,
        ``DICM`` preamble, or named like the other slices) but cannot be read, a series with
        slices of different size/orientation, duplicate slice positions, missing slices (gaps)
        or slices not stacked along the normal.
    """
    folder = Path(folder)
    with reading(folder, "a folder of DICOM CT slices"):
        if not folder.is_dir():
            raise FileError(f"folder: {folder} is not a folder of DICOM files", path=folder)
        files = sorted(p for p in folder.iterdir() if p.is_file() and not p.name.startswith("."))
        headers, unreadable = [], []
        for p in files:
            h = _header(p)
            (unreadable if h is None else headers).append(h or p)
        damaged = [p for p in unreadable if _looks_like_dicom(p, headers)]
        if damaged:
            more = f" (and {len(damaged) - 1} more: {', '.join(p.name for p in damaged[1:4])})" if len(
                damaged) > 1 else ""
            raise FileError(
                f"{damaged[0]}: cannot be read as a DICOM slice (truncated or damaged){more}; expected every "
                f"DICOM file in {folder} to be readable: restore it from the scanner's copy or move it out "
                "(a series missing its first or last slice would be read with a shifted origin)",
                path=damaged[0], expected="a readable DICOM slice",
            )
        if not headers:
            raise FileError(f"folder: {folder} holds no DICOM images", path=folder)
        by_uid: dict[str, list[dict]] = {}
        for h in headers:
            by_uid.setdefault(h["uid"], []).append(h)
        return tuple(_check_series(uid, hs, tolerance) for uid, hs in by_uid.items())


def _stem_pattern(name: str) -> str:
    return "".join("#" if c.isdigit() else c for c in name)


def _looks_like_dicom(path: Path, headers: list[dict]) -> bool:
    """Whether a file GDCM cannot read is meant as a slice: a DICOM suffix, the ``DICM``
    preamble, or a name without a suffix patterned like the readable slices' (``IM0001``)."""
    if path.name.upper() == "DICOMDIR":
        return False
    if path.suffix.lower() in _DICOM_SUFFIXES:
        return True
    with open(path, "rb") as fh:
        head = fh.read(132)
    if head[128:132] == b"DICM":
        return True
    if path.suffix:
        return False
    pattern = _stem_pattern(path.name)
    return any(not h["path"].suffix and _stem_pattern(h["path"].name) == pattern for h in headers)


def _check_series(uid: str, hs: list[dict], tol: float) -> DicomSeriesInfo:
    from collections import Counter

    sizes = Counter((h["rows"], h["cols"]) for h in hs)
    iops = [_floats(h["orientation"], 6, "ImageOrientationPatient", h["path"]) for h in hs]
    common = Counter(tuple(np.round(v, 4)) for v in iops).most_common(1)[0][0]
    majority = (
        h for h, v in zip(hs, iops, strict=True)
        if (h["rows"], h["cols"]) == sizes.most_common(1)[0][0] and tuple(np.round(v, 4)) == common
    )
    ref = next(majority, hs[0])  # compare with a slice of the majority size and orientation
    iop0 = _floats(ref["orientation"], 6, "ImageOrientationPatient", ref["path"])
    for h in hs:
        if (h["rows"], h["cols"]) != (ref["rows"], ref["cols"]):
            raise ValueError(
                f"{h['path']}: mixed series {uid}: slice of {h['cols']}x{h['rows']} pixels, expected "
                f"{ref['cols']}x{ref['rows']} like {ref['path'].name}"
            )
        iop = _floats(h["orientation"], 6, "ImageOrientationPatient", h["path"])
        if np.abs(iop - iop0).max() > 1e-4:
            raise ValueError(
                f"{h['path']}: mixed series {uid}: orientation {iop.round(5).tolist()} differs from "
                f"{iop0.round(5).tolist()} of {ref['path'].name}"
            )
    normal = np.cross(iop0[:3], iop0[3:])
    normal /= np.linalg.norm(normal)
    pos = np.array([_floats(h["position"], 3, "ImagePositionPatient", h["path"]) for h in hs])
    d = pos @ normal
    order = np.argsort(d, kind="stable")
    hs = [hs[i] for i in order]
    pos, d = pos[order], d[order]
    files = tuple(h["path"] for h in hs)
    spacing = math.nan
    if len(hs) > 1:
        step = np.diff(d)
        k = int(np.argmin(step))
        if step[k] < 1e-3:
            raise ValueError(
                f"{files[k + 1]}: duplicate slice position {d[k]:.3f} mm (same as {files[k].name})"
            )
        spacing = float(np.median(step))
        bad = np.flatnonzero(np.abs(step - spacing) > tol * spacing)
        if bad.size:
            k = int(bad[0])
            missing = round(step[k] / spacing) - 1
            what = f"{missing} missing slice(s)" if missing >= 1 else "irregular slice spacing"
            raise ValueError(
                f"{files[k].parent}: series {uid}: {what} between {files[k].name} ({d[k]:.3f} mm) and "
                f"{files[k + 1].name} ({d[k + 1]:.3f} mm): step {step[k]:.3f} mm, expected {spacing:.3f} mm"
            )
        off_line = pos - pos[0] - np.outer(d - d[0], normal)
        if np.abs(off_line).max() > max(tol, 1e-3):
            k = int(np.argmax(np.abs(off_line).max(axis=1)))
            off = np.abs(off_line[k]).max()
            raise ValueError(
                f"{files[k]}: series {uid}: slice position is {off:.3f} mm off the line "
                "along the slice normal (gantry tilt?); expected slices stacked along their normal"
            )
    ps = _floats(ref["spacing"], 2, "PixelSpacing", ref["path"]) if ref["spacing"] else np.ones(2)
    return DicomSeriesInfo(
        uid=uid, files=files, positions=pos, normal=normal, slice_spacing_mm=spacing,
        rows=int(ref["rows"] or 0), cols=int(ref["cols"] or 0), pixel_spacing_mm=(float(ps[0]), float(ps[1])),
        unsorted=[p.name for p in files] != sorted(p.name for p in files),
        description=ref["description"], modality=ref["modality"],
    )


def _compact(data: np.ndarray, units: str, path) -> np.ndarray:
    """int16 when the values are integers that fit, else float32; labels stay integer."""
    if units == "label":
        if np.issubdtype(data.dtype, np.floating):
            if not np.all(np.isfinite(data)) or np.any(data != np.round(data)):
                raise ValueError(f"{path}: label map with non-integer values; expected integer labels")
        return data.astype(np.int32)
    if np.issubdtype(data.dtype, np.integer):
        lo, hi = int(data.min()), int(data.max())
        return data.astype(np.int16) if -32768 <= lo and hi <= 32767 else data.astype(np.float32)
    return data.astype(np.float32)


def _from_sitk(img, path, units: str, name: str, hu_offset: float) -> CTVolume:
    sitk = _sitk()
    if img.GetDimension() != 3 or img.GetNumberOfComponentsPerPixel() != 1:
        raise ValueError(
            f"{path}: expected a 3-D single-channel volume, got {img.GetDimension()}-D with "
            f"{img.GetNumberOfComponentsPerPixel()} component(s) per voxel"
        )
    data = _compact(sitk.GetArrayFromImage(img), units, path)
    if hu_offset:
        data = data.astype(np.float32) + np.float32(hu_offset)
    D = np.array(img.GetDirection(), dtype=float).reshape(3, 3)
    return CTVolume(
        data, spacing=img.GetSpacing(), origin=img.GetOrigin(), direction=D, units=units, name=name
    )


def read_ct(
    path,
    *,
    voxel_size: Sequence[float] | None = None,
    hu_offset: float = 0.0,
    series_uid: str | None = None,
    units: str = "HU",
    name: str | None = None,
    tolerance: float = 0.05,
) -> CTVolume:
    """Read a CT volume (or a label map with ``units="label"``).

    Parameters
    ----------
    path : str or os.PathLike
        A DICOM folder (or one of its files: that file's series is read), ``.nii``/``.nii.gz``,
        ``.nrrd``/``.nhdr``, ``.mha``/``.mhd``, or a multipage ``.tif``/``.tiff`` (slices
        first) with ``voxel_size``.
    voxel_size : (3,) sequence, optional
        Voxel size (x = column, y = row, z = slice) in mm; required for TIFF, ignored otherwise.
    hu_offset : float
        Added to the values read (e.g. -1024 for CT numbers stored as HU + 1024 in a TIFF; DICOM
        rescale slope/intercept are applied automatically).
    series_uid : str, optional
        The series to read from a DICOM folder holding several.
    units : {"HU", "1/mm", "label"}
        Units recorded on the volume; ``"label"`` keeps integer labels (int32).
    name : str, optional
        Defaults to the file or folder name.
    tolerance : float
        DICOM slice-spacing tolerance (see :func:`inspect_dicom_folder`).

    Raises
    ------
    FileError
        (a ``ValueError``) Unknown format, unreadable file (a damaged slice of a DICOM series
        included), several DICOM series without ``series_uid``, gaps or mixed slices, a non-3-D
        or multi-channel image; the message names the file.
    """
    sitk = _sitk()
    if units not in ("HU", "1/mm", "label"):
        raise ValueError(f'units: expected "HU", "1/mm" or "label", got {units!r}')
    p = Path(path)
    lower = p.name.lower()
    if p.is_file() and lower.endswith((".tif", ".tiff")) and voxel_size is None:
        raise ValueError(f"voxel_size: required for the TIFF volume {p} (TIFF stores no voxel size)")
    expected = "a CT volume: a DICOM folder, .nii(.gz), .nrrd, .nhdr, .mha, .mhd or .tif/.tiff"
    with reading(p, expected):
        if p.is_file() and lower.endswith((".tif", ".tiff")):
            vol = read_tiff_volume(p, voxel_size, hu_offset=hu_offset,
                                   units="HU" if units == "label" else units, name=name or p.stem)
            return vol if units != "label" else CTVolume(_compact(vol.data, units, p), spacing=vol.spacing,
                                                         origin=vol.origin, units=units, name=vol.name)
        if p.is_file() and lower.endswith(_ITK_SUFFIXES):
            if lower.endswith((".mha", ".mhd")):
                _check_metaimage(p)
            try:
                _check_announced_size(p)
                img = sitk.ReadImage(str(p))
            except RuntimeError as exc:
                why = str(exc).strip().splitlines()[-1]
                raise FileError(f"path: cannot read {p} as a volume ({why})", path=p) from exc
            stem = p.name[: -len(".nii.gz")] if lower.endswith(".nii.gz") else p.stem
            return _from_sitk(img, p, units, name or stem, hu_offset)
        if p.is_dir() or (p.is_file() and (lower.endswith(_DICOM_SUFFIXES) or "." not in p.name)):
            return _read_dicom(p, series_uid, units, name, hu_offset, tolerance)
        if not p.exists():
            raise FileError(f"path: {p} does not exist; expected {expected}", path=p)
        raise FileError(f"path: cannot tell the format of {p}; expected {expected}", path=p)


def _physical_memory() -> int:
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, OSError, ValueError):  # pragma: no cover - not POSIX
        return 1 << 40


def _check_metaimage(p: Path) -> None:
    """MetaIO (ITK 2.x) corrupts its heap and aborts the process on some damaged ``ElementDataFile``
    values: accept only ``LOCAL`` in ``.mha`` and an existing, printable file name in ``.mhd``."""
    with open(p, "rb") as fh:
        head = fh.read(1 << 16)
    for raw in head.split(b"\n"):
        key, _, value = raw.partition(b"=")
        if key.strip() != b"ElementDataFile":
            continue
        value = value.strip()
        if p.name.lower().endswith(".mha") and value == b"LOCAL":
            return
        try:
            name = value.decode("ascii")
        except UnicodeDecodeError:
            name = ""
        if name and name.isprintable() and name != "LOCAL" and (p.parent / name).is_file():
            return
        raise ValueError(
            f"{p}: ElementDataFile {value[:40]!r}; expected LOCAL (.mha) or the name of the raw data "
            "file next to a .mhd header"
        )
    raise ValueError(f"{p}: no ElementDataFile line in the first 64 kB; expected a MetaImage header")


def _check_announced_size(p: Path) -> None:
    """Refuse a header that announces more voxels than this machine's memory could hold (a
    damaged header would otherwise make ITK try to allocate terabytes, or swap for minutes)."""
    sitk = _sitk()
    r = sitk.ImageFileReader()
    r.SetFileName(str(p))
    r.ReadImageInformation()
    size = r.GetSize()
    bits = re.search(r"(\d+)-bit", sitk.GetPixelIDValueAsString(r.GetPixelID()))
    per = int(bits.group(1)) // 8 if bits else 8
    nbytes = math.prod(int(s) for s in size) * r.GetNumberOfComponents() * per
    if nbytes > _physical_memory() // 2:
        raise FileError(
            f"{p}: the header announces a {'x'.join(str(int(s)) for s in size)}-voxel image "
            f"({nbytes / 1e9:.3g} GB), more than half this machine's memory; a damaged header? "
            "expected a CT volume that fits in memory", path=p, expected="a CT volume that fits in memory",
        )


def _read_dicom(p: Path, series_uid, units, name, hu_offset, tolerance) -> CTVolume:
    sitk = _sitk()
    folder = p if p.is_dir() else p.parent
    if p.is_file():
        h = _header(p)
        if h is None:
            raise ValueError(f"path: {p} is not a DICOM image")
        series_uid = series_uid or h["uid"]
    series = inspect_dicom_folder(folder, tolerance=tolerance)
    if series_uid is None and len(series) > 1:
        listing = "; ".join(f"{s.uid} ({len(s.files)} files, {s.description!r})" for s in series)
        raise ValueError(
            f"{folder}: holds {len(series)} DICOM series ({listing}); pass series_uid= to choose one"
        )
    chosen = [s for s in series if series_uid is None or s.uid == series_uid]
    if not chosen:
        raise ValueError(f"series_uid: {series_uid!r} not found in {folder} (have {[s.uid for s in series]})")
    info = chosen[0]
    reader = sitk.ImageSeriesReader()
    reader.SetFileNames([str(f) for f in info.files])
    try:
        img = reader.Execute()
    except RuntimeError as exc:
        why = str(exc).strip().splitlines()[-1]
        for f in info.files:  # name the slice at fault
            try:
                sitk.ReadImage(str(f))
            except RuntimeError as one:
                why = str(one).strip().splitlines()[-1]
                raise FileError(
                    f"{f}: cannot read the pixels of this slice of DICOM series {info.uid} ({why}); "
                    "expected a complete DICOM slice", path=f, expected="a complete DICOM slice",
                ) from exc
        raise FileError(f"{folder}: cannot read DICOM series {info.uid} ({why})", path=folder) from exc
    dz = info.slice_spacing_mm
    if len(info.files) > 1 and abs(img.GetSpacing()[2] - dz) > 1e-3 * dz:
        raise ValueError(
            f"{folder}: slice spacing {img.GetSpacing()[2]} from ITK differs from the positions' "
            f"{info.slice_spacing_mm} mm"
        )
    return _from_sitk(img, folder, units, name or folder.name, hu_offset)


def _same_grid(a: CTVolume, b: CTVolume) -> bool:
    return (
        a.data.shape == b.data.shape
        and np.allclose(a.spacing, b.spacing, rtol=1e-6)
        and np.allclose(a.origin, b.origin, atol=1e-4)
        and np.allclose(a.direction, b.direction, atol=1e-6)
    )


def split_labels(
    ct: CTVolume,
    labels,
    bones: Mapping[str, int] | None = None,
    *,
    margin_mm: float = 5.0,
    other_labels_hu: float | None = None,
) -> dict[str, CTVolume]:
    """One sub-volume per labelled bone: the label's bounding box grown by ``margin_mm``.

    Parameters
    ----------
    ct : CTVolume
        The CT (HU).
    labels : CTVolume or array
        Integer label map on the same voxel grid (same shape, spacing, origin, direction).
    bones : mapping name -> label value, optional
        Default: every non-zero label, named ``"label_<value>"``.
    margin_mm : float
        Added on every side (rounded up to whole voxels per axis), clipped to the volume.
    other_labels_hu : float, optional
        If given, voxels of the sub-volume that belong to *other* labels are set to this value
        (e.g. 0 HU, soft tissue) so that neighbouring bones do not appear in the bone's DRR.

    Returns
    -------
    dict of name -> CTVolume
        Crops of ``ct`` keeping physical positions (``origin`` moved to the crop's first voxel).

    Raises
    ------
    ValueError
        A label map on another grid, non-integer labels, or a label with no voxel.
    """
    if not isinstance(ct, CTVolume):
        raise ValueError(f"ct: expected a CTVolume, got {type(ct).__name__}")
    if isinstance(labels, CTVolume):
        if not _same_grid(ct, labels):
            raise ValueError(
                f"labels: label map {labels.name!r} is on another voxel grid than {ct.name!r} (shape "
                f"{labels.data.shape} vs {ct.data.shape}, or spacing/origin/direction); resample it first"
            )
        lab = labels.data
    else:
        lab = np.asarray(labels)
        if lab.shape != ct.data.shape:
            raise ValueError(f"labels: expected shape {ct.data.shape} like the CT, got {lab.shape}")
    if not np.issubdtype(lab.dtype, np.integer):
        raise ValueError(f"labels: expected integer labels, got {lab.dtype}")
    margin = float(as_float_array(margin_mm, "margin_mm", shape=()))
    if margin < 0:
        raise ValueError(f"margin_mm: expected >= 0, got {margin}")
    if bones is None:
        bones = {f"label_{int(v)}": int(v) for v in np.unique(lab) if v != 0}
    pad = np.ceil(margin / ct.spacing - 1e-9).astype(int)  # voxels per axis (i, j, k)
    out: dict[str, CTVolume] = {}
    for bone, value in bones.items():
        mask = lab == value
        if not mask.any():
            raise ValueError(f"bones: label {value} ({bone!r}) has no voxel in the label map")
        lo, hi = [], []
        for axis in (2, 1, 0):  # i, j, k -> array axes 2, 1, 0
            idx = np.flatnonzero(mask.any(axis=tuple(a for a in range(3) if a != axis)))
            lo.append(idx[0])
            hi.append(idx[-1] + 1)
        n = ct.shape_ijk
        sl = [slice(max(0, lo[a] - pad[a]), min(n[a], hi[a] + pad[a])) for a in range(3)]
        sub = ct.crop(i=sl[0], j=sl[1], k=sl[2])
        if other_labels_hu is not None:
            sub_lab = lab[sl[2], sl[1], sl[0]]
            others = (sub_lab != 0) & (sub_lab != value)
            data = sub.data.astype(np.float32) if not float(other_labels_hu).is_integer() else sub.data.copy()
            data[others] = other_labels_hu
            sub = CTVolume(data, spacing=sub.spacing, origin=sub.origin, direction=sub.direction,
                           units=sub.units, name=bone)
        else:
            sub = CTVolume(sub.data, spacing=sub.spacing, origin=sub.origin, direction=sub.direction,
                           units=sub.units, name=bone)
        out[bone] = sub
    return out
