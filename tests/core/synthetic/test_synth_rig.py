"""Ground-truth checks of the synthetic walkway rig."""

import numpy as np
import pytest

from core.synthetic.rig import FLOOR_Z_MM, foot_rig


def _closest_approach(c0, d0, c1, d1):
    n = np.cross(d0, d1)
    return abs((c1 - c0) @ n) / np.linalg.norm(n)


@pytest.mark.parametrize("seed", [0, 1, 2, 3, 4])
def test_rig_geometry_ranges(seed):
    rig = foot_rig(seed=seed)
    assert len(rig) == 2
    for cam in rig:
        assert 1300 <= cam.sid <= 1500
        assert cam.pixel_size == pytest.approx(300 / 1024)
        assert cam.image_shape == (1024, 1024)
        # source below the walkway, beam tilted upwards by 20-35 degrees
        assert cam.source[2] < FLOOR_Z_MM
        elev = np.degrees(np.arcsin(cam.principal_ray[2]))
        assert 20 - 1e-9 <= elev <= 35 + 1e-9
        # the principal ray passes within the aim jitter of the lab origin
        d = np.linalg.norm(np.cross(-cam.source, cam.principal_ray))
        assert d <= 5.0 + 1e-9
        # the origin images near the image centre, principal point within 3 mm of the centre
        uv = cam.project(np.zeros(3))
        assert np.all(np.abs(uv - 511.5) < 40)
        assert np.hypot(cam.cu - 511.5, cam.cv - 511.5) * cam.pixel_size <= 3.0 + 1e-9
        # image rows run downwards in the lab: a point above the origin has a smaller v
        assert cam.project(np.array([0, 0, 50.0]))[1] < uv[1]
    ang = np.degrees(rig.angle_between_views())
    assert 60 <= ang <= 120
    a, b = rig
    assert _closest_approach(a.source, a.principal_ray, b.source, b.principal_ray) < 10.0
    # sources on the subject's right (-y), intensifiers on the left (+y)
    assert a.source[1] < 0 and b.source[1] < 0
    assert a.detector_plane()[0][1] > 0 and b.detector_plane()[0][1] > 0


def test_rig_pixels_option_keeps_geometry():
    big, small = foot_rig(seed=7), foot_rig(seed=7, pixels=128)
    for cb, cs in zip(big, small, strict=True):
        np.testing.assert_allclose(cs.source, cb.source)
        np.testing.assert_allclose(cs.R, cb.R)
        assert cs.pixel_size == pytest.approx(cb.pixel_size * 8)
        assert cs.sid == pytest.approx(cb.sid)
        np.testing.assert_allclose(cs.detector_corners(), cb.detector_corners(), atol=1e-9)
        X = np.array([[10.0, -20, 30], [-40, 5, -60]])
        np.testing.assert_allclose((cs.project(X) + 0.5) * 8, cb.project(X) + 0.5, atol=1e-6)


def test_rig_determinism_and_validation():
    a, b, c = foot_rig(seed=3), foot_rig(seed=3), foot_rig(seed=4)
    np.testing.assert_array_equal(a[0].P, b[0].P)
    assert not np.allclose(a[0].P, c[0].P)
    r = foot_rig(seed=5, angle_deg=90, sid_mm=1400)
    assert np.degrees(r.angle_between_views()) == pytest.approx(90)
    assert r[0].sid == pytest.approx(1400)
    with pytest.raises(ValueError, match="angle_deg/elevation_deg"):
        foot_rig(angle_deg=(110, 150), elevation_deg=40)
    for s in range(10):  # the angle is drawn from the feasible part of the range
        r = foot_rig(seed=s, angle_deg=(80, 120), elevation_deg=(30, 40))
        e = np.degrees(np.arcsin([c.principal_ray[2] for c in r]))
        assert 80 - 1e-6 <= np.degrees(r.angle_between_views()) <= min(120, 180 - e.sum()) + 1e-6
    with pytest.raises(ValueError, match="sid_mm"):
        foot_rig(sid_mm=(1500, 1300))
    with pytest.raises(ValueError, match="pixels"):
        foot_rig(pixels=4)
