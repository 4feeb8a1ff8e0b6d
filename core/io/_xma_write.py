"""Writing XMALab projects (``.xma``): :func:`write_xma_project` and the trial and marker data it
takes. The layout, and the XMALab source it follows, are described in :mod:`core.io.xma_project`,
which reads it and from which these names are importable.

Pixels are OpenCV's: ``(x, y) = (column, row)``, origin at the centre of the top-left pixel.
"""

from __future__ import annotations

import io
import os
import zipfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from .atomic import atomic_write

__all__ = ["XMAMarkerData", "XMATrialData", "write_xma_project"]


@dataclass(frozen=True)
class XMAMarkerData:
    """A marker to write: ``points2d`` ``(n_frames, n_cameras, 2)`` raw-image pixels (NaN: not
    set), optional ``points3d`` ``(n_frames, 3)`` (NaN: none)."""

    description: str
    points2d: np.ndarray
    points3d: np.ndarray | None = None


@dataclass(frozen=True)
class XMATrialData:
    """A trial to write: ``views`` per camera the image files (one for a video)."""

    name: str
    views: Sequence[Sequence[str]]
    markers: Sequence[XMAMarkerData] = ()
    rigid_bodies: Mapping[str, Sequence[int]] = field(default_factory=dict)  # name -> 0-based markers
    recording_speed: float = 0.0
    cutoff_frequency: float = 0.0
    n_frames: int | None = None  # default: the number of image files, else the markers' frames


def _csv(M, sep: str = ", ") -> str:
    M = np.atleast_2d(np.asarray(M, float))
    return "".join(sep.join(repr(float(v)) for v in row) + "\n" for row in M)


def _blank_tiff(width: int, height: int) -> bytes:
    import tifffile

    buf = io.BytesIO()
    tifffile.imwrite(buf, np.zeros((height, width), np.uint8), compression="zlib")
    return buf.getvalue()


def write_xma_project(path: str | os.PathLike, cameras, trials: Sequence[XMATrialData] = (), *,
                      grids: Sequence | None = None,
                      distortion_coeffs: Sequence[np.ndarray | None] | None = None) -> Path:
    """Write an XMALab project of an external calibration (``CalibrationType="2"``).

    Parameters
    ----------
    cameras : sequence of :class:`~core.geometry.camera.Camera` (or a Rig)
        Calibration frame 0 of every camera (``K``, ``R``, ``t`` in pixels and the lab frame).
    trials : sequence of XMATrialData
        Every trial refers to calibration frame 0.
    grids : per camera, an :class:`~core.io.xma_project.XMAGrid` or None
        Undistortion grids (written with a blank grid image of the camera's size).
    distortion_coeffs : per camera, OpenCV's 8 lens coefficients or None

    The layout is XMALab's (:mod:`core.io.xma_project`); the file is written atomically.
    """
    cams = list(cameras)
    n = len(cams)
    if n < 1:
        raise ValueError("cameras: expected at least one camera")
    grids = [None] * n if grids is None else list(grids)
    coeffs = [None] * n if distortion_coeffs is None else list(distortion_coeffs)
    if len(grids) != n or len(coeffs) != n:
        raise ValueError(f"grids, distortion_coeffs: expected one entry per camera ({n})")
    names = [c.name for c in cams]
    if len(set(names)) != n or not all(names):
        raise ValueError(f"cameras: expected distinct non-empty names, got {names}")
    files: dict[str, bytes | str] = {}
    x = ['<?xml version="1.0" encoding="UTF-8"?>',
         '<Project Version="0.3" DateCreated="" ActiveTrial="0" CalibrationType="2">']
    for cam, g, k in zip(cams, grids, coeffs, strict=True):
        nm = cam.name
        attrs = (f'Name={quoteattr(nm)} isLightCamera="0" isCalibrated="1" isOptimized="0" isFlipped="0" '
                 f'CameraMatrix={quoteattr(f"{nm}/data/{nm}_CameraMatrix.csv")}')
        files[f"{nm}/data/{nm}_CameraMatrix.csv"] = _csv(cam.K)
        if k is not None:
            kk = np.zeros(8)
            kk[: len(k)] = np.asarray(k, float)
            attrs += f' UndistortionParameter={quoteattr(f"{nm}/data/{nm}_UndistortionParameter.csv")}'
            files[f"{nm}/data/{nm}_UndistortionParameter.csv"] = "".join(f"{v!r}\n" for v in map(float, kk))
        x.append(f"<Camera {attrs}>")
        if g is not None:
            stem = "UndistortionGrid"
            files[f"{nm}/{stem}.tif"] = _blank_tiff(cam.width, cam.height)
            x.append(f'<UndistortionGrid Filename={quoteattr(f"{nm}/{stem}.tif")} isComputed="1">')
            d, r = np.asarray(g.distorted, float), np.asarray(g.references, float)
            inl = np.asarray(g.inlier, bool)
            if d.shape != r.shape or d.ndim != 2 or d.shape[1] != 2 or inl.shape != (len(d),):
                raise ValueError(f"grids: camera {nm!r}: expected (n, 2) distorted and reference points "
                                 f"and (n,) inliers, got {d.shape}, {r.shape}, {inl.shape}")
            for tag, data in (("PointsDetected", _csv(d)), ("GridPointsDistorted", _csv(d)),
                              ("GridPointsReferences", _csv(r)),
                              ("GridPointsInlier", "".join(f"{int(v)}\n" for v in inl))):
                member = f"{nm}/data/{stem}_{tag}.csv"
                files[member] = data
                x.append(f"<{tag} Filename={quoteattr(member)}/>")
            x.append("</UndistortionGrid>")
        x.append(f'<CalibrationImage Filename="external" Width="{int(cam.width)}" Height="{int(cam.height)}" '
                 'isCalibrated="1">')
        for tag, data in (("RotationMatrix", _csv(cam.R)),
                          ("TranslationVector", _csv(np.reshape(cam.t, (3, 1))))):
            member = f"{nm}/data/external_{tag}.csv"
            files[member] = data
            x.append(f"<{tag} Filename={quoteattr(member)}/>")
        x.append("</CalibrationImage></Camera>")
    for tr in trials:
        if len(tr.views) != n:
            raise ValueError(f"trials: trial {tr.name!r} has {len(tr.views)} views, expected {n}")
        n_img = tr.n_frames or (len(tr.views[0]) if len(tr.views[0]) > 1 or not tr.markers
                                else len(tr.markers[0].points2d))
        x.append(f'<Trial Name={quoteattr(tr.name)} Default="0" FromDefault="0" startFrame="1" '
                 f'endFrame="{n_img}" referenceCalibration="0" '
                 f'recordingSpeed="{float(tr.recording_speed)!r}" '
                 f'cutOffFrequency="{float(tr.cutoff_frequency)!r}" interpolate3D="0" nbImages="{n_img}">')
        for c, v in zip(names, tr.views, strict=True):
            files[f"{tr.name}/{c}_filenames_absolute.txt"] = "".join(f"{f}\n" for f in v)
        files[f"{tr.name}/data/MarkerDescription.txt"] = "".join(f"{m.description}\n" for m in tr.markers)
        for i, m in enumerate(tr.markers):
            P = np.asarray(m.points2d, float)
            if P.ndim != 3 or P.shape[1:] != (n, 2):
                raise ValueError(f"trials: marker {m.description!r}: expected points2d of shape "
                                 f"(n_frames, {n}, 2), got {P.shape}")
            unset = np.isnan(P).any(axis=2)
            P = np.where(unset[..., None], -2.0, P)
            base = f"{tr.name}/data/Marker{i:03d}"
            files[f"{base}points2d.csv"] = "".join(",".join(repr(float(v)) for v in row.ravel()) + "\n"
                                                   for row in P)
            files[f"{base}status2d.csv"] = "".join(",".join("0" if u else "50" for u in row) + "\n"
                                                   for row in unset)
            a = (f'<Marker Description={quoteattr(m.description)} ID="{i}" TrackingPenalty="125" '
                 f'DetectionMethod="0" SizeOverride="-1" ThresholdOffset="8" RequiresRecomputation="0" '
                 f'FilenamePoints2D="{base}points2d.csv" FilenameStatus2D="{base}status2d.csv"')
            if m.points3d is not None:
                X = np.asarray(m.points3d, float).reshape(len(P), 3)
                bad = np.isnan(X).any(axis=1)
                files[f"{base}points3d.csv"] = "".join(
                    ",".join(repr(float(v)) for v in row) + "\n" for row in np.where(bad[:, None], 0.0, X))
                files[f"{base}status3d.csv"] = "".join("0\n" if b else "50\n" for b in bad)
                a += f' FilenamePoints3D="{base}points3d.csv" FilenameStatus3D="{base}status3d.csv"'
            x.append(a + "/>")
        rb_lines = []
        for j, (body, idx) in enumerate(tr.rigid_bodies.items()):
            rb_lines.append(f"{body}[{','.join(str(int(i) + 1) for i in idx)}]\n")
            x.append(f'<RigidBody Description={quoteattr(body)} ID="{j}" Visible="1"/>')
        files[f"{tr.name}/data/RigidBodies.txt"] = "".join(rb_lines)
        x.append("</Trial>")
    x.append("</Project>")
    files["project.xml"] = "\n".join(x) + "\n"
    out = Path(path)
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for k2, v2 in files.items():
            zf.writestr(k2, v2)
    atomic_write(out, buf.getvalue())
    return out
