"""Image-intensifier distortion: exact inverse, plausible size, image warping."""

import cv2
import numpy as np
import pytest

from core.synthetic.distortion import Distortion
from core.synthetic.rig import foot_rig


@pytest.fixture(scope="module")
def cam1024():
    return foot_rig(seed=0)[0]


def test_forward_inverse_identity(cam1024):
    d = Distortion.random(cam1024, 5)
    g = cam1024.pixel_grid()[::7, ::7]
    np.testing.assert_allclose(d.inverse(d.forward(g)), g, atol=1e-6)
    np.testing.assert_allclose(d.forward(d.inverse(g)), g, atol=1e-6)
    assert np.abs(d.inverse(d.forward(g)) - g).max() < 0.01
    assert d.forward(np.array(d.center)) == pytest.approx(np.array(d.center))


def test_distortion_magnitude_is_plausible(cam1024):
    d = Distortion.for_camera(cam1024)  # k1 = 0.035, 2 degree twist
    c = np.array(d.center)
    edge = c + np.array([[512.0, 0], [-512, 0], [0, 512], [0, -512]])
    disp = d.displacement(edge)
    assert np.all((5 < disp) & (disp < 40))  # "several px" to a few tens at the edge
    # pincushion: points move outwards by k1 r^3 scale; twist: rotated by 2 degrees at r = 1
    q = d.forward(edge)
    assert np.linalg.norm(q - c, axis=1) == pytest.approx(512 * 1.035)
    ang = np.arctan2(*(q - c).T[::-1]) - np.arctan2(*(edge - c).T[::-1])
    np.testing.assert_allclose(np.angle(np.exp(1j * ang)), np.radians(2.0))
    assert d.displacement(c + np.array([10.0, 0])) < 0.01
    # a straight line through the centre becomes an S: an odd, super-linear (curved) deviation
    t = np.array([-500.0, -250.0, 0.0, 250.0, 500.0])
    line = c + np.column_stack([t, np.zeros_like(t)])
    dev = d.forward(line)[:, 1] - c[1]
    assert dev[0] == pytest.approx(-dev[-1]) and dev[2] == pytest.approx(0, abs=1e-9)
    assert abs(dev[-1]) > 4 * abs(dev[-2]) > 0


def test_same_relative_distortion_at_any_resolution():
    big, small = foot_rig(seed=1)[0], foot_rig(seed=1, pixels=128)[0]
    db, ds = Distortion.for_camera(big), Distortion.for_camera(small)
    p_small = np.array([[10.0, 20.0], [100.0, 60.0]])
    p_big = (p_small + 0.5) * 8 - 0.5
    np.testing.assert_allclose((ds.forward(p_small) + 0.5) * 8 - 0.5, db.forward(p_big), atol=1e-9)


def test_warp_moves_a_blob_to_the_forward_position(cam1024):
    d = Distortion.random(cam1024, 3)
    h = w = 1024
    p = np.array([850.3, 170.6])  # ideal position far from the centre
    v, u = np.mgrid[0:h, 0:w]
    blob = np.exp(-((u - p[0]) ** 2 + (v - p[1]) ** 2) / (2 * 3.0**2))
    warped = d.warp(blob, interpolation=cv2.INTER_CUBIC, border=cv2.BORDER_CONSTANT)
    q = d.forward(p)
    win = (np.abs(u - q[0]) < 15) & (np.abs(v - q[1]) < 15)
    cen = np.array([(u * warped)[win].sum(), (v * warped)[win].sum()]) / warped[win].sum()
    assert np.linalg.norm(cen - q) < 0.1
    back = d.unwarp(warped, interpolation=cv2.INTER_CUBIC, border=cv2.BORDER_CONSTANT)
    assert np.abs(back - blob)[200:-200, 200:-200].max() < 0.02


def test_invalid_distortion_rejected(cam1024):
    with pytest.raises(ValueError, match="k1, k2"):
        Distortion((0.0, 0.0), 100.0, k1=-0.5)
    with pytest.raises(ValueError, match="scale_px"):
        Distortion((0.0, 0.0), 0.0)
