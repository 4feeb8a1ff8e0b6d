"""A study from what a lab has after a collection: one folder, read as far as the files allow.

:func:`scan_folder` looks through a folder (and its sub-folders, three levels deep) for

* **two views**: folders of TIFF frames, or ``.cine`` files (one per camera);
* **cameras**: MayaCam files (``.txt``, 1.0 or 2.0) or one DLT CSV (XMALab/DLTdv, 11 coefficients
  per camera); the views and cameras pair up by name (a view whose path names a camera's file
  stem), else in sorted order;
* **the CT**: one CT (NIfTI, NRRD, MetaImage or a DICOM folder), optionally with a label map
  (a volume whose name contains ``label``, ``seg`` or ``mask``: one bone per label), or one CT
  per bone (the bone is named after the file).

and detects the frames' bit depth (:func:`core.io.bitdepth.detect_bit_depth`). What cannot be
read from the files — the bit depth when it was guessed from the values, the names of the label
map's bones — is listed in :attr:`FolderScan.questions` with a default answer. Problems (no two
views, frames of different sizes, cameras that do not match the frames' size, a CT without bone)
are collected, each naming the file; :func:`make_study_from_folder` refuses a scan that has any
and writes nothing then. The study is built in a temporary folder beside ``out`` and renamed into
place when complete.

CT orientation: Talus works in LPS (DICOM's patient axes, as ITK/SimpleITK read every format);
NIfTI headers store RAS, which the reader converts — a volume's direction matrix says where its
axes point, so no flip is asked.
"""

from __future__ import annotations

import os
import re
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["FolderScan", "ImportFolderError", "make_study_from_folder", "scan_folder"]

_VOLUME_SUFFIXES = (".nii", ".nii.gz", ".nrrd", ".nhdr", ".mha", ".mhd")
_LABEL_WORDS = re.compile(r"label|seg|mask", re.IGNORECASE)
_SKIP_DIRS = {"results", "calibrations", "__pycache__"}
BONE_HU = 200.0  # a CT whose largest value stays under this holds no bone
MIN_USABLE = 0.5  # a view with fewer usable pixels than this is reported before tracking


class ImportFolderError(ValueError):
    """The folder cannot become a study; ``problems`` lists every reason, each naming the file."""

    def __init__(self, folder, problems):
        self.problems = list(problems)
        super().__init__(f"{folder}: cannot make a study:\n" + "\n".join(f"  - {p}" for p in self.problems))


@dataclass
class ViewSource:
    path: Path
    n_frames: int
    shape: tuple[int, int]  # (rows, columns)
    bit_depth: object  # core.io.bitdepth.BitDepth
    usable: float  # fraction of the first frame's pixels in the usable range at bit_depth.bits
    first_frame: np.ndarray | None = None


@dataclass
class FolderScan:
    """What :func:`scan_folder` found (module docs)."""

    folder: Path
    views: list = field(default_factory=list)
    cameras: list = field(default_factory=list)  # camera files (MayaCam) or [DLT csv]
    camera_format: str = ""
    rig: object = None
    ct: Path | None = None
    labels: Path | None = None
    label_values: list = field(default_factory=list)
    bone_volumes: dict = field(default_factory=dict)  # bone name -> CT path
    problems: list = field(default_factory=list)
    warnings: list = field(default_factory=list)
    questions: dict = field(default_factory=dict)  # what the files do not say -> default answer

    @property
    def bit_depth(self) -> int | None:
        return None if not self.views else int(max(v.bit_depth.bits for v in self.views))

    def bones(self) -> dict:
        """Default bone names: per-bone volumes by file name, label-map bones ``bone<label>``."""
        if self.bone_volumes:
            return {n: None for n in self.bone_volumes}
        if self.labels is not None:
            return {f"bone{v}": int(v) for v in self.label_values}
        if self.ct is not None:
            return {_stem(self.ct): None}
        return {}

    def summary(self) -> dict:
        return {"folder": str(self.folder),
                "views": [{"path": str(v.path), "frames": v.n_frames, "size": [v.shape[1], v.shape[0]],
                           "bit_depth": v.bit_depth.bits, "bit_depth_source": v.bit_depth.source,
                           "bit_depth_text": v.bit_depth.text, "usable_fraction": round(v.usable, 4)}
                          for v in self.views],
                "cameras": [str(c) for c in self.cameras], "camera_format": self.camera_format,
                "ct": None if self.ct is None else str(self.ct),
                "labels": None if self.labels is None else str(self.labels),
                "bone_volumes": {k: str(v) for k, v in self.bone_volumes.items()},
                "bones": self.bones(), "questions": self.questions, "warnings": self.warnings,
                "problems": self.problems,
                "ct_orientation": "LPS inside Talus; NIfTI headers (RAS) are converted on reading"}


def _stem(p: Path) -> str:
    name = p.name
    for s in _VOLUME_SUFFIXES:
        if name.lower().endswith(s):
            name = name[: -len(s)]
            break
    name = re.sub(r"[^A-Za-z0-9_\-]", "_", name).strip("_") or "bone"
    return name if name[0].isalnum() else f"b{name}"


def _walk(folder: Path, depth: int = 3):
    for d, dirs, files in os.walk(folder):
        rel = Path(d).relative_to(folder)
        dirs[:] = sorted(x for x in dirs if not x.startswith(".") and x not in _SKIP_DIRS
                         and not (Path(d) / x / "study.json").exists()
                         and not (Path(d) / x / "session.json").exists())
        if len(rel.parts) >= depth:
            dirs[:] = []
        yield Path(d), sorted(f for f in files if not f.startswith("."))


def _is_dicom_dir(d: Path, files) -> bool:
    return any(f.lower().endswith(".dcm") for f in files)


def _tiff_shapes(d: Path, files) -> dict:
    import tifffile

    shapes: dict = {}
    for f in files:
        try:
            with tifffile.TiffFile(d / f) as tf:
                shapes.setdefault(tuple(int(s) for s in tf.pages[0].shape[:2]), []).append(f)
        except Exception as exc:  # any unreadable file is named
            shapes.setdefault(("unreadable", str(exc)), []).append(f)
    return shapes


def _rel(folder: Path, p: Path) -> str:
    try:
        return p.relative_to(folder).as_posix() or "."
    except ValueError:
        return str(p)


def scan_folder(folder, *, bit_depth: int | None = None) -> FolderScan:
    """Read what ``folder`` holds (module docs). Never raises for the folder's content: problems
    are listed in the result (:func:`make_study_from_folder` refuses them); ``ValueError`` only
    when ``folder`` is not a folder."""
    from ..io.bitdepth import detect_bit_depth, usable_fraction
    from ..io.sequences import open_sequence

    root = Path(folder).expanduser()
    if not root.is_dir():
        raise ValueError(f"folder: {root} is not a folder")
    scan = FolderScan(root)
    frame_srcs, txt, csv, volumes = [], [], [], []
    for d, files in _walk(root):
        tifs = [f for f in files if f.lower().endswith((".tif", ".tiff"))]
        if _is_dicom_dir(d, files):
            volumes.append(d)
            continue
        if len(tifs) >= 2:
            shapes = _tiff_shapes(d, tifs)
            if len(shapes) > 1:
                parts = "; ".join(f"{len(v)} of {s[1]}x{s[0]} pixels (e.g. {v[0]})"
                                  if s[0] != "unreadable" else f"{len(v)} unreadable (e.g. {v[0]}: {s[1]})"
                                  for s, v in shapes.items())
                scan.problems.append(f"{_rel(root, d)}/: frames of different sizes: {parts}; every frame of "
                                     "a view must have one size")
                continue
            frame_srcs.append(d)
        for f in files:
            low = f.lower()
            if low.endswith(".cine"):
                frame_srcs.append(d / f)
            elif low.endswith(".txt"):
                txt.append(d / f)
            elif low.endswith(".csv"):
                csv.append(d / f)
            elif low.endswith(_VOLUME_SUFFIXES) and not low.endswith(".raw"):
                volumes.append(d / f)
    # views
    if len(frame_srcs) != 2:
        found = ", ".join(_rel(root, p) for p in frame_srcs) or "none"
        scan.problems.append(f"expected two views (two folders of TIFF frames or two .cine files), found "
                             f"{len(frame_srcs)}: {found}")
    else:
        for p in frame_srcs:
            try:
                bd = detect_bit_depth(p)
                with open_sequence(p, bit_depth=bit_depth or bd.bits) as seq:
                    first = np.asarray(seq.frame(0))
                    scan.views.append(ViewSource(p, len(seq), tuple(seq.frame_shape), bd,
                                                 usable_fraction(first, bit_depth or bd.bits), first))
            except (ValueError, OSError) as exc:
                scan.problems.append(f"{_rel(root, p)}: cannot read the frames ({exc})")
        if len(scan.views) == 2:
            a, b = scan.views
            if a.shape != b.shape:
                scan.problems.append(f"the views have frames of different sizes: {_rel(root, a.path)} "
                                     f"{a.shape[1]}x{a.shape[0]}, {_rel(root, b.path)} "
                                     f"{b.shape[1]}x{b.shape[0]}")
            for v in scan.views:
                if not v.bit_depth.certain:
                    scan.questions[f"bit depth of {_rel(root, v.path)}"] = v.bit_depth.bits
            bits = bit_depth or scan.bit_depth
            for v in scan.views:
                if v.usable < MIN_USABLE:
                    scan.warnings.append(_unusable(root, v, bits))
    _cameras(scan, txt, csv)
    _volumes(scan, volumes)
    return scan


def _unusable(root, v: ViewSource, bits: int) -> str:
    x = np.asarray(v.first_frame, float) / (2**bits - 1)
    dark, bright = float(np.mean(x <= 0.02)), float(np.mean(x >= 0.999))
    why = []
    if dark > 0.25:
        top = int(np.max(v.first_frame))
        hint = ("" if top > 2 ** (bits - 2)
                else f" (the largest value, {top}, suggests fewer bits than {bits})")
        why.append(f"{100 * dark:.0f} % of pixels are black at {bits} bits{hint}")
    if bright > 0.25:
        why.append(f"{100 * bright:.0f} % are saturated")
    return (f"{_rel(root, v.path)}: only {100 * v.usable:.0f} % of the first frame's pixels are usable for "
            f"tracking: " + ("; ".join(why) or "outside the usable fluence range") + ". Check the bit depth")


def _cameras(scan: FolderScan, txt, csv) -> None:
    from ..geometry.camera import Rig
    from ..geometry.mayacam import read_mayacam

    root = scan.folder
    maya = []
    for p in txt:
        try:
            maya.append((p, read_mayacam(p)))
        except (ValueError, OSError):
            continue
    if len(maya) >= 2:
        if len(maya) != 2:
            scan.problems.append(f"expected two MayaCam camera files, found {len(maya)}: "
                                 + ", ".join(_rel(root, p) for p, _ in maya))
            return
        maya = _pair(scan, maya)
        scan.cameras, scan.camera_format = [p for p, _ in maya], "mayacam"
        scan.rig = Rig(tuple(c for _, c in maya))
    elif csv and len(scan.views) == 2:
        from ..io.xmalab import rig_from_dlt_csv

        sizes = [(v.shape[1], v.shape[0]) for v in scan.views]
        for p in csv:
            try:
                scan.rig = rig_from_dlt_csv(p, sizes, max_skew_px=1e9)
            except (ValueError, OSError):
                continue
            scan.cameras, scan.camera_format = [p], "dlt"
            return
    if scan.rig is None:
        scan.problems.append("no cameras: expected two MayaCam files (.txt) or a DLT CSV with two cameras")
        return
    for v, (cam, src) in enumerate(zip(scan.rig, scan.views, strict=False)):
        if (cam.height, cam.width) != src.shape:
            cf = scan.cameras[v] if scan.camera_format == "mayacam" else scan.cameras[0]
            scan.problems.append(f"{_rel(root, cf)}: camera {v + 1} expects {cam.width}x{cam.height}-pixel "
                                 f"frames but {_rel(root, src.path)} has {src.shape[1]}x{src.shape[0]}")


def _pair(scan: FolderScan, maya):
    """Order the camera files as the views: a view whose path names a camera's file stem."""
    if len(scan.views) != 2:
        return maya
    stems = [p.stem.lower() for p, _ in maya]
    order = []
    for v in scan.views:
        hit = [k for k, s in enumerate(stems) if s in str(v.path).lower()]
        order.append(hit[0] if len(hit) == 1 else None)
    if sorted(o for o in order if o is not None) == [0, 1] and None not in order:
        return [maya[k] for k in order]
    return maya


def _volumes(scan: FolderScan, volumes) -> None:
    from ..io.ct import read_ct

    root = scan.folder
    labels = [p for p in volumes if _LABEL_WORDS.search(p.name)]
    cts = [p for p in volumes if p not in labels]
    if not cts:
        scan.problems.append("no CT: expected a CT (NIfTI, NRRD, MetaImage or a DICOM folder), a CT and a "
                             "label map, or one CT per bone")
        return
    if len(labels) > 1:
        scan.problems.append("more than one label map: " + ", ".join(_rel(root, p) for p in labels))
        return
    for p in cts:
        try:
            vol = read_ct(p)
        except (ValueError, OSError) as exc:
            scan.problems.append(f"{_rel(root, p)}: cannot read the CT ({exc})")
            continue
        top = float(np.max(vol.data))
        if top < BONE_HU:
            scan.problems.append(f"{_rel(root, p)}: no bone in the CT (largest value {top:.0f} HU, under "
                                 f"{BONE_HU:.0f} HU)")
    if labels:
        if len(cts) != 1:
            scan.problems.append(f"a label map ({_rel(root, labels[0])}) needs exactly one CT, "
                                 f"found {len(cts)}")
            return
        scan.ct, scan.labels = cts[0], labels[0]
        try:
            lab = read_ct(labels[0], units="label")
            scan.label_values = [int(v) for v in np.unique(lab.data) if v > 0]
        except (ValueError, OSError) as exc:
            scan.problems.append(f"{_rel(root, labels[0])}: cannot read the label map ({exc})")
            return
        if not scan.label_values:
            scan.problems.append(f"{_rel(root, labels[0])}: the label map labels no voxel")
        scan.questions["bone names"] = scan.bones()
    elif len(cts) == 1:
        scan.ct = cts[0]
        scan.questions["bone name"] = _stem(cts[0])
    else:
        scan.bone_volumes = {_stem(p): p for p in cts}


def make_study_from_folder(scan: FolderScan, out, *, bit_depth: int | None = None, bones: dict | None = None,
                           trial: str = "trial1", name: str | None = None) -> Path:
    """Write the study of ``scan`` at ``out`` (a new folder).

    ``bit_depth`` (default: the detected one), ``bones`` (name -> label, or name -> None for a
    whole volume; default :meth:`FolderScan.bones`, renaming keeps the order). Raises
    :class:`ImportFolderError` for a scan with problems or an ``out`` that exists and is not an
    empty folder; nothing is written then, nor when anything fails on the way.
    """
    from . import Study

    out = Path(out).expanduser().absolute()
    if scan.problems:
        raise ImportFolderError(scan.folder, scan.problems)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ImportFolderError(scan.folder, [f"--out: {out} exists and is not an empty folder"])
    bits = int(bit_depth or scan.bit_depth)
    default = scan.bones()
    if bones is None:
        bones = default
    bones = dict(bones)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".partial", dir=out.parent))
    try:
        with Study.create(tmp, name=name or scan.folder.name) as st:
            cams = scan.cameras
            if scan.camera_format == "dlt":
                from ..geometry.mayacam import write_mayacam

                (tmp / "cameras").mkdir()
                cams = []
                for k, cam in enumerate(scan.rig):
                    p = tmp / "cameras" / f"cam{k + 1}.txt"
                    write_mayacam(cam, p, version=2)
                    cams.append(p)
            st.add_calibration("cameras", cams)
            if scan.bone_volumes:
                vols = list(scan.bone_volumes.values())
                for bone, path in zip(bones, vols, strict=True):
                    st.add_volume(bone, path)
                    st.add_bone(bone, volume=bone)
            else:
                st.add_volume("ct", scan.ct, labels=scan.labels)
                for bone, label in bones.items():
                    st.add_bone(bone, volume="ct", label=label)
            st.add_trial(trial, [v.path for v in scan.views], calibration="cameras", bones=list(bones),
                         bit_depth=bits)
        if out.exists():
            out.rmdir()  # an empty folder given as --out
        os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out
