"""Rigid-rig bundle adjustment against ground truth from projected synthetic frames."""

import numpy as np
import pytest
import scipy.sparse

from core.calibration import _bundle_model as bm
from core.calibration.bundle import ObjectFrame, bundle_adjust
from core.calibration.objects import cube_target, spiral_target
from core.geometry.transforms import make_rigid
from core.synthetic.capture import capture_centre, capture_poses, observe


@pytest.fixture(scope="module")
def spiral():
    return spiral_target(23)


@pytest.fixture(scope="module")
def poses(rig, spiral):
    return capture_poses(rig, spiral, 12, rng=7, spread_mm=60)


def _errors(res, rig):
    f = max(abs(c.fx / t.fx - 1) for c, t in zip(res.rig, rig, strict=True))
    src = max(np.linalg.norm(c.source - t.source) for c, t in zip(res.rig, rig, strict=True))
    return f, src


def test_analytic_jacobian_matches_finite_differences(rig, spiral, poses, sizes):
    frames = observe(rig, spiral, poses[:3], noise_px=0.3, rng=0, drop=2)
    prob = bm.Problem(frames, sizes, "separate", [None, (510.0, 515.0)],
                       [(1300.0, 0.29, 5.0), None], 0.1, poses[:3, :3, :3].copy(),
                       np.stack([np.eye(3), rig[1].R @ rig[0].R.T]))
    g = np.random.default_rng(0)
    x = g.normal(0, 0.02, len(prob.names))
    x[: prob.rel0] += [4500, 4400, 505, 512, 5000, 4990][: prob.rel0]
    x[prob.rel0 + 3 : prob.rel0 + 6] += [300, -20, 40]
    x[prob.pose0 :].reshape(-1, 6)[:, 3:] += poses[:3, :3, 3] - rig[0].source @ rig[0].R.T
    J = prob.jacobian(x).toarray()
    r0 = prob.residuals(x)
    for i in range(len(x)):
        h = 1e-6 * max(1.0, abs(x[i]))
        xp = x.copy()
        xp[i] += h
        fd = (prob.residuals(xp) - r0) / h
        np.testing.assert_allclose(J[:, i], fd, rtol=1e-4, atol=1e-3 * max(1.0, np.abs(fd).max()),
                                   err_msg=prob.names[i])


def test_noise_free_frames_give_the_true_rig(rig, spiral, poses, sizes):
    frames = observe(rig, spiral, poses, noise_px=0.0, rng=0, drop=3)
    res = bundle_adjust(frames, sizes, T_lab_from_reference=poses[4], reference=4,
                        pixel_size=rig[0].pixel_size)
    assert res.ok, res.reason
    for c, t in zip(res.rig, rig, strict=True):
        np.testing.assert_allclose(c.K, t.K, rtol=1e-7, atol=1e-5)
        np.testing.assert_allclose(c.source, t.source, atol=1e-5)
        np.testing.assert_allclose(c.R, t.R, atol=1e-9)
    np.testing.assert_allclose(res.object_poses, poses, atol=1e-6)
    assert res.rms_px < 1e-6


def test_noisy_frames_sub_millimetre_rig_and_calibrated_uncertainty(rig, spiral, poses, sizes):
    frames = observe(rig, spiral, poses, noise_px=0.05, rng=1)
    res = bundle_adjust(frames, sizes, T_lab_from_reference=poses[0], pixel_size=rig[0].pixel_size,
                        pixel_sigma=0.05)
    assert res.ok, res.reason
    f_err, src_err = _errors(res, rig)
    assert f_err < 2e-3 and src_err < 1.5
    assert 0.85 < res.sigma0 < 1.15  # the residuals have the noise that was put in
    assert res.rms_px == pytest.approx(0.05 * np.sqrt(2), rel=0.15)
    for c, (s, t) in enumerate(zip(res.camera_std, rig, strict=True)):
        assert 0 < s["f"] < 20 and 0 < s["sid"] < 5 and np.all(s["source"] < 2)
        # the true value lies within 4 standard deviations
        assert abs(res.rig[c].fx - t.fx) < 4 * s["f"]
    v, s = res.parameter("cam1.f")
    assert v == pytest.approx(res.rig[0].fx) and s == pytest.approx(res.camera_std[0]["f"], rel=1e-3)
    assert len(res.residuals) == len(res.frame_index) == 12 * 2 * 23


def test_robust_loss_survives_mislabelled_beads(rig, spiral, poses, sizes):
    frames = observe(rig, spiral, poses, noise_px=0.05, rng=2)
    g = np.random.default_rng(3)
    for fr in frames[1:6]:  # 5 frames with a swapped pair of labels in view 2
        i, j = g.choice(23, 2, replace=False)
        fr.uv[1, [i, j]] = fr.uv[1, [j, i]]
    kw = {"T_lab_from_reference": poses[0], "pixel_size": rig[0].pixel_size, "pixel_sigma": 0.05}
    robust = bundle_adjust(frames, sizes, loss="soft_l1", **kw)
    plain = bundle_adjust(frames, sizes, loss="linear", max_rms_px=100, **kw)
    assert robust.ok
    assert _errors(robust, rig)[1] < 1.5
    assert _errors(plain, rig)[1] > 2 * _errors(robust, rig)[1]
    assert robust.outliers.sum() == 10  # the swapped beads stand out, nothing else
    assert set(robust.frame_index[robust.outliers]) == {1, 2, 3, 4, 5}
    assert set(robust.view[robust.outliers]) == {1}
    assert robust.rms_px < 0.1 < robust.rms_all_px


def test_priors_fixed_principal_point_and_a_static_cube_frame(rig, spiral, poses, sizes):
    cube = cube_target()
    T_cube = make_rigid(np.eye(3), capture_centre(rig) + np.array([0.0, 0.0, -20.0]))
    frames = [*observe(rig, cube, T_cube[None], noise_px=0.0, rng=0),
              *observe(rig, spiral, poses[:4], noise_px=0.05, rng=4)]
    pp = [(c.cu, c.cv) for c in rig]
    res = bundle_adjust(frames, sizes, reference=0, T_lab_from_reference=T_cube,
                        fixed_principal_point=pp, sid_prior=[(c.sid, 0.5) for c in rig],
                        pixel_size=rig[0].pixel_size, pixel_sigma=0.05, focal="separate")
    assert res.ok, res.reason
    assert not any(n.endswith((".cu", ".cv")) for n in res.parameter_names)
    assert "cam1.fy" in res.parameter_names
    for c, t in zip(res.rig, rig, strict=True):
        assert (c.cu, c.cv) == (t.cu, t.cv)
        assert abs(c.sid - t.sid) < 1.0  # the prior keeps the SID within ~its tolerance
    np.testing.assert_allclose(res.object_poses[0], T_cube, atol=1e-9)


def test_bad_input_gives_explicit_failures(rig, spiral, poses, sizes):
    frames = observe(rig, spiral, poses[:3], noise_px=0.05, rng=5)
    blind = [ObjectFrame(f.points, np.stack([f.uv[0], np.full_like(f.uv[1], np.nan)])) for f in frames]
    res = bundle_adjust(blind, sizes)
    assert not res.ok and "camera 2: no detections" in res.reason and res.rig is None
    few = [ObjectFrame(f.points[:5], f.uv[:, :5]) for f in frames]  # < 6 beads: no DLT
    res = bundle_adjust(few, sizes)
    assert not res.ok and "DLT initial guess" in res.reason
    # a frame with < 4 beads in every view is dropped, the rest is calibrated
    frames[1].uv[:, 3:] = np.nan
    res = bundle_adjust(frames, sizes, reference=0, T_lab_from_reference=poses[0])
    assert res.ok and "dropped" in res.message and np.isnan(res.object_poses[1]).all()
    res = bundle_adjust(frames, sizes, reference=1)
    assert not res.ok and "reference frame 1" in res.reason
    with pytest.raises(ValueError, match="sid_prior"):
        bundle_adjust(frames, sizes, sid_prior=[(1300, 1)], pixel_size=0.3)
    with pytest.raises(ValueError, match="pixel_size"):
        bundle_adjust(frames, sizes, sid_prior=[(1300, 1), None])
    with pytest.raises(ValueError, match="focal"):
        bundle_adjust(frames, sizes, focal="zoom")
    with pytest.raises(ValueError, match="uv"):
        ObjectFrame(np.zeros((3, 3)), np.zeros((2, 4, 2)))


def test_schur_covariance_equals_the_dense_inverse():
    g = np.random.default_rng(0)
    p0, F = 5, 4
    rows = []
    for f in range(F):  # each frame's residuals see the globals and its own 6 pose parameters
        blk = np.zeros((20, p0 + 6 * F))
        blk[:, :p0] = g.normal(size=(20, p0))
        blk[:, p0 + 6 * f : p0 + 6 * f + 6] = g.normal(size=(20, 6))
        rows.append(blk)
    J = np.vstack(rows)
    keep = np.r_[np.arange(p0), p0 + 6 * 2 + np.arange(6)]
    std, sub, s0 = bm.covariance(scipy.sparse.csr_matrix(J), 0.5 * 70.0, len(J), p0, keep)
    cov = np.linalg.inv(J.T @ J) * (70.0 / (len(J) - J.shape[1]))
    np.testing.assert_allclose(std, np.sqrt(np.diag(cov)), rtol=1e-8)
    np.testing.assert_allclose(sub, cov[np.ix_(keep, keep)], rtol=1e-7, atol=1e-12)
    assert s0 == pytest.approx(np.sqrt(70.0 / (len(J) - J.shape[1])))
    J[:, 1] = 0.0  # an unobservable global parameter: infinite variance, never a silent number
    std, _, _ = bm.covariance(scipy.sparse.csr_matrix(J), 1.0, len(J), p0, keep)
    assert np.isinf(std[1]) and np.isfinite(std[0])
