import os

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from core.geometry import make_rigid, rig_from_mayacam
from core.io import open_sequence, read_tiff_volume
from core.io.autoscoper import (
    AutoscoperTrial,
    AutoscoperVolume,
    matrix_to_xyzypr,
    read_autoscoper_cfg,
    read_tra,
    read_vie,
    write_autoscoper_cfg,
    write_tra,
    xyzypr_to_matrix,
)
from core.samples import load_wrist_sample

WRIST_VOXEL = (0.39625, 0.39625, 0.625)


def _wrist_cfg(tmp_path, data: os.PathLike) -> os.PathLike:
    """A version 1.1 .cfg made of the lines quoted in the sample's README (relative paths)."""
    rel = os.path.relpath(data, tmp_path)
    lines = ["# wrist trial, lines as in the Autoscoper sample", "Version 1.1", ""]
    lines += [f"mayaCam_csv {rel}/Calibration/xr_calib_wrist_cam0{k}.txt" for k in (1, 2)]
    lines += [f"CameraRootDir {rel}/XMA_UND/xr_data_wrist_cam0{k}/" for k in (1, 2)]
    for bone in ("rad", "uln"):
        lines += [f"VolumeFile {rel}/Models/{bone}_dcm_cropped.tif", "VolumeFlip 0 0 0",
                  "VoxelSize 0.39625 0.39625 0.625"]
    lines += ["RenderResolution 512 512", "OptimizationOffsets 0.1 0.1 0.1 0.1 0.1 0.1"]
    p = tmp_path / "wrist.cfg"
    p.write_text("\r\n".join(lines) + "\r\n")
    return p


def test_real_wrist_trial_cfg(tmp_path, sample_data):
    data = sample_data / "autoscoper_wrist"
    trial = read_autoscoper_cfg(_wrist_cfg(tmp_path, data))
    assert trial.version == (1, 1) and trial.render_resolution == (512, 512)
    assert [p.resolve() for p in trial.cameras] == [
        (data / "Calibration" / f"xr_calib_wrist_cam0{k}.txt").resolve() for k in (1, 2)]
    assert trial.volumes[0].voxel_size == WRIST_VOXEL and trial.volumes[1].flip == (False, False, False)
    # everything the .cfg points to loads, and agrees with the sample loader
    rig = rig_from_mayacam(list(trial.cameras))
    ref = load_wrist_sample(data)
    for a, b in zip(rig, ref.rig, strict=True):
        np.testing.assert_array_equal(a.P, b.P)
    for cam, folder in zip(rig, trial.camera_root_dirs, strict=True):
        seq = open_sequence(folder)
        assert seq.frame_shape == cam.image_shape == (1760, 1760) and len(seq) == 3
    vol = read_tiff_volume(trial.volumes[0].path, trial.volumes[0].voxel_size, hu_offset=-1024)
    np.testing.assert_array_equal(vol.data, ref.volumes["radius"].data)
    # write it elsewhere (relative paths from there) and read the same trial back
    out = tmp_path / "elsewhere" / "copy.cfg"
    out.parent.mkdir()
    write_autoscoper_cfg(trial, out)
    back = read_autoscoper_cfg(out)
    assert [p.resolve() for p in back.cameras] == [p.resolve() for p in trial.cameras]
    assert back.volumes[1].path.resolve() == trial.volumes[1].path.resolve()
    assert back.optimization_offsets == trial.optimization_offsets
    assert "Version 1.1" in out.read_text() and "../" in out.read_text()


def test_cfg_version_1_0_windows_paths(tmp_path):
    p = tmp_path / "old.cfg"
    p.write_text(
        "mayaCam_csv C:\\\\data\\\\cam1.csv\nmayaCam_csv C:/data/cam2.csv\n"
        "CameraRootDir C:\\data\\cam1\\\nCameraRootDir C:/data/cam2/\n"
        "VolumeFile C:/data/v.tif\nVolumeFlip 1 0 1\nVoxelSize 0.5 0.5 1\n"
        "OptimizationOffsets 0.2 0.2 0.2 1 1 1\n"
    )
    t = read_autoscoper_cfg(p)
    assert t.version == (1, 0)
    assert [x.as_posix() for x in t.cameras] == ["C:/data/cam1.csv", "C:/data/cam2.csv"]
    assert t.camera_root_dirs[0].as_posix() == "C:/data/cam1"
    assert t.volumes[0].flip == (True, False, True) and t.optimization_offsets == (0.2, 0.2, 0.2, 1, 1, 1)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("mayaCam_csv a\nCameraRootDir b\nVolumeFile v\nVoxelSise 1 1 1\n",
         r"line 4: unknown key 'VoxelSise'"),
        ("mayaCam_csv a\nmayaCam_csv b\nCameraRootDir b\nVolumeFile v\nVoxelSize 1 1 1\n",
         r"one CameraRootDir per mayaCam_csv .* got 2 camera\(s\) and 1 folder"),
        ("mayaCam_csv a\nCameraRootDir b\nVolumeFile v\n", r"1 file\(s\), 0 voxel size"),
        ("mayaCam_csv a\nCameraRootDir b\nVolumeFile v\nVoxelSize 1 0 1\n", "three positive sizes"),
        ("mayaCam_csv a\nCameraRootDir b\nVolumeFile v\nVolumeFlip 0 2 0\nVoxelSize 1 1 1\n", "0/1 flags"),
        ("Version one\n", r"Version\): expected MAJOR\.MINOR"),
        ("Version 2.0\n", "Version 2.0 is not supported"),
        ("RenderResolution 512\n", r"RenderResolution\): expected 2 number"),
    ],
)
def test_cfg_errors_are_named(tmp_path, text, match):
    p = tmp_path / "bad.cfg"
    p.write_text(text)
    with pytest.raises(ValueError, match=match):
        read_autoscoper_cfg(p)


def _poses(n=6, nv=2, seed=0):
    rng = np.random.default_rng(seed)
    R = Rotation.random(n * nv, random_state=rng).as_matrix().reshape(n, nv, 3, 3)
    t = rng.uniform(-300, 300, size=(n, nv, 3))
    P = make_rigid(R, t)
    P[1, 0] = np.nan  # volume 0 untracked at frame 1
    P[4] = np.nan  # nothing tracked at frame 4
    return P


@pytest.mark.parametrize("layout", ["matrix", "xyzypr"])
@pytest.mark.parametrize("order", ["row", "column"])
@pytest.mark.parametrize("separator", [",", " "])
@pytest.mark.parametrize(("units", "angles"), [("mm", "deg"), ("cm", "rad")])
def test_tra_round_trip(tmp_path, layout, order, separator, units, angles):
    P = _poses()
    p = tmp_path / "bone.tra"
    opts = {"layout": layout, "order": order, "units": units, "angles": angles}
    write_tra(p, P, separator=separator, **opts)
    lines = p.read_text().splitlines()
    assert len(lines) == 6 and lines[4].split(separator)[0] == "NaN"
    assert len(lines[0].split(separator)) == (32 if layout == "matrix" else 12)
    back = read_tra(p, **opts)
    np.testing.assert_allclose(back, P, atol=1e-9, equal_nan=True)
    auto = read_tra(p, units=units, angles=angles)  # layout, order and volume count inferred
    np.testing.assert_allclose(auto, P, atol=1e-9, equal_nan=True)


def test_tra_autoscoper_layout_by_hand(tmp_path):
    """Lines written as Autoscoper's save_tracking_results does (fixed 16 decimals, row order)."""
    T = xyzypr_to_matrix([10.0, -20.0, 30.5, 90.0, 0.0, 0.0])
    np.testing.assert_allclose(T[:3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-15)  # yaw turns x into y
    row = ",".join(f"{v:.16f}" for v in T.ravel())
    col = " ".join(f"{v:.16f}" for v in T.T.ravel())
    p = tmp_path / "a.tra"
    p.write_text(row + "\n" + ",".join(["NaN"] * 16) + "\n")
    P = read_tra(p)
    assert P.shape == (2, 1, 4, 4) and np.isnan(P[1]).all()
    np.testing.assert_allclose(P[0, 0], T, atol=1e-15)
    p.write_text(col + "\n")
    np.testing.assert_allclose(read_tra(p)[0, 0], T, atol=1e-15)
    p.write_text("10,20,30,0,0,0\n")
    np.testing.assert_allclose(read_tra(p, units="cm")[0, 0, :3, 3], [100, 200, 300])


def test_xyzypr_convention():
    rng = np.random.default_rng(1)
    a = np.column_stack([rng.uniform(-9, 9, (50, 3)), rng.uniform(-170, 170, (50, 1)),
                         rng.uniform(-85, 85, (50, 1)), rng.uniform(-170, 170, (50, 1))])
    T = xyzypr_to_matrix(a)
    ref = Rotation.from_euler("ZYX", a[:, 3:], degrees=True).as_matrix()  # Rz(yaw) Ry(pitch) Rx(roll)
    np.testing.assert_allclose(T[:, :3, :3], ref, atol=1e-12)
    np.testing.assert_allclose(matrix_to_xyzypr(T), a, atol=1e-9)


def test_tra_errors(tmp_path):
    p = tmp_path / "e.tra"

    def bad(text, match, **kw):
        p.write_text(text)
        with pytest.raises(ValueError, match=match):
            read_tra(p, **kw)

    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([0.3, 0.2, 0.1]).as_matrix()
    row = ",".join(repr(float(v)) for v in T.ravel())
    bad(row + "\n", "matrix order is ambiguous")  # zero translation: R and R.T both look rigid
    np.testing.assert_allclose(read_tra(p, order="row")[0, 0], T)
    bad("1,2,3\n", r"3 values per line; expected a multiple of 16 \(matrix\) or 6")
    bad("1,2,3,4,5,6\n1,2,3\n", r"line 2: 3 values, expected 6")
    bad("1,2,3,x,5,6\n", r"line 1: expected numbers or NaN, got 'x'")
    bad("1,2,NaN,4,5,6\n", "volume 0 has some NaN and some numbers")
    bad(",".join(["2"] * 16) + "\n", "not a rigid 4x4 matrix")
    bad("\n\n", "no pose lines")
    bad("1,2,3,4,5,6\n", r"6 values per line; expected 2 volume\(s\) x 16", n_volumes=2)
    with pytest.raises(ValueError, match="layout"):
        read_tra(p, layout="euler")
    with pytest.raises(ValueError, match=r"poses\[0, 0\]: expected a rigid"):
        write_tra(p, np.ones((1, 4, 4)))
    with pytest.raises(ValueError, match="separator"):
        write_tra(p, np.eye(4)[None], separator=";")


def test_real_vie_files(sample_data):
    folder = sample_data / "autoscoper_wrist" / "xParameters"
    v = read_vie(folder / "control_settings.vie")
    assert [f.name for f in v.rad_filters] == ["SobelFilter", "ContrastFilter"]
    assert dict(v.rad_filters[0].params) == {"Scale": 0.43, "Blend": 3.0}
    assert dict(v.rad_filters[1].params) == {"Alpha": 2.5, "Beta": 0.9}
    assert dict(v.drr_renderer) == {"SampleDistance": 0.62, "RayIntensity": 0.35, "Cutoff": 0.0}
    drr = [(f.name, dict(f.params)) for f in v.drr_filters]
    assert drr == [("SobelFilter", {"Scale": 0.1, "Blend": 1.7})]
    e = read_vie(folder / "empty_filter.vie")
    assert e.rad_filters == () and e.drr_filters == () and e.drr_renderer["RayIntensity"] == 0.49


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("RadFilters_begin\nSobelFilter_begin\nScale 1\nRadFilters_end\n", "does not close the open block"),
        ("RadFilters_begin\nSobelFilter_begin\nRadius 1\nSobelFilter_end\nRadFilters_end\n",
         "unknown parameter 'Radius' in SobelFilter"),
        ("DrrRenderer_begin\nSampleDistance fast\nDrrRenderer_end\n", "SampleDistance: expected a number"),
        ("SobelFilter_begin\n", "unexpected 'SobelFilter_begin' inside the top level"),
        ("DrrFilters_begin\n", "end of file inside DrrFilters"),
        ("Scale 1 2\n", "expected 'Tag_begin'"),
    ],
)
def test_vie_errors(tmp_path, text, match):
    p = tmp_path / "bad.vie"
    p.write_text(text)
    with pytest.raises(ValueError, match=match):
        read_vie(p)


def test_trial_dataclass_write_validation(tmp_path):
    with pytest.raises(ValueError, match="trial: expected an AutoscoperTrial"):
        write_autoscoper_cfg({"cameras": []}, tmp_path / "x.cfg")
    vol = AutoscoperVolume(tmp_path / "v.tif", (1, 1, 2))
    t = AutoscoperTrial((tmp_path / "c1.txt",), (tmp_path / "f1",), (vol,))
    write_autoscoper_cfg(t, tmp_path / "t.cfg")
    assert read_autoscoper_cfg(tmp_path / "t.cfg").volumes[0].voxel_size == (1, 1, 2)
