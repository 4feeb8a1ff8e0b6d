"""core.tracking.smoothing: the covariance-weighted RTS smoother of a bone's tracked poses."""

import numpy as np
import pytest

from core.geometry.transforms import params_from_pose, pose_from_params, rotvec_to_matrix
from core.tracking.results import FrameResult, TrackingResult
from core.tracking.smoothing import left_jacobian, smooth_poses, smooth_track

CENTER = np.array([5.0, -3.0, 40.0])


def _truth(n=80):
    """A smooth trajectory: the centroid on a curve, the rotation growing to ~25 degrees."""
    t = np.linspace(0.0, 1.0, n)
    p = np.c_[30 * t ** 2, 4 * np.sin(2 * t), -6 * t]
    rv = np.c_[0.4 * t, -0.15 * t ** 2, 0.1 * np.sin(3 * t)]
    base = np.eye(4)
    base[:3, 3] = -CENTER
    return pose_from_params(np.c_[p, rv], center=CENTER, base=base)


def _noisy(T, sigma, scale, seed=0):
    """``T`` with left perturbations of ``scale × sigma`` (mm, degrees), and those errors."""
    g = np.random.default_rng(seed)
    E = g.normal(size=(len(T), 6)) * sigma * scale
    P = np.array([pose_from_params(np.r_[e[:3], np.radians(e[3:])], center=CENTER, base=b)
                  for e, b in zip(E, T, strict=True)])
    return P, E


def _errors(P, T):
    e = np.array([params_from_pose(p, center=CENTER, base=b) for p, b in zip(P, T, strict=True)])
    return np.c_[e[:, :3], np.degrees(e[:, 3:])]


def test_left_jacobian_moves_the_rotation_vector():
    phi = np.array([0.3, -0.2, 0.25])
    d = np.array([1e-5, -2e-5, 1.5e-5])
    J = left_jacobian(phi)
    got = rotvec_to_matrix(phi + d)
    want = rotvec_to_matrix(J @ d) @ rotvec_to_matrix(phi)
    assert np.abs(got - want).max() < 1e-9
    assert np.allclose(left_jacobian(phi, inverse=True) @ J, np.eye(3), atol=1e-12)
    assert np.allclose(left_jacobian(np.zeros(3)), np.eye(3))


def test_smoother_beats_the_frames_and_finds_the_scale():
    T = _truth()
    sigma = np.tile([0.05, 0.04, 0.06, 0.2, 0.15, 0.1], (len(T), 1))
    P, E = _noisy(T, sigma, 0.3)
    sm = smooth_poses(P, sigma, center=CENTER, model="acceleration")
    Es = _errors(sm.poses, T)
    for sl in (slice(0, 3), slice(3, 6)):
        raw = np.sqrt(np.mean(np.sum(E[:, sl] ** 2, 1)))
        got = np.sqrt(np.mean(np.sum(Es[:, sl] ** 2, 1)))
        assert got < 0.6 * raw
    assert np.all(np.abs(sm.scale - 0.3) < 0.1)  # the σ given were 3x the errors: k finds it
    inside = np.mean(np.abs(Es) <= 2 * sm.sigma)
    assert 0.85 <= inside <= 1.0
    assert np.all(sm.weights > 0)


def test_flagged_frame_skipped_and_outlier_down_weighted():
    T = _truth()
    sigma = np.tile([0.05, 0.05, 0.05, 0.2, 0.2, 0.2], (len(T), 1))
    P, _ = _noisy(T, sigma, 0.5, seed=1)
    bad = P.copy()
    bad[40] = pose_from_params(np.r_[1.0, -1.0, 0.5, 0.02, 0.0, 0.0], center=CENTER, base=T[40])
    sk = smooth_poses(bad, sigma, center=CENTER, flagged=np.arange(len(T)) == 40, flagged_weight=0.0)
    assert sk.weights[40] == 0
    assert np.linalg.norm(_errors(sk.poses, T)[40, :3]) < 0.1
    rb = smooth_poses(bad, sigma, center=CENTER, model="acceleration", robust=2.5, outliers=None)
    assert rb.weights[40] < 0.05 and rb.outliers == []
    assert np.linalg.norm(_errors(rb.poses, T)[40, :3]) < 0.1
    out = smooth_poses(bad, sigma, center=CENTER, model="acceleration", robust=None)
    assert out.outliers == [40] and out.weights[40] < 0.05  # taken for an outlier: its variance multiplied
    assert np.linalg.norm(_errors(out.poses, T)[40, :3]) < 0.1
    plain = smooth_poses(bad, sigma, center=CENTER, model="acceleration", robust=None, outliers=None)
    assert np.linalg.norm(_errors(plain.poses, T)[40, :3]) > np.linalg.norm(_errors(rb.poses, T)[40, :3])


def test_a_real_jerk_lets_a_burst_in():
    """A fast step in the truth (2 mm within ~3 frames): the likelihood lets a burst of process noise
    in there, and the smoothed poses follow the step far better than without."""
    T = _truth()
    n = len(T)
    step = np.clip((np.arange(n) - 40) / 3.0, 0.0, 1.0)[:, None] * np.r_[2.0, -2.0, 1.0, 0.0, 0.0, 0.0]
    Tj = np.array([pose_from_params(d, center=CENTER, base=b) for d, b in zip(step, T, strict=True)])
    sigma = np.tile([0.05, 0.05, 0.05, 0.2, 0.2, 0.2], (n, 1))
    P, E = _noisy(Tj, sigma, 0.5, seed=4)
    on = smooth_poses(P, sigma, center=CENTER)
    off = smooth_poses(P, sigma, center=CENTER, transients=None)
    assert on.bursts and min(abs(t - 41) for t in on.bursts) <= 2 and not off.bursts
    win = slice(36, 48)
    e_on = np.linalg.norm(_errors(on.poses, Tj)[win, :3], axis=1)
    e_off = np.linalg.norm(_errors(off.poses, Tj)[win, :3], axis=1)
    assert e_on.max() < 0.5 * e_off.max()
    assert np.sqrt(np.mean(e_on ** 2)) < 1.5 * np.sqrt(np.mean(np.sum(E[win, :3] ** 2, 1)))
    plain = smooth_poses(_noisy(T, sigma, 0.5, seed=4)[0], sigma, center=CENTER)
    assert plain.bursts == []


def test_missing_frames_get_their_neighbours_pose():
    T = _truth()
    sigma = np.tile([0.05, 0.05, 0.05, 0.2, 0.2, 0.2], (len(T), 1))
    P, _ = _noisy(T, sigma, 0.5, seed=2)
    P[30:33] = np.nan
    sigma = sigma.copy()
    sigma[50] = np.nan  # no σ: the coordinate's median
    sm = smooth_poses(P, sigma, center=CENTER, model="velocity", weigh="equal")
    assert np.all(np.isfinite(sm.poses[30:33]))
    assert np.all(sm.weights[30:33] == 0)
    grows = np.r_[0, 1, 3, 4, 5]  # (z is a straight line, -6 t: its fit is global, the gap hardly shows)
    assert np.all(sm.sigma[31, grows] > sm.sigma[20, grows]) and sm.sigma[31, 2] > 0.99 * sm.sigma[20, 2]
    assert np.linalg.norm(_errors(sm.poses, T)[31, :3]) < 0.15
    d = sm.to_dict()
    assert len(d["poses"]) == len(T) and d["model"] == "velocity"


def test_smooth_track_reads_sigma_and_flags():
    T = _truth(30)
    sigma = np.tile([0.05, 0.05, 0.05, 0.2, 0.2, 0.2], (len(T), 1))
    P, _ = _noisy(T, sigma, 0.5, seed=3)
    res = {("b", f): FrameResult("b", f, P[f], 0.5, 10, 0.0, True, ("x",) if f == 7 else (),
                                 confidence={"sigma": sigma[f].tolist()}) for f in range(len(T))}
    tr = TrackingResult(("b",), tuple(range(len(T))), res, "complete", 0.0)
    sm = smooth_track(tr, "b", center=CENTER, flagged_weight=0.0)
    assert sm.weights[7] == 0 and sm.poses.shape == (len(T), 4, 4)
    direct = smooth_poses(P, sigma, center=CENTER, flagged=np.arange(len(T)) == 7, flagged_weight=0.0)
    assert np.allclose(sm.poses, direct.poses)


def test_arguments_checked():
    T = _truth(20)
    s = np.ones((20, 6))
    with pytest.raises(ValueError, match="sigma"):
        smooth_poses(T, s[:5], center=CENTER)
    with pytest.raises(ValueError, match="model"):
        smooth_poses(T, s, center=CENTER, model="spline")
    with pytest.raises(ValueError, match="flagged_weight"):
        smooth_poses(T, s, center=CENTER, flagged_weight=2.0)
    with pytest.raises(ValueError, match="measured"):
        smooth_poses(T, s, center=CENTER, flagged=np.ones(20, bool), flagged_weight=0.0)
