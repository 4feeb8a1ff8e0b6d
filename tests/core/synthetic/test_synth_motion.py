"""Stance-phase trajectories: rigid, smooth, plausible, seeded."""

import numpy as np
import pytest

from core.synthetic.motion import pose_about_centroid, rotation_about, stance_trajectories
from core.synthetic.phantoms import BONE_NAMES, bone_centroid

STANCE_S = 0.6  # stance duration of a walking step, s


def _centroid_paths(T):
    return np.stack([T[b, :, :3, :3] @ bone_centroid(n) + T[b, :, :3, 3]
                     for b, n in enumerate(BONE_NAMES)])


def test_valid_rigid_transforms():
    T = stance_trajectories(40, seed=1)
    assert T.shape == (4, 40, 4, 4)
    R = T[..., :3, :3]
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    np.testing.assert_array_equal(T[..., 3, :], np.broadcast_to([0, 0, 0, 1.0], T[..., 3, :].shape))


def test_motion_is_smooth_with_bounded_acceleration():
    n = 301
    c = _centroid_paths(stance_trajectories(n, seed=2)) / 1000.0  # m
    dt = STANCE_S / (n - 1)
    vel = np.linalg.norm(np.diff(c, axis=1), axis=-1) / dt
    acc = np.linalg.norm(np.diff(c, 2, axis=1), axis=-1) / dt**2
    assert vel.max() < 2.0  # m/s
    assert acc.max() < 40.0  # m/s^2 (no impacts: C2-smooth profiles)
    # C2: halving the frame interval keeps the acceleration (second differences / dt^2) bounded
    c2 = _centroid_paths(stance_trajectories(2 * n - 1, seed=2)) / 1000.0
    acc2 = np.linalg.norm(np.diff(c2, 2, axis=1), axis=-1) / (dt / 2) ** 2
    assert acc2.max() < 1.2 * acc.max()
    # rotations are smooth too: angular speed below the ~200-400 deg/s of the shank at push-off
    T = stance_trajectories(n, seed=2)
    dR = np.einsum("bnji,bnjk->bnik", T[:, :-1, :3, :3], T[:, 1:, :3, :3])
    ang = np.arccos(np.clip((np.trace(dR, axis1=-2, axis2=-1) - 1) / 2, -1, 1))
    omega = np.degrees(ang) / dt
    assert omega.max() < 450.0
    assert np.abs(np.diff(omega, axis=1)).max() / dt < 1e4  # deg/s^2


def test_stance_kinematics_are_plausible():
    T = stance_trajectories(100, seed=0)
    c = _centroid_paths(T)
    tib = BONE_NAMES.index("tibia")
    fwd = c[tib, -1, 0] - c[tib, 0, 0]
    assert 30.0 < fwd < 100.0  # the tibia travels several cm forward over stance
    # tibia rotates forward (sagittal) by tens of degrees relative to the lab
    R0, R1 = T[tib, 0, :3, :3], T[tib, -1, :3, :3]
    axis0, axis1 = R0[:, 2], R1[:, 2]
    assert 15 < np.degrees(np.arccos(axis0 @ axis1)) < 60
    # talus and calcaneus move together: small relative rotation (subtalar joint)
    tal, cal = BONE_NAMES.index("talus"), BONE_NAMES.index("calcaneus")
    rel = np.einsum("nji,njk->nik", T[cal, :, :3, :3], T[tal, :, :3, :3])
    ang = np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    assert ang.max() < 12.0
    # the heel rises at the end of stance
    cal_z = c[cal, :, 2]
    assert cal_z[-1] - cal_z[40] > 20.0


def test_trajectory_determinism_and_options():
    a = stance_trajectories(12, seed=5)
    np.testing.assert_array_equal(a, stance_trajectories(12, seed=5))
    assert not np.allclose(a, stance_trajectories(12, seed=6))
    still = stance_trajectories(5, seed=0, jitter_deg=0, jitter_mm=0, phase=(0.3, 0.3))
    np.testing.assert_allclose(still, np.broadcast_to(still[:, :1], still.shape))
    sub = stance_trajectories(3, names=["talus"], seed=0)
    assert sub.shape == (1, 3, 4, 4)
    with pytest.raises(ValueError, match="names"):
        stance_trajectories(3, names=["femur"])
    with pytest.raises(ValueError, match="phase"):
        stance_trajectories(3, phase=(0.8, 0.2))


def test_pose_helpers():
    T = rotation_about([1.0, 2, 3], [0, 0, 1], np.pi / 2)
    np.testing.assert_allclose(T[:3, :3] @ [1.0, 2, 3] + T[:3, 3], [1, 2, 3])
    c = np.array([5.0, -2, 7])
    P = pose_about_centroid([0.1, -0.2, 0.3], [1.0, 2.0, 3.0], c)
    np.testing.assert_allclose(P[:3, :3] @ c + P[:3, 3], c + np.array([1.0, 2, 3]))
