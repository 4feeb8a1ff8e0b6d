"""n-view triangulation (core.geometry.triangulate)."""

import numpy as np
import pytest

from core.geometry import Triangulation, triangulate


def _sse(P, X, uv):
    """Sum over views of squared reprojection errors of points X (N, 3); uv (V, N, 2)."""
    h = np.einsum("vij,nj->vni", P[:, :, :3], X) + P[:, None, :, 3]
    d = h[..., :2] / h[..., 2:] - uv
    return np.nansum(d**2, axis=(0, 2))


@pytest.mark.parametrize("method", ["linear", "optimal"])
def test_exact_without_noise(rig_iso, volume_points, method):
    rig, iso = rig_iso
    X = volume_points(np.random.default_rng(0), iso, 300)
    res = triangulate(rig, rig.project(X), method=method)
    assert isinstance(res, Triangulation) and res.method == method
    assert res.points.shape == (300, 3) and res.reprojection_error.shape == (300, 2)
    np.testing.assert_allclose(res.points, X, atol=1e-7)
    assert np.nanmax(res.reprojection_error) < 1e-6
    np.testing.assert_array_equal(res.n_views, 2)


def test_optimal_with_noise_is_no_worse_and_stationary(rig_iso, volume_points):
    rig, iso = rig_iso
    rng = np.random.default_rng(1)
    X = volume_points(rng, iso, 400)
    sigma = 0.5
    uv = rig.project(X) + rng.normal(0, sigma, (2, 400, 2))
    lin = triangulate(rig, uv, method="linear")
    opt = triangulate(rig, uv, method="optimal")
    P = np.stack([c.P for c in rig])
    sse_lin, sse_opt = _sse(P, lin.points, uv), _sse(P, opt.points, uv)
    assert np.all(sse_opt <= sse_lin * (1 + 1e-9) + 1e-12)
    assert sse_opt.sum() < sse_lin.sum()
    # a local minimum of the reprojection error: small moves never decrease it
    for step in (1e-3, -1e-3):
        for axis in range(3):
            moved = opt.points.copy()
            moved[:, axis] += step
            assert np.all(_sse(P, moved, uv) >= sse_opt - 1e-9)
    # sub-millimetre 3D accuracy for 0.5 px noise (pixels ~0.25 mm at the isocentre)
    err = np.linalg.norm(opt.points - X, axis=1)
    assert np.sqrt(np.mean(err**2)) < 0.5
    # 4 residuals - 3 unknowns per point: E[SSE] = sigma^2
    assert 0.7 * sigma**2 < sse_opt.mean() < 1.3 * sigma**2
    np.testing.assert_allclose(opt.rms_error, np.sqrt(sse_opt / 2), rtol=1e-9)


def test_three_views_with_missing_observations(make_rig, volume_points):
    rig, iso = make_rig(5, n_views=3)
    X = volume_points(np.random.default_rng(2), iso, 20)
    uv = rig.project(X)
    uv[2, :5] = np.nan  # points 0-4 not seen by the third camera
    uv[0, 5] = np.nan  # point 5 seen by one camera only
    uv[1, 5] = np.nan
    res = triangulate(rig, uv)
    np.testing.assert_array_equal(res.n_views[:7], [2, 2, 2, 2, 2, 1, 3])
    assert np.all(np.isnan(res.points[5]))
    assert np.all(np.isnan(res.reprojection_error[5]))
    keep = np.arange(20) != 5
    np.testing.assert_allclose(res.points[keep], X[keep], atol=1e-7)
    assert np.all(np.isnan(res.reprojection_error[:5, 2]))
    assert np.all(np.isfinite(res.reprojection_error[6:]))
    # min_views=3 keeps only fully observed points
    res3 = triangulate(rig, uv, min_views=3, method="linear")
    assert np.all(np.isnan(res3.points[:6])) and np.all(np.isfinite(res3.points[6:]))


def test_camera_inputs_and_leading_shape(rig_iso, volume_points):
    rig, iso = rig_iso
    X = volume_points(np.random.default_rng(3), iso, 12).reshape(3, 4, 3)
    uv = rig.project(X)  # (2, 3, 4, 2)
    P = np.stack([-3.0 * rig[0].P, 1e-3 * rig[1].P])  # any scale, negative included
    for cams in (rig, list(rig.cameras), P):
        res = triangulate(cams, uv)
        assert res.points.shape == (3, 4, 3)
        assert res.reprojection_error.shape == (3, 4, 2) and res.n_views.shape == (3, 4)
        np.testing.assert_allclose(res.points, X, atol=1e-7)
    single = triangulate(rig, uv[:, 0, 0])
    assert single.points.shape == (3,)
    np.testing.assert_allclose(single.points, X[0, 0], atol=1e-7)


def test_all_points_missing_gives_nan(rig_iso):
    rig, _ = rig_iso
    res = triangulate(rig, np.full((2, 3, 2), np.nan))
    assert np.all(np.isnan(res.points)) and np.all(res.n_views == 0)
    assert np.all(np.isnan(res.rms_error))


@pytest.mark.parametrize(
    ("uv_shape", "kwargs", "match"),
    [
        ((3, 5, 2), {}, r"uv: expected shape \(2, \.\.\., 2\)"),
        ((2, 5, 3), {}, r"uv: expected shape \(2, \.\.\., 2\)"),
        ((2, 5, 2), {"method": "midpoint"}, "method: expected"),
        ((2, 5, 2), {"min_views": 1}, "min_views: expected an integer >= 2"),
    ],
)
def test_rejects_bad_input(rig_iso, uv_shape, kwargs, match):
    rig, _ = rig_iso
    with pytest.raises(ValueError, match=match):
        triangulate(rig, np.zeros(uv_shape), **kwargs)


def test_rejects_bad_cameras_and_values(rig_iso):
    rig, _ = rig_iso
    uv = np.zeros((2, 4, 2))
    with pytest.raises(ValueError, match="cameras: expected at least 2 views"):
        triangulate([rig[0]], uv[:1])
    with pytest.raises(ValueError, match=r"cameras: expected a Rig.*\(V, 3, 4\)"):
        triangulate(np.zeros((2, 3, 3)), uv)
    bad = uv.copy()
    bad[0, 1, 0] = np.nan
    with pytest.raises(ValueError, match="uv: a point has one coordinate NaN"):
        triangulate(rig, bad)
    bad[0, 1, 0] = np.inf
    with pytest.raises(ValueError, match="uv: contains infinite values"):
        triangulate(rig, bad)
