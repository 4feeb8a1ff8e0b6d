"""Downstream and peer formats: every reader reads what its writer wrote, and files written by
hand to each format's published layout."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from core.errors import FileError


def _poses(n, nb, seed=0):
    rng = np.random.default_rng(seed)
    P = np.tile(np.eye(4), (n, nb, 1, 1))
    P[..., :3, :3] = Rotation.random(n * nb, random_state=rng).as_matrix().reshape(n, nb, 3, 3)
    P[..., :3, 3] = rng.normal(0, 80, (n, nb, 3))
    return P


# ---------------------------------------------------------------- XMALab rigid-body CSV
def test_rigid_body_csv_round_trip(tmp_path):
    from core.io.rigid_body_csv import read_rigid_body_csv, write_rigid_body_csv

    P = _poses(5, 2)
    P[2, 1] = np.nan
    for kw in ({}, {"frame_column": False}, {"header": False}, {"cutoff_hz": 25}):
        p = tmp_path / "rb.csv"
        write_rigid_body_csv(p, ["radius", "ulna"], P, frames=np.arange(11, 16), **kw)
        r = read_rigid_body_csv(p)
        np.testing.assert_allclose(r.poses, P, atol=1e-12)
        if kw.get("header", True):
            assert r.bodies == ("radius", "ulna")
            assert r.cutoff_hz == ((25.0, 25.0) if "cutoff_hz" in kw else (None, None))
        if kw.get("frame_column", True):
            assert list(r.frames) == list(range(11, 16))


def test_rigid_body_csv_as_xmalab_writes_it(tmp_path):
    """XMALab (Trial.cpp saveRigidBodyTransformations, RigidBody.cpp getTransformationMatrix):
    rotation rows first, translation in columns TX TY TZ, filtered suffix, 1-based frames."""
    from core.io.rigid_body_csv import read_rigid_body_csv

    names = ["R11", "R12", "R13", "01", "R21", "R22", "R23", "02", "R31", "R32", "R33", "03",
             "TX", "TY", "TZ", "1"]
    head = "Frame," + ",".join(f"cal_{n}_10Hz" for n in names)
    # rotation 90 deg about z (body x -> lab y) and translation (1, 2, 3): XMALab writes R's
    # transpose row by row, i.e. T column by column
    row = "1,0,1,0,0,-1,0,0,0,0,0,1,0,1,2,3,1"
    p = tmp_path / "xma.csv"
    p.write_text(head + "\n" + row + "\n2," + ",".join(["NaN"] * 16) + "\n")
    r = read_rigid_body_csv(p)
    assert r.bodies == ("cal",) and r.cutoff_hz == (10.0,) and list(r.frames) == [1, 2]
    T = r.poses[0, 0]
    np.testing.assert_allclose(T @ [1, 0, 0, 1], [1, 3, 3, 1])  # x axis -> lab y, plus t
    assert np.isnan(r.poses[1, 0]).all()


# ---------------------------------------------------------------- Slicer / ITK .tfm
def test_slicer_tfm_round_trip_and_published_layout(tmp_path):
    from core.io.slicer_tfm import read_itk_tfm, read_slicer_tfm, write_slicer_tfm

    T = _poses(1, 1)[0, 0]
    p = tmp_path / "bone.tfm"
    write_slicer_tfm(p, T)
    np.testing.assert_allclose(read_slicer_tfm(p), T, atol=1e-12)
    # Slicer: a RAS "to parent" translation (10, 20, 30) is saved as the LPS resampling transform
    # translation (10, 20, -30) [-(10, 20, 30) in RAS, then x, y negated]
    q = tmp_path / "slicer.tfm"
    q.write_text("#Insight Transform File V1.0\n#Transform 0\nTransform: AffineTransform_double_3_3\n"
                 "Parameters: 1 0 0 0 1 0 0 0 1 10 20 -30\nFixedParameters: 0 0 0\n")
    np.testing.assert_allclose(read_slicer_tfm(q)[:3, 3], [10, 20, 30])
    # ITK's centre: y = A (x - c) + c + t
    c = tmp_path / "centre.tfm"
    c.write_text("#Insight Transform File V1.0\n#Transform 0\nTransform: AffineTransform_double_3_3\n"
                 "Parameters: 0 -1 0 1 0 0 0 0 1 0 0 0\nFixedParameters: 5 0 0\n")
    np.testing.assert_allclose(read_itk_tfm(c) @ [5, 0, 0, 1], [5, 0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(read_itk_tfm(c) @ [6, 0, 0, 1], [5, 1, 0, 1], atol=1e-12)


# ---------------------------------------------------------------- JointTrack .jts
def test_jts_euler_is_z_x_y_and_round_trips(tmp_path):
    from core.io.jointtrack import euler312_to_matrix, matrix_to_euler312, read_jts, write_jts

    z, x, y = 30.0, -20.0, 55.0
    R = (Rotation.from_euler("z", z, degrees=True) * Rotation.from_euler("x", x, degrees=True)
         * Rotation.from_euler("y", y, degrees=True)).as_matrix()
    T = euler312_to_matrix([1, 2, -1000, z, x, y])
    np.testing.assert_allclose(T[:3, :3], R, atol=1e-12)
    np.testing.assert_allclose(matrix_to_euler312(T), [1, 2, -1000, z, x, y], atol=1e-9)
    P = _poses(4, 1)[:, 0]
    P[1] = np.nan
    p = tmp_path / "fem.jts"
    write_jts(p, P)
    np.testing.assert_allclose(read_jts(p), P, atol=1e-7)
    # a file as JointTrack writes it: title, column line, "x, y, z, z_rot, x_rot, y_rot"
    q = tmp_path / "jt.jts"
    q.write_text("JT_EULER_312\n          x_tran,          y_tran,          z_tran,                   "
                 "z_rot,           x_rot,           y_rot\n 18.52191, 19.69514, -1027.713,\t\t   "
                 "-7.419319, -0.2587041, -26.69708\nNOT_OPTIMIZED,0,0,0,0,0\n")
    r = read_jts(q)
    np.testing.assert_allclose(matrix_to_euler312(r[0]), [18.52191, 19.69514, -1027.713, -7.419319,
                                                          -0.2587041, -26.69708], atol=1e-9)
    assert np.isnan(r[1]).all()


def test_jts_camera_frame_projects_like_the_talus_camera():
    """A bone point in JointTrack's frame (source at origin, y up, looking down -z) lands on the
    pixel the Talus (OpenCV) camera gives it."""
    from core.geometry.camera import Camera
    from core.io.jointtrack import jts_to_lab, lab_to_jts

    K = np.array([[1000.0, 0, 320], [0, 1000.0, 240], [0, 0, 1]])
    R = Rotation.from_euler("xyz", [10, -20, 5], degrees=True).as_matrix()
    cam = Camera(K=K, R=R, t=np.array([5.0, -3.0, 900.0]), width=640, height=480)
    T = _poses(1, 1)[0, 0]
    T[:3, 3] = [10, 5, -50]
    J = lab_to_jts(T, cam)
    np.testing.assert_allclose(jts_to_lab(J, cam), T, atol=1e-9)
    X = np.array([3.0, -4.0, 7.0, 1.0])
    xj = J @ X  # JointTrack camera coordinates
    assert xj[2] < 0  # in front of the source: negative z
    u = 320 + 1000 * xj[0] / -xj[2]
    v = 240 - 1000 * xj[1] / -xj[2]  # y up
    uv = cam.project((T @ X)[:3])
    np.testing.assert_allclose(np.ravel(uv), [u, v], atol=1e-9)


# ---------------------------------------------------------------- OpenSim
def test_mot_round_trip_and_kinematics(tmp_path):
    from core.io.opensim import bone_kinematics_table, kinematics_to_poses, read_mot, write_mot

    P = _poses(6, 2)
    tab = bone_kinematics_table(["radius", "ulna"], P, np.arange(6) / 100)
    p = tmp_path / "k.mot"
    write_mot(p, tab)
    r = read_mot(p)
    assert r.labels == tab.labels and r.in_degrees
    np.testing.assert_allclose(r.data, tab.data, atol=1e-8)
    np.testing.assert_allclose(kinematics_to_poses(r, ["radius", "ulna"]), P, atol=1e-6)
    # a Storage file as OpenSim writes one (extra header lines, spaces)
    q = tmp_path / "os.mot"
    q.write_text("Coordinates\nversion=1\nnRows=2\nnColumns=3\ninDegrees=yes\n\nUnits are S.I. units\n"
                 "endheader\ntime\tpelvis_tilt\tpelvis_tx\n0.0\t1.5\t0.01\n0.01\t2.5\t0.02\n")
    m = read_mot(q)
    assert m.labels == ("pelvis_tilt", "pelvis_tx")
    np.testing.assert_allclose(m.data, [[1.5, 0.01], [2.5, 0.02]])


def test_trc_round_trip_and_published_layout(tmp_path):
    from core.io.opensim import MarkerTable, bone_markers, read_trc, write_trc

    P = _poses(5, 1)[:, 0]
    X = bone_markers(P, [[0, 0, 0], [10, 0, 0], [0, 10, 0]])
    X[2, 1] = np.nan
    p = tmp_path / "m.trc"
    write_trc(p, MarkerTable(("O", "X", "Y"), X, 250.0))
    r = read_trc(p)
    assert r.names == ("O", "X", "Y") and r.rate == 250.0 and r.units == "mm"
    np.testing.assert_allclose(r.xyz, X, atol=1e-7)
    q = tmp_path / "pub.trc"
    q.write_text("PathFileType\t4\t(X/Y/Z)\tpub.trc\n"
                 "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\t"
                 "OrigNumFrames\n60\t60\t2\t2\tmm\t60\t1\t2\nFrame#\tTime\tA\t\t\tB\nt\t\tX1\tY1\tZ1\tX2\tY2\tZ2\n"
                 "\n1\t0\t1\t2\t3\t4\t5\t6\n2\t0.016667\t1\t2\t3\t\t\t\n")
    t = read_trc(q)
    assert t.names == ("A", "B")
    np.testing.assert_allclose(t.xyz[0], [[1, 2, 3], [4, 5, 6]])
    assert np.isnan(t.xyz[1, 1]).all()


# ---------------------------------------------------------------- JCS CSV
def test_jcs_csv_round_trip(tmp_path):
    from core.io.jcs_csv import jcs_table, read_jcs_csv, write_jcs_csv
    from core.tracking.jcs import Joint, compose_jcs

    n = 4
    prox = _poses(n, 1)[:, 0]
    ang = np.array([[10, 5, -20], [20, 4, -15], [30, 3, -10], [40, 2, -5]], float)
    dist = np.stack([prox[i] @ compose_jcs(ang[i], (1, 2, 3), e1_axis="x", e3_axis="z") for i in range(n)])
    dist[3] = np.nan
    tab = jcs_table({"radius": prox, "ulna": dist}, [Joint("dru", "radius", "ulna")],
                    frames=np.arange(2, 2 + n), rate=100.0)
    np.testing.assert_allclose(tab.values[:3, 0, :3], ang[:3], atol=1e-8)
    np.testing.assert_allclose(tab.values[:3, 0, 3:], np.tile([1, 2, 3], (3, 1)), atol=1e-8)
    p = tmp_path / "jcs.csv"
    write_jcs_csv(p, tab)
    r = read_jcs_csv(p)
    assert r.joints == ("dru",) and list(r.frames) == [2, 3, 4, 5] and r.notes == tab.notes
    np.testing.assert_allclose(r.values, tab.values, atol=1e-7, equal_nan=True)


# ---------------------------------------------------------------- C3D
def test_c3d_round_trip(tmp_path):
    pytest.importorskip("ezc3d")
    from core.io.c3d import read_c3d, write_c3d

    P = _poses(5, 2)
    P[3, 0] = np.nan
    p = tmp_path / "trial.c3d"
    write_c3d(p, ["radius", "ulna"], P, rate=125.0)
    r = read_c3d(p)
    assert r.bones == ("radius", "ulna") and r.rate == 125.0 and r.units == "mm"
    np.testing.assert_allclose(r.poses, P, atol=1e-9, equal_nan=True)
    assert r.point_labels[:4] == ("radius_O", "radius_X", "radius_Y", "radius_Z")
    np.testing.assert_allclose(r.points[0, 1], (P[0, 0] @ [10, 0, 0, 1])[:3], atol=1e-3)
    assert not list(tmp_path.glob(".*"))  # no temporary left
    with pytest.raises(FileError, match=r"bad\.c3d"):
        (tmp_path / "bad.c3d").write_bytes(b"\x02P" + bytes(600))
        read_c3d(tmp_path / "bad.c3d")
