"""Reconstruction error over the capture volume and on an independent object."""

import numpy as np
import pytest

from core.calibration.errormap import capture_lattice, error_map, object_reconstruction, reconstruction_errors
from core.calibration.objects import cube_target
from core.geometry.camera import Rig
from core.geometry.transforms import make_rigid
from core.synthetic.capture import capture_centre


@pytest.fixture(scope="module")
def lattice(rig):
    return capture_lattice(rig, spacing_mm=20.0)


def test_lattice_fills_the_intersection_of_the_cones(rig, lattice):
    assert len(lattice) > 200
    assert np.allclose(np.round(lattice / 20.0), lattice / 20.0)  # on the 20 mm grid
    for cam in rig:
        uv, z = cam.project(lattice, return_depth=True)
        assert np.all((z > 0) & (z < cam.sid))
        assert np.all((uv >= -0.5) & (uv <= 1023.5))
    # a point just outside one image is excluded
    edge = rig[0].detector_point([[1030.0, 500.0]], distance=900.0)
    assert len(capture_lattice(rig, spacing_mm=20.0, margin_px=50)) < len(lattice)
    assert not np.any(np.all(np.isclose(lattice, edge), axis=1))


def test_reconstruction_error_is_zero_for_the_true_rig_and_grows_with_a_wrong_one(rig, lattice):
    assert reconstruction_errors(rig, rig, lattice).max() < 1e-6
    moved = Rig((rig[0], rig[1].with_pose(rig[1].R, rig[1].t + np.array([1.0, 0.0, 0.0]))))
    em = error_map(rig, [rig, moved], points=lattice)
    assert em.errors.shape == (2, len(lattice))
    assert em.errors[0].max() < 1e-6 and 0.1 < em.errors[1].mean() < 2.0
    assert np.allclose(em.max, em.errors[1]) and np.allclose(em.mean, em.errors[1] / 2)
    s = em.summary()
    assert s["n_points"] == len(lattice) and s["max_mm"] == pytest.approx(em.errors.max())
    noisy = reconstruction_errors(rig, rig, lattice, image_noise_px=0.1, rng=0)
    assert 0.005 < np.sqrt(np.mean(noisy**2)) < 0.1  # 0.1 px ~ 0.02 mm at the object


def test_independent_object(rig):
    cube = cube_target()
    T = make_rigid(np.eye(3), capture_centre(rig) + np.array([20.0, -10.0, 15.0]))
    uv = rig.project(cube.centers_lab(T)) + np.random.default_rng(0).normal(0, 0.05, (2, 15, 2))
    uv[1, 3] = np.nan  # seen in one view only
    rec = object_reconstruction(rig, cube.centers, uv)
    assert np.isnan(rec.points[3]).all() and np.isnan(rec.residuals[3])
    assert rec.rms_mm < 0.03
    assert len(rec.distance_errors) == 14 * 13 // 2 and np.abs(rec.distance_errors).max() < 0.1
    assert np.nanmax(rec.reprojection_px) < 0.3
