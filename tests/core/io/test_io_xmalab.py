import numpy as np
import pytest

from core.geometry import P_from_dlt
from core.io.xmalab import (
    dlt_csv_from_rig,
    read_dlt_csv,
    read_points_2d,
    read_points_3d,
    rig_from_dlt_csv,
    write_dlt_csv,
    write_points_2d,
    write_points_3d,
)
from core.synthetic import foot_rig


@pytest.fixture(scope="module")
def rig():
    return foot_rig(seed=5, pixels=256)


@pytest.fixture(scope="module")
def lab_points():
    return np.random.default_rng(0).uniform(-40, 40, size=(4, 5, 3))  # (frames, markers, xyz) mm


def test_dlt_csv_round_trip(tmp_path, rig, lab_points):
    p = tmp_path / "cal_DLTcoefs.csv"
    dlt_csv_from_rig(rig, p)
    lines = p.read_text().splitlines()
    assert len(lines) == 11 and all(len(ln.split(",")) == 2 for ln in lines)  # L1..L11 x cameras
    L = read_dlt_csv(p)
    assert L.shape == (2, 11)
    back = rig_from_dlt_csv(p, [(c.width, c.height) for c in rig])
    X = lab_points.reshape(-1, 3)
    for a, b in zip(rig, back, strict=True):
        np.testing.assert_allclose(b.project(X), a.project(X), atol=1e-6)
        np.testing.assert_allclose(b.source, a.source, atol=1e-6)
    # the stored DLT is in DLTdv coordinates: u + 1, height - v
    uv = rig[0].project(X)
    h = np.c_[X, np.ones(len(X))] @ P_from_dlt(L[0], convention="talus").T
    np.testing.assert_allclose(h[:, :2] / h[:, 2:], np.c_[uv[:, 0] + 1, rig[0].height - uv[:, 1]], atol=1e-6)
    tp = tmp_path / "rows.csv"  # one row of 11 per camera is accepted too
    tp.write_text("\n".join(",".join(repr(float(x)) for x in row) for row in L) + "\n")
    np.testing.assert_array_equal(read_dlt_csv(tp), L)


def test_dlt_errors(tmp_path, rig):
    p = tmp_path / "d.csv"
    p.write_text("1,2\n3,4\n")
    with pytest.raises(ValueError, match=r"2 rows of 2 values; expected 11 rows \(L1\.\.L11\)"):
        read_dlt_csv(p)
    p.write_text("1,2\n3\n")
    with pytest.raises(ValueError, match="different numbers of values"):
        read_dlt_csv(p)
    p.write_text("\n".join(["1,x"] * 11))
    with pytest.raises(ValueError, match=r"line 1, column 2: expected a number, got 'x'"):
        read_dlt_csv(p)
    dlt_csv_from_rig(rig, p)
    with pytest.raises(ValueError, match=r"image_sizes: expected 2"):
        rig_from_dlt_csv(p, [(256, 256)])
    with pytest.raises(ValueError, match="coefficients"):
        write_dlt_csv(p, np.ones((2, 10)))


@pytest.mark.parametrize(("offset1", "yinvert"), [(False, False), (True, False), (True, True)])
def test_points_2d_round_trip(tmp_path, rig, lab_points, offset1, yinvert):
    uv = np.stack([c.project(lab_points) for c in rig], axis=2)  # (frames, markers, cams, 2)
    uv[1, 2, 0] = np.nan  # marker 3 not found in camera 1 at frame 1
    names = ["bead_a", "bead_b", "talus1", "talus2", "calc1"]
    heights = [c.height for c in rig]
    p = tmp_path / "pts2d.csv"
    write_points_2d(p, names, uv, offset1=offset1, yinvert=yinvert, heights=heights)
    head = p.read_text().splitlines()[0]
    assert head.startswith("bead_a_cam1_X , bead_a_cam1_Y , bead_a_cam2_X")
    got_names, got = read_points_2d(p, offset1=offset1, yinvert=yinvert, heights=heights)
    assert got_names == tuple(names)
    np.testing.assert_allclose(got, uv, atol=1e-9, equal_nan=True)
    if offset1 and yinvert:  # == DLTdv coordinates, consistent with the DLT file convention
        raw = np.array([[float(x) for x in ln.split(",")] for ln in p.read_text().splitlines()[1:]])
        raw = raw.reshape(uv.shape)
        np.testing.assert_allclose(raw[0, 0, 1], [uv[0, 0, 1, 0] + 1, heights[1] - uv[0, 0, 1, 1]])


def test_points_2d_without_header(tmp_path):
    p = tmp_path / "n.csv"
    p.write_text("1,2,3,4\n5,6,NaN,NaN\n")
    names, pts = read_points_2d(p, n_cameras=2)
    assert names == ("marker001",) and pts.shape == (2, 1, 2, 2) and np.isnan(pts[1, 0, 1]).all()
    with pytest.raises(ValueError, match="n_cameras: required"):
        read_points_2d(p)
    p.write_text("1,NaN,3,4\n")
    with pytest.raises(ValueError, match="marker 'marker001' camera 1 has one NaN coordinate"):
        read_points_2d(p, n_cameras=2)
    p.write_text("a_cam1_X,a_cam1_Y,a_cam2_Y,a_cam2_X\n1,2,3,4\n")
    with pytest.raises(ValueError, match="header column 'a_cam2_Y'; expected a_cam2_X"):
        read_points_2d(p)
    p.write_text("a_cam1_X,a_cam1_Y\n1,2\n")
    with pytest.raises(ValueError, match=r"heights: expected 1 image height"):
        read_points_2d(p, yinvert=True)


def test_points_3d_round_trip(tmp_path, lab_points):
    pts = lab_points.copy()
    pts[2, 1] = np.nan
    p = tmp_path / "p3.csv"
    write_points_3d(p, ["m1", "m2", "m3", "m4", "m5"], pts)
    assert p.read_text().splitlines()[0].startswith("m1_X , m1_Y , m1_Z , m2_X")
    names, back = read_points_3d(p)
    assert names[4] == "m5"
    np.testing.assert_array_equal(back, pts)
    p.write_text("a_X,a_Y,a_Q\n1,2,3\n")
    with pytest.raises(ValueError, match=r"expected <marker>_X, _Y, _Z"):
        read_points_3d(p)
    p.write_text("1,2\n")
    with pytest.raises(ValueError, match="2 columns; expected a multiple of 3"):
        read_points_3d(p)


def test_real_calibrations_through_dlt(tmp_path, sample_data):
    """Every real MayaCam file of the sample survives MayaCam -> DLT CSV -> camera."""
    from core.geometry import read_mayacam
    from core.geometry.camera import Rig

    files = sorted((sample_data / "autoscoper_wrist" / "Calibration").glob("*.txt"))
    assert len(files) == 6
    cams = [read_mayacam(f) for f in files]
    rig = Rig(tuple(cams))
    p = tmp_path / "all_DLTcoefs.csv"
    dlt_csv_from_rig(rig, p)
    back = rig_from_dlt_csv(p, [(c.width, c.height) for c in cams], max_skew_px=1.0)
    X = np.random.default_rng(2).uniform(-50, 50, size=(20, 3)) + np.array([100.0, 130.0, 90.0])
    for a, b in zip(cams, back, strict=True):
        np.testing.assert_allclose(b.project(X), a.project(X), atol=1e-3)
