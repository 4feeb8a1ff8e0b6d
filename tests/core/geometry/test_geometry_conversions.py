"""P <-> (K, R, t), DLT <-> P and linear DLT estimation (core.geometry.conversions)."""

import numpy as np
import pytest

from core.geometry import (
    P_from_dlt,
    camera_from_dlt,
    camera_from_P,
    compose_P,
    decompose_P,
    dlt_from_correspondences,
    dlt_from_P,
    make_K,
)


def _project_P(P, X):
    h = np.c_[X, np.ones(len(X))] @ P.T
    return h[:, :2] / h[:, 2:]


@pytest.mark.parametrize("scale", [1.0, 3.7e-4, -1.0, -250.0])
def test_P_KRt_P_round_trip(rig_iso, scale):
    rig, _ = rig_iso
    for cam in rig:
        K, R, t = decompose_P(scale * cam.P)
        np.testing.assert_allclose(K, cam.K, rtol=1e-10, atol=1e-8)
        np.testing.assert_allclose(R, cam.R, atol=1e-12)
        np.testing.assert_allclose(t, cam.t, rtol=1e-10, atol=1e-8)
        assert K[2, 2] == 1.0 and K[0, 0] > 0 and K[1, 1] > 0
        np.testing.assert_allclose(np.linalg.det(R), 1.0)
        np.testing.assert_allclose(compose_P(K, R, t), cam.P, rtol=1e-10, atol=1e-8)
        back = camera_from_P(scale * cam.P, cam.width, cam.height, pixel_size=cam.pixel_size)
        np.testing.assert_allclose(back.source, cam.source, atol=1e-7)
        assert back.sid == pytest.approx(cam.sid)


def test_decompose_recovers_skew_and_camera_from_P_drops_small_skew(rig_iso):
    cam = rig_iso[0][0]
    K = cam.K.copy()
    K[0, 1] = 0.8  # px
    P = compose_P(K, cam.R, cam.t)
    Kd, _, _ = decompose_P(P)
    assert Kd[0, 1] == pytest.approx(0.8)
    new, shift = camera_from_P(P, cam.width, cam.height, return_skew_shift=True)
    assert new.K[0, 1] == 0.0
    expected = 0.8 * max(cam.cv + 0.5, cam.height - 0.5 - cam.cv) / cam.fy
    assert shift == pytest.approx(expected)
    # the reported bound is the real worst-case displacement over the image
    X = cam.detector_point(np.array([[0.0, -0.5], [cam.width - 1.0, cam.height - 0.5]]))
    moved = np.abs(new.project(X) - _project_P(P, X)).max()
    assert moved == pytest.approx(expected, rel=1e-6)
    with pytest.raises(ValueError, match=r"P: the intrinsics have skew K\[0, 1\] = 0\.8"):
        camera_from_P(P, cam.width, cam.height, max_skew_px=0.01)


@pytest.mark.parametrize(
    ("P", "match"),
    [
        (np.hstack([np.ones((3, 3)), np.ones((3, 1))]), r"P: expected a finite projective camera"),
        (np.zeros((3, 4)), r"P: expected a finite projective camera"),
        (np.eye(3), r"P: expected shape \(3, 4\)"),
        (np.full((3, 4), np.nan), r"P: contains NaN"),
    ],
)
def test_decompose_rejects_bad_P(P, match):
    with pytest.raises(ValueError, match=match):
        decompose_P(P)


def test_camera_from_P_rejects_bad_options(rig_iso):
    cam = rig_iso[0][0]
    with pytest.raises(ValueError, match="max_skew_px"):
        camera_from_P(cam.P, 1024, 1024, max_skew_px=-1)
    with pytest.raises(ValueError, match="height: expected a positive integer"):
        camera_from_P(cam.P, 1024, 10.5)


def test_dlt_round_trip_talus(rig_iso, volume_points):
    rig, iso = rig_iso
    X = volume_points(np.random.default_rng(0), iso, 50)
    for cam in rig:
        L = dlt_from_P(cam.P)
        assert L.shape == (11,)
        # the DLT equations reproduce Talus pixels directly
        den = X @ L[8:11] + 1
        u = (X @ L[0:3] + L[3]) / den
        v = (X @ L[4:7] + L[7]) / den
        np.testing.assert_allclose(np.c_[u, v], cam.project(X), atol=1e-8)
        P = P_from_dlt(L)
        np.testing.assert_allclose(_project_P(P, X), cam.project(X), atol=1e-8)
        back = camera_from_dlt(L, cam.width, cam.height)
        np.testing.assert_allclose(back.K, cam.K, rtol=1e-9)
        np.testing.assert_allclose(back.R, cam.R, atol=1e-11)
        np.testing.assert_allclose(back.t, cam.t, rtol=1e-9, atol=1e-7)
        np.testing.assert_allclose(dlt_from_P(-2.0 * cam.P), L, rtol=1e-12, atol=1e-15)


def test_dlt_dltdv_convention_is_one_based_and_flipped(rig_iso, volume_points):
    rig, iso = rig_iso
    X = volume_points(np.random.default_rng(1), iso, 30)
    cam = rig[1]
    L = dlt_from_P(cam.P, convention="dltdv", height=cam.height)
    den = X @ L[8:11] + 1
    ud = (X @ L[0:3] + L[3]) / den
    vd = (X @ L[4:7] + L[7]) / den
    uv = cam.project(X)
    np.testing.assert_allclose(ud, uv[:, 0] + 1, atol=1e-8)
    np.testing.assert_allclose(vd, cam.height - uv[:, 1], atol=1e-8)
    P = P_from_dlt(L, convention="dltdv", height=cam.height)
    np.testing.assert_allclose(_project_P(P, X), uv, atol=1e-8)
    back = camera_from_dlt(L, cam.width, cam.height, convention="dltdv")
    np.testing.assert_allclose(back.R, cam.R, atol=1e-11)
    np.testing.assert_allclose(back.K, cam.K, rtol=1e-9)


def test_dlt_rejects_bad_input(rig_iso):
    cam = rig_iso[0][0]
    with pytest.raises(ValueError, match=r'height: required .* convention="dltdv"'):
        dlt_from_P(cam.P, convention="dltdv")
    with pytest.raises(ValueError, match="convention: expected"):
        dlt_from_P(cam.P, convention="opencv")
    with pytest.raises(ValueError, match=r"L: expected shape \(11,?\)"):
        P_from_dlt(np.ones(12))
    # lab origin in the source's principal plane: P[2, 3] = 0
    K = make_K(5000, 5000, 512, 512)
    P0 = compose_P(K, np.eye(3), [0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"P: P\[2, 3\] is ~0"):
        dlt_from_P(P0)


def test_dlt_from_correspondences_exact_without_noise(rig_iso, volume_points):
    rig, iso = rig_iso
    rng = np.random.default_rng(2)
    for cam in rig:
        X = volume_points(rng, iso, 8)
        fit = dlt_from_correspondences(X, cam.project(X))
        assert fit.rms_px < 1e-6
        np.testing.assert_allclose(fit.coefficients, dlt_from_P(cam.P), rtol=1e-6, atol=1e-9)
        back = camera_from_P(fit.P, cam.width, cam.height)
        np.testing.assert_allclose(back.source, cam.source, atol=1e-3)
        np.testing.assert_allclose(back.K, cam.K, rtol=1e-6)
        # P is scaled as K [R | t]: positive depth, K[2, 2] = 1
        np.testing.assert_allclose(fit.P, cam.P, rtol=1e-6, atol=1e-6 * np.abs(cam.P).max())


def test_dlt_from_correspondences_with_noise(rig_iso, volume_points):
    rig, iso = rig_iso
    rng = np.random.default_rng(3)
    cam = rig[0]
    X = volume_points(rng, iso, 200)
    sigma = 0.3
    uv = cam.project(X) + rng.normal(0, sigma, (200, 2))
    fit = dlt_from_correspondences(X, uv)
    assert fit.residuals.shape == (200,)
    # residuals are 2D distances: RMS ~ sqrt(2) sigma (11 parameters fitted to 400 numbers)
    assert 0.9 * np.sqrt(2) * sigma < fit.rms_px < 1.1 * np.sqrt(2) * sigma
    assert np.linalg.norm(camera_from_P(fit.P, 1024, 1024, max_skew_px=5).source - cam.source) < 20
    # dltdv-convention input gives the same camera
    uvd = np.c_[uv[:, 0] + 1, cam.height - uv[:, 1]]
    fit_d = dlt_from_correspondences(X, uvd, convention="dltdv", height=cam.height)
    np.testing.assert_allclose(fit_d.P, fit.P, rtol=1e-7, atol=1e-9 * np.abs(fit.P).max())
    np.testing.assert_allclose(
        fit_d.coefficients, dlt_from_P(fit.P, convention="dltdv", height=cam.height), rtol=1e-8
    )


def test_dlt_from_correspondences_rejects_degenerate_input(rig_iso, volume_points):
    rig, iso = rig_iso
    cam = rig[0]
    rng = np.random.default_rng(4)
    X = volume_points(rng, iso, 10)
    with pytest.raises(ValueError, match="X: expected at least 6 correspondences"):
        dlt_from_correspondences(X[:5], cam.project(X[:5]))
    flat = X.copy()
    flat[:, 2] = iso[2]
    with pytest.raises(ValueError, match="X: the points are coplanar"):
        dlt_from_correspondences(flat, cam.project(flat))
    with pytest.raises(ValueError, match="uv: expected 10 points"):
        dlt_from_correspondences(X, cam.project(X)[:9])
    with pytest.raises(ValueError, match=r"uv: expected shape \(N, 2\)"):
        dlt_from_correspondences(X, np.zeros((10, 3)))
    uv = cam.project(X)
    uv[3, 0] = np.nan
    with pytest.raises(ValueError, match="uv: contains NaN"):
        dlt_from_correspondences(X, uv)
