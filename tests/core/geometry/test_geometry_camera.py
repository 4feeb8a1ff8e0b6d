"""Camera / Rig (core.geometry.camera): projection, rays, detector geometry, validation."""

import numpy as np
import pytest

from core.geometry import Camera, Rig, make_K


def _line_distance(origin, directions, X):
    v = X - origin
    return np.linalg.norm(v - (v * directions).sum(-1, keepdims=True) * directions, axis=-1)


def test_ray_through_projection_passes_through_point(rig_iso, volume_points):
    rig, iso = rig_iso
    X = volume_points(np.random.default_rng(3), iso, 200)
    for cam in rig:
        uv, depth = cam.project(X, return_depth=True)
        assert np.all(depth > 1000)  # in front of the source, ~1.3-1.5 m away
        origin, d = cam.rays(uv)
        np.testing.assert_allclose(origin, cam.source)
        np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, atol=1e-12)
        assert np.all((d * (X - origin)).sum(-1) > 0)  # pointing from the source to the point
        assert _line_distance(origin, d, X).max() < 1e-9


def test_principal_ray_hits_principal_point(rig_iso):
    rig, _ = rig_iso
    for cam in rig:
        X = cam.source + 700.0 * cam.principal_ray
        np.testing.assert_allclose(cam.project(X), [cam.cu, cam.cv], atol=1e-9)
        np.testing.assert_allclose(cam.principal_ray, cam.rays([cam.cu, cam.cv])[1], atol=1e-12)


def test_pixel_convention_u_is_column_v_is_row(look_at):
    cam = look_at(np.array([0.0, 0.0, -1000.0]), [0, 0, 0], roll=0.0, fx=5000, fy=5000, cu=10, cv=20)
    grid = cam.pixel_grid()
    assert grid.shape == (1024, 1024, 2)
    np.testing.assert_array_equal(grid[3, 7], [7, 3])  # [row, col] -> (u=col, v=row)
    # camera x-axis moves u, camera y-axis moves v (v grows downwards along R[1])
    X0 = cam.source + 1000 * cam.principal_ray
    du = cam.project(X0 + cam.R[0]) - cam.project(X0)
    dv = cam.project(X0 + cam.R[1]) - cam.project(X0)
    assert du[0] > 0 and abs(du[1]) < 1e-9
    assert dv[1] > 0 and abs(dv[0]) < 1e-9


def test_detector_corners_geometry(rig_iso):
    rig, _ = rig_iso
    for cam in rig:
        corners = cam.detector_corners()
        # on the detector plane, SID from the source along the principal ray
        np.testing.assert_allclose((corners - cam.source) @ cam.principal_ray, cam.sid)
        tl, tr, br, bl = corners
        np.testing.assert_allclose(np.linalg.norm(tr - tl), cam.width * cam.pixel_size)
        np.testing.assert_allclose(np.linalg.norm(bl - tl), cam.height * cam.pixel_size * cam.fx / cam.fy)
        np.testing.assert_allclose((tr - tl) @ (bl - tl), 0.0, atol=1e-6)  # a rectangle
        np.testing.assert_allclose(br - tr, bl - tl, atol=1e-9)
        # corners project to the outer pixel edges, half a pixel beyond the centres
        w, h = cam.width, cam.height
        np.testing.assert_allclose(
            cam.project(corners),
            [[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]],
            atol=1e-7,
        )
        point, normal = cam.detector_plane()
        np.testing.assert_allclose(normal, cam.principal_ray)
        np.testing.assert_allclose((corners - point) @ normal, 0.0, atol=1e-6)


def test_detector_point_round_trip(rig_iso):
    rig, _ = rig_iso
    uv = np.random.default_rng(0).uniform(0, 1023, (5, 4, 2))
    for cam in rig:
        P = cam.detector_point(uv)
        assert P.shape == (5, 4, 3)
        np.testing.assert_allclose(cam.project(P), uv, atol=1e-8)
        np.testing.assert_allclose(
            cam.detector_point(uv, distance=500.0), cam.source + 500.0 / cam.sid * (P - cam.source)
        )


def test_P_matches_project(rig_iso, volume_points):
    rig, iso = rig_iso
    X = volume_points(np.random.default_rng(1), iso, 10)
    for cam in rig:
        h = np.c_[X, np.ones(len(X))] @ cam.P.T
        np.testing.assert_allclose(h[:, :2] / h[:, 2:], cam.project(X), atol=1e-9)
        T = cam.T_cam_from_lab
        np.testing.assert_allclose(T[:3, :3] @ cam.source + T[:3, 3], 0.0, atol=1e-9)


def test_rig_project_and_angle(rig_iso, volume_points):
    rig, iso = rig_iso
    X = volume_points(np.random.default_rng(2), iso, 12).reshape(3, 4, 3)
    uv = rig.project(X)
    assert uv.shape == (2, 3, 4, 2)
    np.testing.assert_allclose(uv[1], rig[1].project(X))
    assert np.radians(60) <= rig.angle_between_views() <= np.radians(120)
    assert len(rig) == 2 and list(rig) == list(rig.cameras)


def test_sid_requires_pixel_size():
    cam = Camera(make_K(5000, 5000, 512, 512), np.eye(3), [0, 0, 1000], 1024, 1024)
    with pytest.raises(ValueError, match="pixel_size"):
        _ = cam.sid


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"R": np.diag([1.0, 1.0, 1.1])}, r"R: expected an orthonormal"),
        ({"R": np.diag([1.0, 1.0, -1.0])}, r"R: expected a proper rotation"),
        ({"R": np.eye(4)}, r"R: expected shape \(3, 3\)"),
        ({"K": make_K(0.0, 5000, 512, 512)}, r"K: expected positive focal lengths"),
        ({"K": np.zeros((3, 3))}, r"K: expected an upper-triangular"),
        ({"K": make_K(-5000, 5000, 512, 512)}, r"K: expected positive focal lengths"),
        ({"t": [0.0, np.nan, 1000.0]}, r"t: contains NaN"),
        ({"t": [0.0, 1000.0]}, r"t: expected shape \(3,?\)"),
        ({"width": 10.5}, r"width: expected a positive integer"),
        ({"height": 0}, r"height: expected a positive integer"),
        ({"pixel_size": -0.3}, r"pixel_size: expected a positive"),
    ],
)
def test_camera_rejects_bad_input(kwargs, match):
    args = {
        "K": make_K(5000, 5000, 512, 512),
        "R": np.eye(3),
        "t": [0.0, 0.0, 1000.0],
        "width": 1024,
        "height": 1024,
    }
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        Camera(**args)


def test_project_and_rig_reject_bad_input():
    cam = Camera(make_K(5000, 5000, 512, 512), np.eye(3), [0, 0, 1000], 1024, 1024)
    with pytest.raises(ValueError, match=r"X: expected shape \(\.\.\., 3\)"):
        cam.project(np.zeros((4, 2)))
    with pytest.raises(ValueError, match=r"uv: contains NaN"):
        cam.rays([np.nan, 1.0])
    with pytest.raises(ValueError, match="cameras: expected a non-empty sequence"):
        Rig(())
    with pytest.raises(ValueError, match="cameras: expected a non-empty sequence"):
        Rig((cam, "cam2"))
