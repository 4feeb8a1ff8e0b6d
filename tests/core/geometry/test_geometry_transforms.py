"""Rigid transforms, rotation parametrisations and pose parameters (core.geometry.transforms)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from core.geometry import (
    apply_rigid,
    compose_rigid,
    euler_to_matrix,
    invert_rigid,
    make_rigid,
    matrix_to_euler,
    matrix_to_quat,
    matrix_to_rotvec,
    params_from_pose,
    pose_from_params,
    quat_to_matrix,
    random_perturbation,
    rotvec_to_matrix,
)


def _random_rigid(rng, *lead):
    n = int(np.prod(lead)) if lead else 1
    R = Rotation.random(n, random_state=rng).as_matrix().reshape(*lead, 3, 3)
    t = rng.uniform(-200, 200, (*lead, 3))
    return make_rigid(R, t)


def test_make_invert_compose_apply():
    rng = np.random.default_rng(0)
    A, B = _random_rigid(rng, 5), _random_rigid(rng, 5)
    X = rng.uniform(-100, 100, (5, 3))
    np.testing.assert_allclose(
        apply_rigid(compose_rigid(A, B), X), apply_rigid(A, apply_rigid(B, X)), atol=1e-9
    )
    np.testing.assert_allclose(
        compose_rigid(A, invert_rigid(A)), np.broadcast_to(np.eye(4), A.shape), atol=1e-12
    )
    np.testing.assert_allclose(apply_rigid(invert_rigid(A), apply_rigid(A, X)), X, atol=1e-9)
    # a single transform broadcasts over points; T[:, None] gives every transform x every point
    assert apply_rigid(A[0], X).shape == (5, 3)
    assert apply_rigid(A[:, None], X[None, :4]).shape == (5, 4, 3)
    assert compose_rigid(A[0], B).shape == (5, 4, 4)
    T = make_rigid(t=[1.0, 2.0, 3.0])
    np.testing.assert_array_equal(T[:3, :3], np.eye(3))
    np.testing.assert_array_equal(apply_rigid(T, np.zeros(3)), [1.0, 2.0, 3.0])
    assert make_rigid(np.eye(3), np.zeros((4, 3))).shape == (4, 4, 4)


def test_rigid_helpers_reject_bad_input():
    with pytest.raises(ValueError, match="R: expected orthonormal"):
        make_rigid(np.diag([1.0, 2.0, 1.0]))
    with pytest.raises(ValueError, match="R: expected proper rotations"):
        make_rigid(np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match=r"t: expected shape \(\.\.\., 3\)"):
        make_rigid(np.eye(3), [1.0, 2.0])
    bad = np.eye(4)
    bad[3, 0] = 1.0
    with pytest.raises(ValueError, match=r"T: expected last row \(0, 0, 0, 1\)"):
        invert_rigid(bad)
    with pytest.raises(ValueError, match=r"T: expected shape \(\.\.\., 4, 4\)"):
        apply_rigid(np.eye(3), np.zeros(3))
    with pytest.raises(ValueError, match="X: contains NaN"):
        apply_rigid(np.eye(4), [np.nan, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"transforms\[1\]"):
        compose_rigid(np.eye(4), 2 * np.eye(4))
    with pytest.raises(ValueError, match="transforms: expected at least one"):
        compose_rigid()


def test_rotation_parametrisations_round_trip():
    rng = np.random.default_rng(1)
    R = Rotation.random(12, random_state=rng).as_matrix().reshape(3, 4, 3, 3)
    rv = matrix_to_rotvec(R)
    assert rv.shape == (3, 4, 3)
    assert np.linalg.norm(rv, axis=-1).max() <= np.pi
    np.testing.assert_allclose(rotvec_to_matrix(rv), R, atol=1e-12)
    q_last = matrix_to_quat(R)
    q_first = matrix_to_quat(R, scalar_first=True)
    np.testing.assert_allclose(q_first, np.roll(q_last, 1, axis=-1))
    assert np.all(q_last[..., 3] >= 0)
    np.testing.assert_allclose(quat_to_matrix(q_last), R, atol=1e-12)
    np.testing.assert_allclose(quat_to_matrix(5.0 * q_first, scalar_first=True), R, atol=1e-12)
    for seq in ("xyz", "ZYX", "zxz", "YXY"):
        ang = matrix_to_euler(R, seq)
        np.testing.assert_allclose(euler_to_matrix(ang, seq), R, atol=1e-12)


def test_rotation_conventions_explicit():
    quarter = np.pi / 2
    Rz = rotvec_to_matrix([0.0, 0.0, quarter])
    np.testing.assert_allclose(Rz @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-15)  # right-handed
    np.testing.assert_allclose(matrix_to_quat(np.eye(3)), [0, 0, 0, 1])  # scalar last
    np.testing.assert_allclose(matrix_to_quat(np.eye(3), scalar_first=True), [1, 0, 0, 0])
    a = np.array([0.3, -0.2, 0.7])
    # extrinsic "xyz" = Rz Ry Rx = intrinsic "ZYX" with reversed angles
    Rx, Ry, Rzz = (rotvec_to_matrix(np.eye(3)[i] * a[i]) for i in range(3))
    np.testing.assert_allclose(euler_to_matrix(a, "xyz"), Rzz @ Ry @ Rx, atol=1e-15)
    np.testing.assert_allclose(euler_to_matrix(a[::-1], "ZYX"), Rzz @ Ry @ Rx, atol=1e-15)
    np.testing.assert_allclose(euler_to_matrix(a, "XYZ"), Rx @ Ry @ Rzz, atol=1e-15)


def test_rotation_helpers_reject_bad_input():
    with pytest.raises(ValueError, match="seq: expected 3 axis letters"):
        euler_to_matrix([0.0, 0.0, 0.0], "xYz")
    with pytest.raises(ValueError, match="seq: expected 3 axis letters"):
        euler_to_matrix([0.0, 0.0, 0.0], "xxz")
    with pytest.raises(ValueError, match=r"angles: expected shape \(\.\.\., 3\)"):
        euler_to_matrix([0.0, 0.0], "xyz")
    with pytest.raises(ValueError, match="q: expected non-zero quaternions"):
        quat_to_matrix(np.zeros(4))
    with pytest.raises(ValueError, match="rotvec: contains NaN"):
        rotvec_to_matrix([np.nan, 0.0, 0.0])
    with pytest.raises(ValueError, match="R: expected orthonormal"):
        matrix_to_rotvec(np.ones((3, 3)))


def test_pose_params_rotate_about_the_centre():
    rng = np.random.default_rng(2)
    base = _random_rigid(rng)
    center = np.array([10.0, -20.0, 35.0])  # bone centroid, bone coordinates
    np.testing.assert_allclose(pose_from_params(np.zeros(6), center=center, base=base), base)
    p = np.array([1.0, -2.0, 3.0, 0.1, -0.05, 0.2])
    T = pose_from_params(p, center=center, base=base)
    c_lab = apply_rigid(base, center)
    # the centre moves by exactly the translation, whatever the rotation
    np.testing.assert_allclose(apply_rigid(T, center), c_lab + p[:3], atol=1e-10)
    # every bone point turns about the centre by the lab rotation vector
    Y = rng.uniform(-50, 50, (10, 3))
    Rd = rotvec_to_matrix(p[3:])
    expected = (apply_rigid(base, Y) - c_lab) @ Rd.T + c_lab + p[:3]
    np.testing.assert_allclose(apply_rigid(T, Y), expected, atol=1e-10)
    # pure rotation keeps the centre fixed
    T_rot = pose_from_params(np.r_[0, 0, 0, p[3:]], center=center, base=base)
    np.testing.assert_allclose(apply_rigid(T_rot, center), c_lab, atol=1e-10)


def test_pose_params_round_trip_vectorised():
    rng = np.random.default_rng(3)
    base = _random_rigid(rng)
    center = np.array([5.0, 5.0, -40.0])
    p = random_perturbation(rng, 24, trans_mm=10.0, rot_rad=0.5).reshape(4, 6, 6)
    T = pose_from_params(p, center=center, base=base)
    assert T.shape == (4, 6, 4, 4)
    np.testing.assert_allclose(params_from_pose(T, center=center, base=base), p, atol=1e-10)
    # one base per pose, default identity base
    bases = _random_rigid(rng, 4, 6)
    T2 = pose_from_params(p, center=center, base=bases)
    np.testing.assert_allclose(params_from_pose(T2, center=center, base=bases), p, atol=1e-10)
    np.testing.assert_allclose(
        params_from_pose(pose_from_params(p, center=center), center=center), p, atol=1e-10
    )


def test_pose_params_reject_bad_input():
    with pytest.raises(ValueError, match=r"params: expected shape \(\.\.\., 6\)"):
        pose_from_params(np.zeros(5), center=np.zeros(3))
    with pytest.raises(ValueError, match=r"center: expected shape \(\.\.\., 3\)"):
        pose_from_params(np.zeros(6), center=np.zeros(2))
    with pytest.raises(ValueError, match="base"):
        pose_from_params(np.zeros(6), center=np.zeros(3), base=2 * np.eye(4))
    with pytest.raises(ValueError, match="params: contains NaN"):
        pose_from_params(np.full(6, np.nan), center=np.zeros(3))


def test_random_perturbation():
    p = random_perturbation(np.random.default_rng(4), 500, trans_mm=5.0, rot_rad=0.2)
    assert p.shape == (500, 6)
    tn, rn = np.linalg.norm(p[:, :3], axis=1), np.linalg.norm(p[:, 3:], axis=1)
    assert tn.max() <= 5.0 and rn.max() <= 0.2
    # uniform in the ball: P(|t| < r/2) = 1/8
    assert 0.07 < np.mean(tn < 2.5) < 0.18
    assert np.abs(p[:, :3].mean(axis=0)).max() < 0.5  # no preferred direction
    s = random_perturbation(7, 50, trans_mm=2.0, rot_rad=0.1, distribution="sphere")
    np.testing.assert_allclose(np.linalg.norm(s[:, :3], axis=1), 2.0)
    np.testing.assert_allclose(np.linalg.norm(s[:, 3:], axis=1), 0.1)
    np.testing.assert_array_equal(
        s, random_perturbation(7, 50, trans_mm=2.0, rot_rad=0.1, distribution="sphere")
    )
    assert random_perturbation(0, 0, trans_mm=1.0, rot_rad=0.1).shape == (0, 6)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"n": -1}, "n: expected a non-negative integer"),
        ({"n": 2.5}, "n: expected a non-negative integer"),
        ({"trans_mm": -1.0}, "trans_mm: expected a finite number >= 0"),
        ({"rot_rad": 4.0}, r"rot_rad: expected an angle in \[0, pi\]"),
        ({"rot_rad": np.nan}, r"rot_rad: expected an angle in \[0, pi\]"),
        ({"distribution": "normal"}, "distribution: expected"),
    ],
)
def test_random_perturbation_rejects_bad_input(kwargs, match):
    args = {"n": 3, "trans_mm": 1.0, "rot_rad": 0.1} | kwargs
    n = args.pop("n")
    with pytest.raises(ValueError, match=match):
        random_perturbation(0, n, **args)
