"""XMALab projects (``.xma``): cameras, undistortion grids, trials and markers, read from and
written to the zip.

Layout, from XMALab 2.2.7 (XROMMPackages/xmalab ``src/ui/ProjectFileIO.cpp``:
``saveProject`` lines 150-271 and ``writeProjectFile`` 1459-1715; the readers it mirrors,
``readProjectFile`` 1717-2200): a zip holding

* ``project.xml``: ``<Project Version="0.3" CalibrationType=…>`` (0 none, 1 internal, 2
  external: ``src/core/Project.h`` 39-44) with per camera ``<Camera Name isLightCamera
  isCalibrated isFlipped CameraMatrix=<cam>/data/<cam>_CameraMatrix.csv
  [UndistortionParameter=<cam>/data/<cam>_UndistortionParameter.csv]>``, an optional
  ``<UndistortionGrid Filename isComputed>`` (with ``<Center x y>``, ``<PointsDetected>``,
  ``<GridPointsDistorted>``, ``<GridPointsReferences>``, ``<GridPointsInlier>`` file children),
  and ``<CalibrationSequence Filename Frames Width Height>`` or per calibration frame
  ``<CalibrationImage Filename|Frame [Width Height] isCalibrated>`` (``Filename="external"``
  with ``Width``/``Height`` for an external calibration) with ``<RotationMatrix Filename>`` and
  ``<TranslationVector Filename>``; then per trial ``<Trial Name Default startFrame endFrame
  referenceCalibration recordingSpeed cutOffFrequency nbImages>`` with ``<Marker Description ID
  FilenamePoints2D FilenameStatus2D FilenamePoints3D FilenameStatus3D …>`` and ``<RigidBody
  Description ID …>`` children;
* the camera matrix (``Camera::saveCameraMatrix``, ``src/core/Camera.cpp`` 417-427) and
  rotation matrix (``CalibrationImage::saveRotationMatrix``, ``src/core/CalibrationImage.cpp``
  606-621): three lines of ``a, b, c``; the translation vector (623-632): three lines of one
  number; the lens-model coefficients (``Camera::saveUndistortionParam``, ``Camera.cpp``
  467-480): eight lines of one number, OpenCV's ``k1 k2 p1 p2 k3 k4 k5 k6``. They are OpenCV's
  pinhole model of the calibration frame: ``x ~ K [R | t] X``, ``X`` in the calibration object's
  frame, which is the lab of a trial whose ``referenceCalibration`` is that frame;
* the undistortion grid (``UndistortionObject::savePoints``, ``src/core/UndistortionObject.cpp``
  844-853): one ``x, y`` line per grid point, distorted (detected) and reference (ideal) positions
  in the same order, and the inliers (870-886) one ``1`` or ``0`` a line. XMALab keeps no fitted
  model in the file: it refits its local weighted mean to the inlier pairs when it opens the
  project (``LocalUndistortion::localUndistortion_thread``, ``src/processing/LocalUndistortion.cpp``
  116-139; 12 neighbours, ``src/core/Settings.cpp`` 72);
* a trial's frames (``Trial::save``, ``src/core/Trial.cpp`` 351-361, via ``VideoStream::save``):
  ``<trial>/<cam>_filenames_absolute.txt``, one absolute image path a line (one line for an
  ``.avi`` or ``.cine``); the marker names ``<trial>/data/MarkerDescription.txt`` and rigid bodies
  ``<trial>/data/RigidBodies.txt`` (``name[i,j,…]``, 1-based marker numbers: ``Trial.cpp``
  890-916);
* a marker's 2-D points (``Marker::save``, ``src/core/Marker.cpp`` 634-650): one line per frame,
  ``x,y`` per camera, comma-separated, in the raw (distorted) image; its status file one
  ``s1,s2`` line per frame (``src/core/Marker.h`` 54-68: a point is set where the status is
  above 0, as the 3-D reconstruction requires, ``Marker.cpp`` 259); 3-D points ``x,y,z`` a line
  with their status (``Marker::save3DPoints``, 783-806).

Pixels are OpenCV's: ``(x, y) = (column, row)``, origin at the centre of the top-left pixel,
Talus's convention. A camera with ``isFlipped="1"`` sees its images mirrored left-right
(``src/core/Image.cpp`` 81-85).

:func:`read_xma_project` returns the project; :meth:`XMAProject.rig` gives Talus cameras for a
trial, :meth:`XMAProject.grid` a camera's undistortion grid, :meth:`XMAProject.view_files` a
trial's image files, :meth:`XMAProject.marker_points` a marker's 2-D track.
:func:`write_xma_project` writes a project of an external calibration (one calibration frame),
undistortion grids, trials and markers in the same layout (it lives in :mod:`core.io._xma_write`
and is importable from here, with :class:`XMATrialData` and :class:`XMAMarkerData`).
"""

from __future__ import annotations

import math
import os
import zipfile
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from xml.etree import ElementTree

import numpy as np

from ._xma_write import XMAMarkerData, XMATrialData, write_xma_project
from .errors import reads

__all__ = ["XMACamera", "XMAGrid", "XMAMarker", "XMAMarkerData", "XMAProject", "XMATrial", "XMATrialData",
           "read_xma_project", "write_xma_project"]


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
    light: bool = False  # a light (video) camera, not an X-ray view
    distortion_coeffs: np.ndarray | None = None  # (8,) OpenCV k1 k2 p1 p2 k3 k4 k5 k6, or None


@dataclass(frozen=True)
class XMAGrid:
    """A camera's undistortion grid: ``distorted`` (detected) and ``references`` (ideal) pixel
    positions ``(n, 2)`` of the same points, and which are ``inlier`` ``(n,)``."""

    distorted: np.ndarray
    references: np.ndarray
    inlier: np.ndarray


@dataclass(frozen=True)
class XMAMarker:
    id: int
    description: str
    points2d: str | None  # member path
    status2d: str | None = None
    points3d: str | None = None
    status3d: str | None = None


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
    default: bool = False  # XMALab's placeholder trial, without images
    views: tuple[str | None, ...] = ()  # per camera: member path of its file list


@dataclass(frozen=True)
class XMAProject:
    path: Path
    version: str
    cameras: tuple[XMACamera, ...]
    trials: tuple[XMATrial, ...]
    calibration_type: int = 1

    def rig(self, trial: str | None = None, *, sizes=None, cameras=None):
        """Talus :class:`~core.geometry.camera.Rig` of the cameras at ``trial``'s reference
        calibration frame (default: the first trial's, else frame 0). ``cameras``: indices of the
        cameras to include (default all); ``sizes``: ``(width, height)`` per included camera, for
        cameras whose image size the project does not record."""
        from ..geometry.camera import Camera, Rig

        ref = 0
        if trial is not None or self.trials:
            t = self.trial(trial) if trial is not None else self.trials[0]
            ref = t.reference_calibration
        cams = []
        chosen = range(len(self.cameras)) if cameras is None else list(cameras)
        for k, c in enumerate(self.cameras[i] for i in chosen):
            if ref not in c.poses:
                raise ValueError(f"{self.path}: camera {c.name!r} has no calibration at frame {ref}")
            w, h = c.width, c.height
            if (w is None or h is None) and sizes is not None:
                w, h = sizes[k]
            if w is None or h is None:
                raise ValueError(f"{self.path}: camera {c.name!r}: image size unknown")
            if not np.isfinite(c.K).all():
                raise ValueError(f"{self.path}: camera {c.name!r} has no camera matrix (not calibrated)")
            R, t = c.poses[ref]
            try:
                cams.append(Camera(K=c.K, R=R, t=t, width=w, height=h, name=c.name))
            except ValueError as exc:
                raise ValueError(f"{self.path}: camera {c.name!r}: {exc}") from None
        return Rig(cams)

    def trial(self, name: str) -> XMATrial:
        for t in self.trials:
            if t.name == name:
                return t
        have = [t.name for t in self.trials]
        raise ValueError(f"trial: no trial named {name!r} in {self.path} (have {have})")

    def camera(self, name: str) -> XMACamera:
        for c in self.cameras:
            if c.name == name:
                return c
        have = [c.name for c in self.cameras]
        raise ValueError(f"camera: no camera named {name!r} in {self.path} (have {have})")

    def marker_points(self, trial: str, marker: int) -> np.ndarray:
        """``(n_frames, n_cameras, 2)`` raw-image pixel positions of a marker, NaN where it is not
        set (status 0 or below, or XMALab's ``-2, -2`` placeholder when there is no status file)."""
        return _marker_points(self.path, self, trial, marker)

    def marker_status(self, trial: str, marker: int) -> np.ndarray | None:
        """``(n_frames, n_cameras)`` XMALab status codes of a marker's 2-D points (``Marker.h``
        54-68: 0 undefined, 10 predicted, 20 interpolated, 40 tracked, 50 set, 60 manual, below 0
        lost or deleted), or None when the project has no status file."""
        return _marker_status(self.path, self, trial, marker)

    def marker_points3d(self, trial: str, marker: int) -> np.ndarray | None:
        """``(n_frames, 3)`` reconstructed positions (lab, the project's units), NaN where the 3-D
        status is 0 or below; None when the project holds none."""
        return _marker_points3d(self.path, self, trial, marker)

    def grid(self, camera: str) -> XMAGrid | None:
        """The undistortion grid of ``camera``, or None when it has none (not computed)."""
        return _grid(self.path, self.camera(camera))

    def view_files(self, trial: str) -> list[list[str]]:
        """Per camera, the image files a trial lists (absolute paths on the machine that saved
        the project, as written; one file for a video)."""
        return _view_files(self.path, self, trial)


# ---------------------------------------------------------------------------- reading
def _rows(text: str) -> list[str]:
    return [r for r in text.replace("\r", "").split("\n") if r.strip()]


def _numbers(path, member: str, text: str, shape) -> np.ndarray:
    rows = _rows(text)
    try:
        vals = [float(v) for r in rows for v in r.split(",")]
    except ValueError:
        raise ValueError(f"{path}: {member}: expected comma-separated numbers") from None
    if len(vals) != int(np.prod(shape)) or not all(math.isfinite(v) for v in vals):
        raise ValueError(f"{path}: {member}: expected {int(np.prod(shape))} finite numbers, got {len(vals)}")
    return np.array(vals).reshape(shape)


def _table(path, member: str, text: str, width: int, *, finite: bool = True) -> np.ndarray:
    """Rows of ``width`` comma-separated numbers → ``(n, width)``."""
    out = []
    for i, r in enumerate(_rows(text)):
        parts = r.split(",")
        if len(parts) != width:
            raise ValueError(f"{path}: {member}: line {i + 1}: {len(parts)} values, expected {width}")
        try:
            vals = [float(p) for p in parts]
        except ValueError:
            raise ValueError(f"{path}: {member}: line {i + 1}: expected numbers") from None
        if finite and not all(math.isfinite(v) for v in vals):
            raise ValueError(f"{path}: {member}: line {i + 1}: expected finite numbers")
        out.append(vals)
    return np.array(out, float).reshape(len(out), width)


def _norm(rel: str) -> str:
    return str(PurePosixPath(rel.replace("\\", "/")))


def _member(zf: zipfile.ZipFile, names: set[str], rel: str, path) -> str:
    m = _norm(rel)
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


def _text(path, zf: zipfile.ZipFile, member: str, limit: int = 256 << 20) -> str:
    if zf.getinfo(member).file_size > limit:
        raise ValueError(f"{path}: {member} is too large")
    try:
        return zf.read(member).decode("utf-8-sig")
    except UnicodeDecodeError:
        raise ValueError(f"{path}: {member}: expected UTF-8 text") from None


def read_xma_project(path: str | os.PathLike) -> XMAProject:
    """Read an XMALab ``.xma`` project (see the module docs)."""
    return _read(Path(path))


@reads("an XMALab project (.xma: a zip with project.xml)")
def _read(path: Path) -> XMAProject:
    with zipfile.ZipFile(path) as zf:
        names = set(zf.namelist())
        if "project.xml" not in names:
            raise ValueError(f"{path}: no project.xml in the archive")
        if zf.getinfo("project.xml").file_size > 64 << 20:
            raise ValueError(f"{path}: project.xml is too large (expected a small XML file)")
        try:
            root = ElementTree.fromstring(zf.read("project.xml"))
        except ElementTree.ParseError as exc:
            raise ValueError(f"{path}: project.xml: expected XML ({exc})") from None
        if root.tag != "Project":
            raise ValueError(f"{path}: project.xml: root element <{root.tag}>, expected <Project>")

        def text(member: str) -> str:
            return _text(path, zf, member)

        cameras = []
        for c in root.findall("Camera"):
            name = c.get("Name")
            if not name:
                raise ValueError(f"{path}: <Camera> without a Name")
            K = np.full((3, 3), np.nan)
            if c.get("CameraMatrix"):
                m = _member(zf, names, c.get("CameraMatrix"), path)
                K = _numbers(path, m, text(m), (3, 3))
            coeffs = None
            if c.get("UndistortionParameter"):
                m = _member(zf, names, c.get("UndistortionParameter"), path)
                vals = _table(path, m, text(m), 1)[:, 0]
                if len(vals) > 8:
                    raise ValueError(f"{path}: {m}: {len(vals)} lines, expected 8 lens coefficients")
                coeffs = np.zeros(8)
                coeffs[: len(vals)] = vals  # XMALab reads missing lines as 0 (Camera.cpp 501-507)
            und = {}
            grid = c.find("UndistortionGrid")
            if grid is not None and grid.get("isComputed", "1") not in ("0", ""):
                if grid.get("Filename"):
                    und["image"] = _norm(grid.get("Filename"))
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
            if (width is not None and width <= 0) or (height is not None and height <= 0):
                raise ValueError(f"{path}: camera {name!r}: image size {width}x{height}, expected positive")
            cameras.append(XMACamera(name, K, width, height, c.get("isFlipped", "0") == "1",
                                     c.get("isCalibrated", "0") == "1", poses, und,
                                     c.get("isLightCamera", "0") == "1", coeffs))
        if not cameras:
            raise ValueError(f"{path}: project.xml has no <Camera>")
        trials = []
        for t in root.findall("Trial"):
            tname = t.get("Name") or f"trial{len(trials) + 1}"
            markers = []
            for m in t.findall("Marker"):
                def opt(attr, m=m):
                    v = m.get(attr)
                    return None if not v else _norm(v)

                markers.append(XMAMarker(_int(path, m, "ID"), m.get("Description", ""),
                                         opt("FilenamePoints2D"), opt("FilenameStatus2D"),
                                         opt("FilenamePoints3D"), opt("FilenameStatus3D")))
            default = t.get("Default", "0") == "1" or tname == "Default"
            views = tuple(
                (f"{tname}/{c.name}_filenames_absolute.txt"
                 if f"{tname}/{c.name}_filenames_absolute.txt" in names else None) for c in cameras)
            trials.append(XMATrial(
                tname, _int(path, t, "startFrame", 1),
                _int(path, t, "endFrame", 1), _int(path, t, "referenceCalibration", 0),
                _float(path, t, "recordingSpeed"), _float(path, t, "cutOffFrequency"),
                _int(path, t, "nbImages", 0), tuple(markers),
                tuple(r.get("Description", "") for r in t.findall("RigidBody")), default, views))
    return XMAProject(path, root.get("Version", ""), tuple(cameras), tuple(trials),
                      _int(path, root, "CalibrationType", 1))


def _open_member(path: Path, member: str) -> str:
    with zipfile.ZipFile(path) as zf:
        if member not in zf.namelist():
            raise ValueError(f"{path}: {member} is not in the archive")
        return _text(path, zf, member)


def _marker(path: Path, project: XMAProject, trial: str, marker: int) -> XMAMarker:
    t = project.trial(trial)
    m = next((m for m in t.markers if m.id == marker), None)
    if m is None:
        raise ValueError(f"marker: trial {trial!r} of {path} has no marker {marker}")
    return m


@reads("an XMALab project marker file (one line per frame, x,y per camera)")
def _marker_points(path: Path, project: XMAProject, trial: str, marker: int) -> np.ndarray:
    m = _marker(path, project, trial, marker)
    if m.points2d is None:
        raise ValueError(f"{path}: trial {trial!r} has no 2-D points of marker {marker}")
    nc = len(project.cameras)
    out = _table(path, m.points2d, _open_member(path, m.points2d), 2 * nc).reshape(-1, nc, 2)
    status = _marker_status(path, project, trial, marker)
    if status is not None:
        if len(status) != len(out):
            raise ValueError(f"{path}: {m.status2d}: {len(status)} frames, the points {len(out)}")
        out[status <= 0] = np.nan
    else:
        out[(out == -2.0).all(axis=2)] = np.nan  # XMALab's placeholder of an unset point (Marker.cpp 1901)
    return out


@reads("an XMALab project marker status file (one line per frame, a code per camera)")
def _marker_status(path: Path, project: XMAProject, trial: str, marker: int) -> np.ndarray | None:
    m = _marker(path, project, trial, marker)
    if m.status2d is None:
        return None
    with zipfile.ZipFile(path) as zf:
        if m.status2d not in zf.namelist():
            return None  # optional: XMALab reads the points without it
        text = _text(path, zf, m.status2d)
    return _table(path, m.status2d, text, len(project.cameras)).astype(int)


@reads("an XMALab project 3-D marker file (one x,y,z line per frame)")
def _marker_points3d(path: Path, project: XMAProject, trial: str, marker: int) -> np.ndarray | None:
    m = _marker(path, project, trial, marker)
    if m.points3d is None:
        return None
    with zipfile.ZipFile(path) as zf:
        have = zf.namelist()
        if m.points3d not in have:
            return None
        X = _table(path, m.points3d, _text(path, zf, m.points3d), 3, finite=False)
        if m.status3d and m.status3d in have:
            s = _table(path, m.status3d, _text(path, zf, m.status3d), 1)[:, 0]
            if len(s) != len(X):
                raise ValueError(f"{path}: {m.status3d}: {len(s)} frames, the points {len(X)}")
            X[s <= 0] = np.nan
    return X


@reads("an XMALab undistortion grid (x, y lines; inliers 1 or 0)")
def _grid(path: Path, cam: XMACamera) -> XMAGrid | None:
    u = cam.undistortion
    if "GridPointsDistorted" not in u or "GridPointsReferences" not in u:
        return None
    with zipfile.ZipFile(path) as zf:
        d = _table(path, u["GridPointsDistorted"], _text(path, zf, u["GridPointsDistorted"]), 2)
        r = _table(path, u["GridPointsReferences"], _text(path, zf, u["GridPointsReferences"]), 2)
        if len(d) != len(r):
            raise ValueError(f"{path}: camera {cam.name!r}: {len(d)} distorted grid points but "
                             f"{len(r)} reference points")
        inl = np.ones(len(d), bool)
        if "GridPointsInlier" in u:
            v = _table(path, u["GridPointsInlier"], _text(path, zf, u["GridPointsInlier"]), 1)[:, 0]
            if len(v) != len(d):
                raise ValueError(f"{path}: {u['GridPointsInlier']}: {len(v)} lines, expected {len(d)} "
                                 "(one per grid point)")
            inl = v > 0.5  # UndistortionObject.cpp 994
    return XMAGrid(d, r, inl)


@reads("an XMALab trial file list (one image path a line)")
def _view_files(path: Path, project: XMAProject, trial: str) -> list[list[str]]:
    t = project.trial(trial)
    if t.default:
        raise ValueError(f"trial: {trial!r} of {path} is XMALab's default trial (no images)")
    out = []
    with zipfile.ZipFile(path) as zf:
        for c, member in zip(project.cameras, t.views, strict=True):
            if member is None:
                raise ValueError(f"{path}: trial {trial!r} has no {t.name}/{c.name}_filenames_absolute.txt")
            files = [r.strip() for r in _rows(_text(path, zf, member))]
            if not files:
                raise ValueError(f"{path}: {member}: expected one image path a line, found none")
            out.append(files)
    return out
