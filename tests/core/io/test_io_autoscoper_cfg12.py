"""Autoscoper configuration version 1.2 (MeshFile per volume) and Windows line endings."""

from __future__ import annotations

import pytest

from core.errors import FileError
from core.io.autoscoper import AutoscoperTrial, AutoscoperVolume, read_autoscoper_cfg, write_autoscoper_cfg

# the example of Autoscoper's configuration specification (Documentation/file-specifications/config.md)
SPEC = """# This is a comment
Version 1.2

mayaCam_csv Calibration/task-cam01.csv
mayaCam_csv Calibration/task-cam02.csv

CameraRootDir RadiographImages/task-cam01/
CameraRootDir RadiographImages/task-cam02/

VolumeFile Volumes/radius.tif
VolumeFlip 0 0 0
VoxelSize 0.1 0.1 0.1
MeshFile Models/radius.stl

RenderResolution 512 512

OptimizationOffsets 0.1 0.1 0.1 0.1 0.1 0.1
"""


@pytest.mark.parametrize("newline", ["\n", "\r\n"])
def test_spec_example_reads(tmp_path, newline):
    p = tmp_path / "task.cfg"
    p.write_bytes(SPEC.replace("\n", newline).encode())
    t = read_autoscoper_cfg(p)
    assert t.version == (1, 2)
    (v,) = t.volumes
    assert v.mesh == tmp_path / "Models" / "radius.stl"
    assert v.path == tmp_path / "Volumes" / "radius.tif" and v.voxel_size == (0.1, 0.1, 0.1)
    assert t.camera_root_dirs[1] == tmp_path / "RadiographImages" / "task-cam02"


def test_mesh_counts_and_versions(tmp_path):
    p = tmp_path / "a.cfg"
    extra = "MeshFile Models/radius.stl\nVolumeFile Volumes/u.tif\nVoxelSize 0.1 0.1 0.1\n"
    two = SPEC.replace("MeshFile Models/radius.stl\n", extra)
    p.write_text(two)
    with pytest.raises(FileError, match=r"a\.cfg.*MeshFile for each VolumeFile"):
        read_autoscoper_cfg(p)
    # before 1.2 Autoscoper ignores MeshFile lines (Trial.cpp reads meshes only from 1.2)
    p.write_text(SPEC.replace("Version 1.2", "Version 1.1"))
    assert read_autoscoper_cfg(p).volumes[0].mesh is None


@pytest.mark.parametrize("newline", ["\n", "\r\n"])
def test_write_read_round_trip(tmp_path, newline):
    t = AutoscoperTrial(
        cameras=(tmp_path / "c1.txt", tmp_path / "c2.txt"),
        camera_root_dirs=(tmp_path / "f1", tmp_path / "f2"),
        volumes=(AutoscoperVolume(tmp_path / "v" / "rad.tif", (0.39625, 0.39625, 0.625), (False, True, False),
                                  tmp_path / "m" / "rad.stl"),
                 AutoscoperVolume(tmp_path / "v" / "uln.tif", (0.4, 0.4, 0.6), (False, False, False),
                                  tmp_path / "m" / "uln.stl")),
        render_resolution=(640, 480), optimization_offsets=(0.1, 0.2, 0.3, 0.4, 0.5, 0.6), version=(1, 2),
    )
    p = tmp_path / "out.cfg"
    write_autoscoper_cfg(t, p, newline=newline)
    raw = p.read_bytes()
    assert raw.startswith(b"Version 1.2")
    assert raw.count(b"\r\n") == (raw.count(b"\n") if newline == "\r\n" else 0)
    assert read_autoscoper_cfg(p) == t
    half = AutoscoperTrial(t.cameras, t.camera_root_dirs, (t.volumes[0], AutoscoperVolume(tmp_path / "x.tif",
                                                                                          (1, 1, 1))))
    with pytest.raises(ValueError, match="mesh for every volume"):
        write_autoscoper_cfg(half, tmp_path / "h.cfg")
