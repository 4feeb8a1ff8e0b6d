"""XMALab projects (``.xma``): cameras, undistortion files, trials and markers, read from the zip.

Layout, from XMALab's ``ProjectFileIO::writeProjectFile`` (XROMMPackages/xmalab
``src/ui/ProjectFileIO.cpp`` lines 1459-1715) and the savers it calls: a zip holding

* ``project.xml``: ``<Project Version=… CalibrationType=…>`` with per camera
  ``<Camera Name isCalibrated isFlipped CameraMatrix=<cam>/data/<cam>_CameraMatrix.csv
  [UndistortionParameter=…]>``, an optional ``<UndistortionGrid Filename isComputed>`` (with
  ``<PointsDetected>``, ``<GridPointsDistorted>``, ``<GridPointsReferences>``,
  ``<GridPointsInlier>`` file children), and ``<CalibrationSequence Filename Frames Width
  Height>`` or per calibration frame ``<CalibrationImage Filename|Frame isCalibrated>`` with
  ``<RotationMatrix Filename>`` and ``<TranslationVector Filename>``; a ``<CalibrationObject>``;
  then per trial ``<Trial Name startFrame endFrame referenceCalibration recordingSpeed
  cutOffFrequency nbImages>`` with ``<Marker Description ID FilenamePoints2D …>`` and
  ``<RigidBody Description ID …>`` children;
* the camera matrix (``Camera::saveCameraMatrix``, ``src/core/Camera.cpp`` 417-427) and
  rotation matrix (``CalibrationImage::saveRotationMatrix``, ``src/core/CalibrationImage.cpp``
  606-621): three lines of ``a, b, c``; the translation vector (623-632): three lines of one
  number. They are OpenCV's pinhole model of the calibration frame: ``x ~ K [R | t] X``, ``X``
  in the calibration object's frame, which is the lab of a trial whose ``referenceCalibration``
  is that frame;
* a marker's 2-D points (``Marker::save``, ``src/core/Marker.cpp`` 634-650): one line per frame,
  ``x,y`` per camera, comma-separated.

:func:`read_xma_project` returns the project; :meth:`XMAProject.rig` gives Talus cameras for a
trial, :meth:`XMAProject.marker_points` a marker's 2-D track.
"""

from __future__ import annotations

import math
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from xml.etree import ElementTree

import numpy as np

from .errors import reads

__all__ = ["XMACamera", "XMAMarker", "XMAProject", "XMATrial", "read_xma_project"]


@dataclass(frozen=True)
class XMACamera:
    name: str
    K: np.ndarray  # (3, 3) pixels
    width: int | None
    height: int | None
    flipped: bool
    calibrated: bool
    poses: dict  # calibration frame index -> (R (3, 3), t (3,)): lab (calibration object) -> camera
    undistortion: dict = field(default_factory=dict)  # name -> member path in the zip


@dataclass(frozen=True)
class XMAMarker:
    id: int
    description: str
    points2d: str | None  # member path


@dataclass(frozen=True)
class XMATrial:
    name: str
    start_frame: int
    end_frame: int
    reference_calibration: int
    recording_speed: float
    cutoff_frequency: float
    n_images: int
    markers: tuple[XMAMarker, ...]
    rigid_bodies: tuple[str, ...]


@dataclass(frozen=True)
class XMAProject:
    path: Path
    version: str
    cameras: tuple[XMACamera, ...]
    trials: tuple[XMATrial, ...]

    def rig(self, trial: str | None = None):
        """Talus :class:`~core.geometry.camera.Rig` of the cameras at ``trial``'s reference
        calibration frame (default: the first trial's, else frame 0)."""
        from ..geometry.camera import Camera, Rig

        ref = 0
        if trial is not None or self.trials:
            t = self.trial(trial) if trial is not None else self.trials[0]
            ref = t.reference_calibration
        cams = []
        for c in self.cameras:
            if ref not in c.poses:
                raise ValueError(f"{self.path}: camera {c.name!r} has no calibration at frame {ref}")
            if c.width is None or c.height is None:
                raise ValueError(f"{self.path}: camera {c.name!r}: image size unknown")
            R, t = c.poses[ref]
            cams.append(Camera(K=c.K, R=R, t=t, width=c.width, height=c.height, name=c.name))
        return Rig(cams)

    def trial(self, name: str) -> XMATrial:
        for t in self.trials:
            if t.name == name:
                return t
        have = [t.name for t in self.trials]
        raise ValueError(f"trial: no trial named {name!r} in {self.path} (have {have})")

    def marker_points(self, trial: str, marker: int) -> np.ndarray:
        """``(n_frames, n_cameras, 2)`` pixel positions of a marker (NaN where untracked)."""
        return _marker_points(self.path, self, trial, marker)


def _numbers(path, member: str, text: str, shape) -> np.ndarray:
    rows = [r for r in text.replace("\r", "").split("\n") if r.strip()]
    try:
        vals = [float(v) for r in rows for v in r.split(",")]
    except ValueError:
        raise ValueError(f"{path}: {member}: expected comma-separated numbers") from None
    if len(vals) != int(np.prod(shape)) or not all(math.isfinite(v) for v in vals):
        raise ValueError(f"{path}: {member}: expected {int(np.prod(shape))} finite numbers, got {len(vals)}")
    return np.array(vals).reshape(shape)


def _member(zf: zipfile.ZipFile, names: set[str], rel: str, path) -> str:
    m = str(PurePosixPath(rel.replace("\\", "/")))
    if m not in names:
        raise ValueError(f"{path}: project.xml names {rel!r}, which is not in the archive")
    return m


def _int(path, el, attr: str, default=None) -> int:
    v = el.get(attr)
    if v is None:
        if default is None:
            raise ValueError(f"{path}: <{el.tag}> has no {attr} attribute")
        return default
    try:
        return int(v)
    except ValueError:
        raise ValueError(f"{path}: <{el.tag} {attr}={v!r}>: expected an integer") from None


def _float(path, el, attr: str, default: float = 0.0) -> float:
    v = el.get(attr)
    try:
        return default if v is None else float(v)
    except ValueError:
        raise ValueError(f"{path}: <{el.tag} {attr}={v!r}>: expected a number") from None


def read_xma_project(path: str | os.PathLike) -> XMAProject:
    """Read an XMALab ``.xma`` project (see the module docs)."""
    return _read(Path(path))


@reads("an XMALab project (.xma: a zip with project.xml)")
def _read(path: Path) -> XMAProject:
    with zipfile.ZipFile(path) as zf:
        names = set(zf.namelist())
        root_xml = next((n for n in ("project.xml",) if n in names), None)
        if root_xml is None:
            raise ValueError(f"{path}: no project.xml in the archive")
        info = zf.getinfo(root_xml)
        if info.file_size > 64 << 20:
            raise ValueError(f"{path}: project.xml of {info.file_size} bytes (expected a small XML file)")
        root = ElementTree.fromstring(zf.read(root_xml))
        if root.tag != "Project":
            raise ValueError(f"{path}: project.xml: root element <{root.tag}>, expected <Project>")

        def text(member: str) -> str:
            if zf.getinfo(member).file_size > 256 << 20:
                raise ValueError(f"{path}: {member} is too large")
            return zf.read(member).decode("utf-8-sig")

        cameras = []
        for c in root.findall("Camera"):
            name = c.get("Name")
            if not name:
                raise ValueError(f"{path}: <Camera> without a Name")
            K = np.full((3, 3), np.nan)
            if c.get("CameraMatrix"):
                m = _member(zf, names, c.get("CameraMatrix"), path)
                K = _numbers(path, m, text(m), (3, 3))
            und = {}
            grid = c.find("UndistortionGrid")
            if grid is not None:
                if grid.get("Filename"):
                    und["image"] = str(PurePosixPath(grid.get("Filename").replace("\\", "/")))
                for child in grid:
                    if child.get("Filename"):
                        und[child.tag] = _member(zf, names, child.get("Filename"), path)
            poses, width, height = {}, None, None
            seq = c.find("CalibrationSequence")
            if seq is not None:
                width, height = _int(path, seq, "Width", 0) or None, _int(path, seq, "Height", 0) or None
            for k, img in enumerate(c.findall(".//CalibrationImage")):
                frame = _int(path, img, "Frame", k)
                if img.get("Width"):
                    width, height = _int(path, img, "Width"), _int(path, img, "Height")
                rm, tv = img.find("RotationMatrix"), img.find("TranslationVector")
                if rm is None or tv is None or not rm.get("Filename") or not tv.get("Filename"):
                    continue
                mr = _member(zf, names, rm.get("Filename"), path)
                mt = _member(zf, names, tv.get("Filename"), path)
                R = _numbers(path, mr, text(mr), (3, 3))
                if np.abs(R @ R.T - np.eye(3)).max() > 1e-4 or np.linalg.det(R) < 0:
                    raise ValueError(f"{path}: {mr}: not a rotation matrix")
                poses[frame] = (R, _numbers(path, mt, text(mt), (3,)))
            cameras.append(XMACamera(name, K, width, height, c.get("isFlipped", "0") == "1",
                                     c.get("isCalibrated", "0") == "1", poses, und))
        trials = []
        for t in root.findall("Trial"):
            markers = []
            for m in t.findall("Marker"):
                p2 = m.get("FilenamePoints2D")
                markers.append(XMAMarker(_int(path, m, "ID"), m.get("Description", ""),
                                         None if not p2 else str(PurePosixPath(p2.replace("\\", "/")))))
            trials.append(XMATrial(
                t.get("Name") or f"trial{len(trials) + 1}", _int(path, t, "startFrame", 1),
                _int(path, t, "endFrame", 1), _int(path, t, "referenceCalibration", 0),
                _float(path, t, "recordingSpeed"), _float(path, t, "cutOffFrequency"),
                _int(path, t, "nbImages", 0), tuple(markers),
                tuple(r.get("Description", "") for r in t.findall("RigidBody"))))
        if not cameras:
            raise ValueError(f"{path}: project.xml has no <Camera>")
    return XMAProject(path, root.get("Version", ""), tuple(cameras), tuple(trials))


@reads("an XMALab project marker file (one line per frame, x,y per camera)")
def _marker_points(path: Path, project: XMAProject, trial: str, marker: int) -> np.ndarray:
    t = project.trial(trial)
    m = next((m for m in t.markers if m.id == marker), None)
    if m is None or m.points2d is None:
        raise ValueError(f"{path}: trial {trial!r} has no 2-D points of marker {marker}")
    with zipfile.ZipFile(path) as zf:
        if m.points2d not in zf.namelist():
            raise ValueError(f"{path}: {m.points2d} is not in the archive")
        rows = [r for r in zf.read(m.points2d).decode("utf-8-sig").replace("\r", "").split("\n") if r.strip()]
    nc = len(project.cameras)
    out = np.full((len(rows), nc, 2), np.nan)
    for i, r in enumerate(rows):
        parts = r.split(",")
        if len(parts) != 2 * nc:
            raise ValueError(f"{path}: {m.points2d}: line {i + 1}: {len(parts)} values, expected {2 * nc}")
        try:
            out[i] = np.array([float(p) for p in parts]).reshape(nc, 2)
        except ValueError:
            raise ValueError(f"{path}: {m.points2d}: line {i + 1}: expected numbers") from None
    return out
