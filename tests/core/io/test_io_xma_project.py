"""XMALab .xma projects read from an archive written to XMALab's layout (ProjectFileIO.cpp)."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from core.errors import FileError
from core.io.xma_project import read_xma_project

K = [np.array([[1800.0, 0, 512], [0, 1800.0, 500], [0, 0, 1]]),
     np.array([[1750.0, 0, 520], [0, 1760.0, 510], [0, 0, 1]])]
R = [Rotation.from_euler("xyz", a, degrees=True).as_matrix() for a in ([5, 30, -2], [-4, -35, 3])]
T = [np.array([10.0, -20.0, 900.0]), np.array([-15.0, 5.0, 950.0])]


def _csv(M) -> str:
    M = np.atleast_2d(M)
    return "".join(", ".join(f"{v:.12g}" for v in row) + "\n" for row in M)


def make_xma(path, points3d, *, drop=None) -> None:
    cams = ["cam1", "cam2"]
    xml = ['<?xml version="1.0" encoding="UTF-8"?>',
           '<Project Version="0.3" DateCreated="x" ActiveTrial="0" CalibrationType="0">']
    files = {}
    for c, name in enumerate(cams):
        xml.append(f'<Camera Name="{name}" isLightCamera="0" isCalibrated="1" isOptimized="0" isFlipped="0" '
                   f'CameraMatrix="{name}/data/{name}_CameraMatrix.csv">')
        xml.append(f'<UndistortionGrid Filename="{name}/grid.tif" isComputed="1">'
                   f'<GridPointsDistorted Filename="{name}/data/grid_GridPointsDistorted.csv"/>'
                   '</UndistortionGrid>')
        xml.append(f'<CalibrationSequence Filename="{name}/calib.avi" Frames="1" Width="1024" Height="1000">')
        xml.append(f'<CalibrationImage Frame="0" isCalibrated="1">'
                   f'<RotationMatrix Filename="{name}/data/calib0_RotationMatrix.csv"/>'
                   f'<TranslationVector Filename="{name}/data/calib0_TranslationVector.csv"/>'
                   '</CalibrationImage>')
        xml.append("</CalibrationSequence></Camera>")
        files[f"{name}/data/{name}_CameraMatrix.csv"] = _csv(K[c])
        files[f"{name}/data/calib0_RotationMatrix.csv"] = _csv(R[c])
        files[f"{name}/data/calib0_TranslationVector.csv"] = "".join(f"{v:.12g}\n" for v in T[c])
        files[f"{name}/data/grid_GridPointsDistorted.csv"] = "1, 2\n3, 4\n"
    xml.append('<Trial Name="hop" Default="0" FromDefault="0" startFrame="1" endFrame="3" '
               'referenceCalibration="0" recordingSpeed="250" cutOffFrequency="25" interpolate3D="0" '
               'nbImages="3">')
    xml.append('<Marker Description="bead1" ID="0" FilenamePoints2D="hop/data/Marker000points2d.csv"/>')
    xml.append('<RigidBody Description="tibia" ID="0"/></Trial></Project>')
    rows = []
    for X in points3d:
        vals = []
        for c in range(2):
            x = K[c] @ (R[c] @ X + T[c])
            vals += [x[0] / x[2], x[1] / x[2]]
        rows.append(",".join(f"{v:.12g}" for v in vals))
    files["hop/data/Marker000points2d.csv"] = "\n".join(rows) + "\n"
    files["project.xml"] = "\n".join(xml)
    if drop:
        files.pop(drop)
    with zipfile.ZipFile(path, "w") as zf:
        for k, v in files.items():
            zf.writestr(k, v)


def test_xma_project_cameras_trials_markers(tmp_path):
    X = np.array([[0.0, 0.0, 0.0], [10.0, -5.0, 20.0], [-3.0, 8.0, 4.0]])
    p = tmp_path / "study.xma"
    make_xma(p, X)
    prj = read_xma_project(p)
    assert [c.name for c in prj.cameras] == ["cam1", "cam2"] and prj.version == "0.3"
    (t,) = prj.trials
    assert (t.name, t.start_frame, t.end_frame) == ("hop", 1, 3)
    assert (t.recording_speed, t.cutoff_frequency) == (250, 25)
    assert t.markers[0].description == "bead1" and t.rigid_bodies == ("tibia",)
    assert "GridPointsDistorted" in prj.cameras[0].undistortion
    rig = prj.rig("hop")
    uv = prj.marker_points("hop", 0)
    assert uv.shape == (3, 2, 2)
    for c in range(2):
        np.testing.assert_allclose(np.asarray(rig[c].project(X)), uv[:, c], atol=1e-6)


@pytest.mark.parametrize("drop", ["project.xml", "cam2/data/calib0_RotationMatrix.csv"])
def test_damaged_projects_name_the_file(tmp_path, drop):
    p = tmp_path / "bad.xma"
    make_xma(p, np.zeros((1, 3)), drop=drop)
    with pytest.raises(FileError, match=r"bad\.xma"):
        read_xma_project(p)
    q = tmp_path / "notzip.xma"
    q.write_bytes(b"PK\x03\x04garbage")
    with pytest.raises(FileError, match=r"notzip\.xma"):
        read_xma_project(q)
