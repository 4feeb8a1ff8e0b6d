"""Exact line integrals through beads, boxes, cylinders and plates."""

import numpy as np
import pytest

from core.geometry import Camera, make_K
from core.synthetic.analytic import (
    attenuation_per_mm,
    bead_line_integrals,
    box_line_integrals,
    cylinder_line_integrals,
    slab_line_integrals,
)
from core.synthetic.rig import foot_rig


@pytest.fixture
def axis_camera():
    """Source at z = -1000 looking along +z; pixel (32, 32) is centred on the principal ray."""
    return Camera(make_K(1000.0, 1000.0, 32.0, 32.0), np.eye(3), [0, 0, 1000.0], 65, 65, 0.5)


def test_attenuation_table_values():
    assert attenuation_per_mm("water", 60) == pytest.approx(0.02059, rel=1e-4)
    steel = attenuation_per_mm("steel", 60)
    assert 0.9 < steel < 1.0  # NIST: Fe 1.205 cm2/g x 7.9 g/cm3
    assert 2.0 < attenuation_per_mm("steel", 42) < 3.0  # the "2-3 /mm" quoted for ~40 keV
    assert attenuation_per_mm("water", 55) == pytest.approx(0.02163, rel=0.01)  # log-log interp
    with pytest.raises(ValueError, match="material"):
        attenuation_per_mm("gold")
    with pytest.raises(ValueError, match="energy_kev"):
        attenuation_per_mm("water", 200)


def test_bead_chord_on_axis_and_off_axis(axis_camera):
    mu, d = 0.95, 3.0
    img = bead_line_integrals(axis_camera, [[0.0, 0, 0]], [d], mu, supersample=1)
    assert img[32, 32] == pytest.approx(2 * 1.5 * mu, rel=1e-6)
    # neighbour pixel: perpendicular distance of its ray from the bead centre
    src, dirs = axis_camera.rays(np.array([[33.0, 32.0]]))
    dist = np.linalg.norm(np.cross(-src, dirs[0]))
    assert img[32, 33] == pytest.approx(2 * np.sqrt(1.5**2 - dist**2) * mu, rel=1e-6)
    assert img[32, 36] == 0.0  # 4 px = 2 mm off the axis at the bead: outside the bead


def test_bead_integral_equals_mu_times_volume():
    cam = foot_rig(seed=1, pixels=512)[0]
    centers = np.array([[0.0, 0, 0], [20, -10, 15]])
    diam = np.array([3.0, 5.0])
    mu = attenuation_per_mm("steel")
    img = bead_line_integrals(cam, centers, diam, mu, supersample=4)
    for c, dd in zip(centers, diam, strict=True):
        uv = cam.project(c)
        # pixel footprint at the bead (perpendicular to the ray), mm^2
        src, ray = cam.rays(uv)
        foot = (cam.pixel_size * np.linalg.norm(c - src) / cam.sid) ** 2 / (ray @ cam.principal_ray) ** 3
        u, v = np.rint(uv).astype(int)
        patch = img[v - 15 : v + 16, u - 15 : u + 16]
        assert patch.sum() * foot == pytest.approx(mu * np.pi / 6 * dd**3, rel=0.01)


def test_bead_roi_and_superposition():
    cam = foot_rig(seed=2, pixels=256)[1]
    c = np.array([[0.0, 0, 0], [0.5, 0.3, 0.2]])
    full = bead_line_integrals(cam, c, [2.0, 3.0], [1.0, 0.5])
    one = bead_line_integrals(cam, c[:1], 2.0, 1.0)
    two = bead_line_integrals(cam, c[1:], 3.0, 0.5)
    np.testing.assert_allclose(full, one + two, rtol=1e-6, atol=1e-7)
    uv = np.rint(cam.project(c[0])).astype(int)
    roi = (uv[0] - 10, uv[1] - 8, 20, 16)
    crop = bead_line_integrals(cam, c, [2.0, 3.0], [1.0, 0.5], roi=roi)
    assert crop.shape == (16, 20) and crop.dtype == np.float32
    np.testing.assert_allclose(crop, full[roi[1] : roi[1] + 16, roi[0] : roi[0] + 20], atol=1e-7)
    assert bead_line_integrals(cam, np.zeros((0, 3)), [], 1.0).sum() == 0
    with pytest.raises(ValueError, match="diameters"):
        bead_line_integrals(cam, c, [2.0, -1.0], 1.0)


def test_box_cylinder_slab_chords(axis_camera):
    mu = 0.1
    T = np.eye(4)
    box = box_line_integrals(axis_camera, T, (5.0, 6.0, 7.0), mu, supersample=1)
    assert box[32, 32] == pytest.approx(14 * mu)
    assert box[0, 0] == 0.0
    cyl_z = cylinder_line_integrals(axis_camera, T, 4.0, 10.0, mu, supersample=1)
    assert cyl_z[32, 32] == pytest.approx(20 * mu)
    Tx = np.eye(4)
    Tx[:3, :3] = [[0, 0, 1], [0, 1, 0], [-1, 0, 0]]  # cylinder axis along lab x
    cyl_x = cylinder_line_integrals(axis_camera, Tx, 4.0, 10.0, mu, supersample=1)
    assert cyl_x[32, 32] == pytest.approx(8 * mu)
    slab = slab_line_integrals(axis_camera, (0, 0, 100.0), (0, 0, 1), 3.0, mu)
    assert slab[32, 32] == pytest.approx(3 * mu)
    _, d = axis_camera.rays(np.array([[0.0, 0.0]]))
    assert slab[0, 0] == pytest.approx(3 * mu / d[0, 2])
    behind = slab_line_integrals(axis_camera, (0, 0, -2000.0), (0, 0, 1), 3.0, mu)
    assert behind.max() == 0.0
