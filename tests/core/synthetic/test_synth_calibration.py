"""Calibration objects and frames: geometry and rendered ground truth agree."""

import numpy as np
import pytest

from core.synthetic.analytic import bead_line_integrals
from core.synthetic.calib_objects import (
    CUBE_DIAMETERS_MM,
    calibration_cube,
    distortion_grid,
    helical_spiral,
    helix_frame_from_beads,
)
from core.synthetic.calibration import (
    bead_lattice_frame,
    distortion_grid_frame,
    flatfield_frames,
    object_frames,
    pinhole_frames,
)
from core.synthetic.distortion import Distortion
from core.synthetic.imaging import ImagingModel
from core.synthetic.rig import foot_rig


@pytest.fixture(scope="module")
def rig256():
    return foot_rig(seed=0, pixels=256)


def _centroid(img, uv, half=4):
    u0, v0 = np.rint(uv).astype(int)
    win = img[v0 - half : v0 + half + 1, u0 - half : u0 + half + 1]
    v, u = np.mgrid[v0 - half : v0 + half + 1, u0 - half : u0 + half + 1]
    return np.array([(u * win).sum(), (v * win).sum()]) / win.sum()


def test_objects_match_the_thesis():
    cube = calibration_cube()
    assert len(cube) == 15
    for d in CUBE_DIAMETERS_MM:
        assert np.sum(cube.diameters == d) == 5
        z = cube.centers[cube.diameters == d, 2]
        assert np.ptp(z) == 0  # one plane per diameter
    assert np.all(np.abs(cube.centers) < 50)
    for n in (23, 33):
        sp = helical_spiral(n)
        assert len(sp) == n
        np.testing.assert_array_equal(sp.diameters[:4], [3.0, 5.0, 3.0, 5.0])
        np.testing.assert_allclose(np.hypot(*sp.centers[:, :2].T), sp.centers[0, 0])
        np.testing.assert_allclose(helix_frame_from_beads(sp.centers), np.eye(4), atol=1e-9)
    assert 230 <= len(distortion_grid().holes) <= 320
    with pytest.raises(ValueError, match="radius_mm"):
        helical_spiral(17)


def test_distortion_grid_frame_ground_truth(rig256):
    cam = rig256[0]
    d = Distortion.random(cam, 3)
    model = ImagingModel(distortion=d, psf_sigma_px=0.5)
    fr = distortion_grid_frame(cam, model, rng=1)
    image, ideal, distorted = fr  # unpacks like a tuple
    assert image.dtype == np.uint16 and image.shape == (256, 256)
    assert 200 <= len(ideal) <= 320
    np.testing.assert_allclose(distorted, d.forward(ideal))
    # neighbouring holes 15 mm apart on the face (magnification ~1 at the intensifier)
    step = np.sort(np.linalg.norm(ideal[1:] - ideal[:-1], axis=1))[: len(ideal) // 2]
    assert np.median(step) * cam.pixel_size == pytest.approx(15.0 * cam.sid / (cam.sid - 3.6), rel=0.02)
    # each hole's bright spot in the expected (noise-free) frame sits at its distorted position
    sig = fr.expected - np.median(fr.expected)
    inner = np.linalg.norm(distorted - 127.5, axis=1) < 90
    err = [np.linalg.norm(_centroid(np.clip(sig, 0, None), q, 2) - q) for q in distorted[inner]]
    assert np.median(err) < 0.15
    assert np.all(fr.line_integral >= 0)


def test_distortion_argument_uses_the_realistic_chain(rig256):
    cam = rig256[1]
    d = Distortion.random(cam, 1)
    fr = distortion_grid_frame(cam, d, rng=5)
    np.testing.assert_allclose(fr.distorted_uv, d.forward(fr.ideal_uv))
    a = distortion_grid_frame(cam, d, rng=5).image
    np.testing.assert_array_equal(a, fr.image)


def test_bead_lattice_frame(rig256):
    cam = rig256[0]
    fr = bead_lattice_frame(cam, ImagingModel(), offset_mm=(10.0, -5.0), angle_rad=0.3)
    assert len(fr.ideal_uv) == 36
    P = fr.points_lab
    dist = np.linalg.norm(P[1] - P[0])
    assert dist == pytest.approx(20.0)
    # beads are dark in the image at their (undistorted here) projections
    for q in fr.distorted_uv[:5]:
        u, v = np.rint(q).astype(int)
        assert fr.expected[v, u] < np.median(fr.expected) - 100


def test_pinhole_frames_and_psf(rig256):
    cam = foot_rig(seed=0, pixels=1024)[0]
    model = ImagingModel.fluoroscope(cam, rng=0, distortion=None, glare_fraction=0.0)
    fr = pinhole_frames(cam, model, n_frames=3, rng=2, psf_size=9)
    assert fr.image.shape == (3, 1024, 1024) and fr.psf.shape == (9, 9)
    assert fr.psf.sum() == pytest.approx(1.0) and fr.psf.argmax() == 40
    # the noise-free spot of a central hole has the PSF's shape (hole ~ pixel, so a bit wider)
    q = fr.distorted_uv[3]
    u, v = np.rint(q).astype(int)
    spot = fr.expected[v - 4 : v + 5, u - 4 : u + 5] - model.dark_dn
    spot = spot / spot.sum()
    assert np.corrcoef(spot.ravel(), fr.psf.ravel())[0, 1] > 0.95
    assert fr.expected[v, u] > model.dark_dn + 0.3 * model.gain_dn * fr.psf.max()  # holes pass light
    assert np.median(fr.expected) == pytest.approx(model.dark_dn, abs=1.0)  # 5 mm lead is opaque


def test_flatfield_frames_average_to_the_flatfield(rig256):
    cam = rig256[0]
    model = ImagingModel.fluoroscope(cam, rng=3)
    frames, flat = flatfield_frames(cam, model, n_frames=8, rng=4)
    assert frames.shape == (8, 256, 256) and frames.dtype == np.uint16
    np.testing.assert_allclose(flat, model.flatfield((256, 256)))
    mean = frames.mean(axis=0)
    assert np.abs(mean - flat)[32:-32, 32:-32].mean() < 0.01 * model.gain_dn
    assert flat[128, 128] > flat[128, 2]  # roll-off


def test_object_frames_biplane(rig256):
    models = [ImagingModel.fluoroscope(c, rng=i) for i, c in enumerate(rig256)]
    sp = helical_spiral(23)
    T = np.eye(4)
    T[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]  # axis along lab -y... tilted by the rig views
    fr = object_frames(rig256, sp, T, models, rng=7)
    assert fr.image.shape == (2, 256, 256) and fr.ideal_uv.shape == (2, 23, 2)
    np.testing.assert_allclose(fr.ideal_uv[1], rig256[1].project(fr.points_lab))
    np.testing.assert_allclose(fr.distorted_uv[0], models[0].distortion.forward(fr.ideal_uv[0]))
    # the big beads are dark at their distorted positions in both views
    for v in range(2):
        big = fr.distorted_uv[v][sp.diameters == 5.0]
        ij = np.rint(big).astype(int)
        vals = fr.expected[v][ij[:, 1], ij[:, 0]]
        assert np.median(vals) < np.median(fr.expected[v]) - 300
    with pytest.raises(ValueError, match="imagings"):
        object_frames(rig256, sp, T, models[:1])
    cube = object_frames(rig256, calibration_cube(), np.eye(4), models, rng=1)
    assert cube.ideal_uv.shape == (2, 15, 2)


def test_fluence_and_line_averages_agree_without_supersampling(rig256):
    cam = rig256[0]
    c, d = np.array([[0.0, 0, 0]]), [4.0]
    a = bead_line_integrals(cam, c, d, 0.95, supersample=1)
    b = bead_line_integrals(cam, c, d, 0.95, supersample=1, average="fluence")
    np.testing.assert_allclose(a, b, atol=1e-5)
    f = bead_line_integrals(cam, c, d, 0.95, supersample=4, average="fluence")
    line = bead_line_integrals(cam, c, d, 0.95, supersample=4)
    assert np.all(f <= line + 1e-5)  # Jensen: the mean fluence beats the fluence of the mean
