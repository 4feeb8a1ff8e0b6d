"""Voxelising closed meshes against analytic volumes."""

import numpy as np
import pytest

from core.synthetic.voxelize import (
    box_mesh,
    icosphere,
    mesh_inside_grid,
    mesh_volume,
    point_triangle_distance,
    voxelize_mesh,
)


def test_icosphere_and_box_mesh_volumes():
    V, F = icosphere(10.0, 3)
    assert len(F) == 20 * 4**3
    np.testing.assert_allclose(np.linalg.norm(V, axis=1), 10.0)
    assert mesh_volume(V, F) == pytest.approx(4 / 3 * np.pi * 1000, rel=0.01)
    V, F = box_mesh((1, 2, 3), center=(5, 5, 5))
    assert mesh_volume(V, F) == pytest.approx(48.0)


def test_point_triangle_distance_regions():
    a, b, c = np.array([0.0, 0, 0]), np.array([4.0, 0, 0]), np.array([0.0, 4, 0])
    P = np.array([[1, 1, 2.0], [-3, 0, 0], [6, 0, 0], [0, 7, 0], [2, -2, 0], [-1, 2, 0],
                  [3, 3, 0], [1, 1, 0]])
    want = [2, 3, 2, 3, 2, 1, np.sqrt(2), 0]
    n = len(P)
    got = point_triangle_distance(P, np.tile(a, (n, 1)), np.tile(b, (n, 1)), np.tile(c, (n, 1)))
    np.testing.assert_allclose(got, want, atol=1e-12)


def test_inside_grid_matches_analytic_sphere():
    V, F = icosphere(12.0, 4)
    origin = np.array([-15.0, -15.0, -15.0])
    n = 31
    inside = mesh_inside_grid(V, F, origin, 1.0, (n, n, n))
    k, j, i = np.indices(inside.shape)
    r = np.sqrt((origin[0] + i) ** 2 + (origin[1] + j) ** 2 + (origin[2] + k) ** 2)
    disagree = inside != (r < 12.0)
    # only voxel centres within the icosphere's chordal error (~0.03 mm) of the sphere may differ
    assert np.all(np.abs(r[disagree] - 12.0) < 0.05)
    assert inside[15, 15, 15] and not inside[0, 0, 0]


def test_inside_grid_rows_through_edges_and_vertices():
    # every face, edge and vertex of this box lies exactly on grid rows: each row must count
    # its crossings once, giving exactly the 4 x 4 x 4 voxels of the box's volume
    V, F = box_mesh((2.0, 2.0, 2.0))
    inside = mesh_inside_grid(V, F, (-3.0, -3.0, -3.0), 1.0, (7, 7, 7))
    assert inside.sum() == 64
    k, j, i = np.nonzero(inside)
    assert np.ptp(i) == np.ptp(j) == np.ptp(k) == 3


def test_voxelised_icosphere_volume_and_shell():
    R = 15.0
    V, F = icosphere(R, 4)
    vol = voxelize_mesh(V, F, spacing=1.0, cortex_mm=2.0, cortical_hu=1500, trabecular_hu=1500,
                        dtype=np.float32, name="ball")
    assert vol.name == "ball" and vol.units == "HU"
    occ = (vol.data - 40.0) / (1500 - 40.0)  # solid ball: HU is bg + (cortical - bg) * occupancy
    assert occ.sum() * 1.0 == pytest.approx(4 / 3 * np.pi * R**3, rel=0.01)
    assert occ.sum() == pytest.approx(mesh_volume(V, F), rel=0.005)
    shell = voxelize_mesh(V, F, spacing=1.0, cortex_mm=2.0, cortical_hu=1500, trabecular_hu=300)
    k, j, i = np.indices(shell.data.shape).reshape(3, -1)
    r = np.linalg.norm(shell.index_to_physical(np.column_stack([i, j, k])), axis=1)
    hu = shell.data.reshape(-1)
    assert np.all(hu[r < R - 3] == 300)
    assert np.all(hu[(r > R - 1.5) & (r < R - 0.5)] == 1500)
    assert np.all(hu[r > R + 0.6] == 40)


def test_voxelised_box_exact():
    V, F = box_mesh((8.0, 6.0, 4.0))
    vol = voxelize_mesh(V, F, spacing=0.5, cortex_mm=1.0, cortical_hu=1500, trabecular_hu=1500,
                        dtype=np.float32, margin_mm=2.0)
    occ = (vol.data - 40.0) / 1460.0
    assert occ.sum() * 0.125 == pytest.approx(16 * 12 * 8, rel=1e-3)
    tex = voxelize_mesh(V, F, spacing=0.5, texture_hu=50.0, seed=2)
    assert np.array_equal(tex.data, voxelize_mesh(V, F, spacing=0.5, texture_hu=50.0, seed=2).data)


def test_open_mesh_rejected():
    V, F = box_mesh((1, 1, 1))
    with pytest.raises(ValueError, match="not closed"):
        voxelize_mesh(V, F[:-1])
    with pytest.raises(ValueError, match="faces"):
        voxelize_mesh(V, F + 100)
