import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from core.tracking import kinematics as K
from core.tracking.bones import marching_tetrahedra


def _pose(R, t):
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def test_butterworth_zero_phase_and_cutoff():
    fs = 250.0
    t = np.arange(500) / fs
    slow = np.sin(2 * np.pi * 2 * t)
    x = slow + 0.3 * np.sin(2 * np.pi * 60 * t)
    y = K.butterworth(x, fs, 10.0)
    assert np.abs(y - slow)[50:-50].max() < 0.02  # no lag, the 60 Hz part removed
    # the combined (two-pass) response is -3 dB at the cutoff
    s = np.sin(2 * np.pi * 10 * t)
    ys = K.butterworth(s, fs, 10.0)
    assert np.std(ys[100:-100]) / np.std(s[100:-100]) == pytest.approx(2**-0.5, abs=0.03)
    x2 = x.copy()
    x2[100] = np.nan
    y2 = K.butterworth(x2, fs, 10.0)
    assert np.isnan(y2[100]) and np.isfinite(y2[99])
    with pytest.raises(ValueError, match="cutoff"):
        K.butterworth(x, fs, 200.0)


def test_residual_cutoff_finds_the_signal_band():
    fs = 200.0
    g = np.random.default_rng(0)
    t = np.arange(800) / fs
    x = np.sin(2 * np.pi * 3 * t) + 0.5 * np.sin(2 * np.pi * 5 * t) + 0.02 * g.normal(size=t.size)
    fc, res = K.residual_cutoff(x, fs)
    assert 4 < fc < 20 and res.shape == (40,)


def test_filter_poses_keeps_a_smooth_motion():
    fs, n = 100.0, 200
    ang = np.linspace(0, 0.6, n)
    P = np.stack([_pose(Rotation.from_rotvec([0, 0, a]).as_matrix(), [a * 10, 0, 0]) for a in ang])
    g = np.random.default_rng(1)
    noisy = P.copy()
    noisy[:, :3, 3] += 0.05 * g.normal(size=(n, 3))
    c = np.array([5.0, 0, 0])
    F = K.filter_poses(noisy, fs, 6.0, center=c)
    err = np.linalg.norm((F[:, :3, :3] @ c + F[:, :3, 3]) - (P[:, :3, :3] @ c + P[:, :3, 3]), axis=1)
    raw = np.linalg.norm(noisy[:, :3, 3] - P[:, :3, 3], axis=1)
    assert np.median(err) < 0.5 * np.median(raw)
    RRt = F[:, :3, :3] @ np.swapaxes(F[:, :3, :3], 1, 2)
    np.testing.assert_allclose(RRt, np.broadcast_to(np.eye(3), (n, 3, 3)), atol=1e-9)


def test_joint_angles_grood_suntay():
    a, b, c = 0.3, -0.15, 0.2
    prox = _pose(Rotation.from_euler("xyz", [0.1, 0.2, 0.3]).as_matrix(), [10, 20, 30])
    rel = _pose(Rotation.from_euler("ZXY", [a, b, c]).as_matrix(), [1.0, 2.0, 3.0])
    dist = prox @ rel
    out = K.joint_angles(prox[None], dist[None])
    assert out["sequence"] == "ZXY"
    np.testing.assert_allclose(out["angles"][0], [a, b, c], atol=1e-12)
    # translations: components of the origin displacement along e1, e2, e3
    e1, e3 = prox[:3, 2], dist[:3, 1]
    e2 = np.cross(e3, e1) / np.linalg.norm(np.cross(e3, e1))
    q = out["translations"][0]
    np.testing.assert_allclose(q[0] * e1 + q[1] * e2 + q[2] * e3, dist[:3, 3] - prox[:3, 3], atol=1e-9)
    # the floating axis is perpendicular to e1 and e3, and "abduction" is the angle between them - 90°
    assert np.degrees(np.arccos(e1 @ e3)) == pytest.approx(90 - np.degrees(b), abs=1e-9)
    with pytest.raises(ValueError, match="e1_axis"):
        K.joint_angles(prox[None], dist[None], e1_axis="z", e3_axis="z")


def test_anatomical_frames():
    g = np.random.default_rng(2)
    X = g.normal(size=(4000, 3)) * [3.0, 20.0, 8.0] + [1, 2, 3]
    T = K.principal_axes_frame(X, long_axis="z")
    np.testing.assert_allclose(T[:3, 3], [1, 2, 3], atol=1.0)
    assert abs(T[:3, 2] @ [0, 1, 0]) > 0.99  # longest extent (y) is the frame's z
    assert abs(T[:3, 0] @ [0, 0, 1]) > 0.99  # then 8 (z) on x, 3 (x) on y
    assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)
    F = K.frame_from_axes([0, 0, 0], [2, 0, 0], [1, 1, 0])
    np.testing.assert_allclose(F[:3, :3], np.eye(3), atol=1e-12)
    with pytest.raises(ValueError, match="x_axis"):
        K.frame_from_axes([0, 0, 0], [1, 0, 0], [2, 0, 0])


def test_helical_axis_of_a_screw_motion():
    n = np.array([1.0, 2.0, 2.0]) / 3.0
    p = np.array([10.0, -5.0, 0.0])
    p = p - (p @ n) * n
    th, s = 0.4, 1.5
    R = Rotation.from_rotvec(n * th).as_matrix()
    screw = _pose(R, p - R @ p + s * n)
    A = _pose(Rotation.from_euler("xyz", [0.2, 0.1, -0.3]).as_matrix(), [3, 4, 5])
    h = K.helical_axes(np.stack([A, screw @ A]))
    np.testing.assert_allclose(h["axis"][0], n, atol=1e-9)
    assert h["angle"][0] == pytest.approx(th) and h["translation"][0] == pytest.approx(s)
    np.testing.assert_allclose(h["point"][0], p, atol=1e-9)
    rel = K.helical_axes(np.stack([np.eye(4)] * 2), np.stack([A, screw @ A]))
    assert rel["angle"][0] == pytest.approx(th)


def test_min_distance_between_two_spheres():
    k, j, i = np.mgrid[0:24, 0:24, 0:24]
    v, f = marching_tetrahedra(8.0 - np.sqrt((i - 11.5) ** 2 + (j - 11.5) ** 2 + (k - 11.5) ** 2))
    v = v - 11.5
    I = np.eye(4)
    B = np.eye(4)
    B[:3, 3] = [16.0 + 3.0, 0.0, 0.0]
    out = K.min_distance((v, f), (v, f), I[None], B[None])
    assert out["distance"][0] == pytest.approx(3.0, abs=0.1)
    assert out["point_a"][0][0] == pytest.approx(8.0, abs=0.1)
    nan = np.full((4, 4), np.nan)
    assert np.isnan(K.min_distance((v, f), (v, f), nan[None], B[None])["distance"][0])


def test_exports(tmp_path):
    from core.io.autoscoper import read_tra

    P = np.stack([_pose(Rotation.from_rotvec([0, 0, 0.1 * k]).as_matrix(), [k, 2 * k, 0]) for k in range(3)])
    Q = P.copy()
    Q[1] = np.nan
    poses = {"talus": P, "tibia": Q}
    K.export_csv(tmp_path / "m.csv", poses)
    K.export_csv(tmp_path / "d.csv", poses, layout="6dof")
    rows = (tmp_path / "d.csv").read_text().splitlines()
    assert rows[0].startswith("frame,talus_tx_mm") and rows[2].endswith(",,,,,,")
    assert float(rows[3].split(",")[6]) == pytest.approx(np.degrees(0.2))
    m = np.loadtxt(tmp_path / "m.csv", delimiter=",", skiprows=1, max_rows=1)
    np.testing.assert_allclose(m[1:17], P[0].ravel())
    K.export_tra(tmp_path / "a.tra", poses)
    back = read_tra(tmp_path / "a.tra")
    np.testing.assert_allclose(np.asarray(back.poses if hasattr(back, "poses") else back)[:, 0], P, atol=1e-6)
    K.export_json(tmp_path / "a.json", poses, scores={"talus": np.array([0.9, np.nan, 0.8])})
    doc = json.loads((tmp_path / "a.json").read_text())
    assert doc["bones"]["tibia"]["poses"][1] is None and doc["bones"]["talus"]["scores"][1] is None
    with pytest.raises(ValueError, match="layout"):
        K.export_csv(tmp_path / "x.csv", poses, layout="quaternion")
