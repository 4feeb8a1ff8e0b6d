"""Single-frame DLT: exact recovery, degenerate input as explicit failures, batched form."""

import numpy as np
import pytest

from core.calibration.dlt import calibrate_dlt, camera_parameters, dlt_batch
from core.calibration.objects import cube_target, spiral_target
from core.geometry.transforms import make_rigid
from core.synthetic.capture import capture_centre


@pytest.fixture(scope="module")
def cube_lab(rig):
    T = make_rigid(np.eye(3), capture_centre(rig))
    return cube_target().centers_lab(T)


def test_noise_free_cube_recovers_the_camera(rig, cube_lab):
    for cam in rig:
        d = calibrate_dlt(cube_lab, cam.project(cube_lab), width=cam.width, height=cam.height,
                          pixel_size=cam.pixel_size)
        assert d.ok and d.reason == "" and d.n_points == 15
        np.testing.assert_allclose(d.camera.K, cam.K, rtol=1e-7, atol=1e-6)
        np.testing.assert_allclose(d.camera.R, cam.R, atol=1e-9)
        np.testing.assert_allclose(d.camera.source, cam.source, atol=1e-5)
        assert d.rms_px < 1e-8 and d.skew_shift_px < 1e-6
        assert d.camera.sid == pytest.approx(cam.sid, rel=1e-9)


def test_missing_beads_are_skipped(rig, cube_lab):
    uv = rig[0].project(cube_lab)
    uv[[2, 7, 11]] = np.nan
    d = calibrate_dlt(cube_lab, uv, width=1024, height=1024)
    assert d.ok and d.n_points == 12
    assert np.isnan(d.residuals[[2, 7, 11]]).all() and np.isfinite(d.residuals[0])


def test_degenerate_configurations_fail_with_a_reason(rig, cube_lab):
    cam = rig[0]
    uv = cam.project(cube_lab)
    kw = {"width": 1024, "height": 1024}
    d = calibrate_dlt(cube_lab[:5], uv[:5], **kw)
    assert not d.ok and "only 5" in d.reason and d.camera is None
    d = calibrate_dlt(cube_lab, np.full_like(uv, np.nan), **kw)
    assert not d.ok and "no detections" in d.reason
    plane = cube_lab[5:10]  # one plane of the cube (+ 2 more beads in the same plane)
    plane = np.vstack([plane, plane[:2] + 0.5 * (plane[2:4] - plane[:2])])
    d = calibrate_dlt(plane, cam.project(plane), **kw)
    assert not d.ok and "coplanar" in d.reason
    bumpy = plane + np.random.default_rng(0).normal(0, 0.1, plane.shape)  # ~0.1 mm out of plane
    d = calibrate_dlt(bumpy, cam.project(bumpy), **kw)
    assert not d.ok and "nearly) coplanar" in d.reason and 0 < d.planarity < 0.02
    line = np.outer(np.linspace(-40, 40, 9), [1.0, 0.3, 0.2]) + capture_centre(rig)
    d = calibrate_dlt(line, cam.project(line), **kw)
    assert not d.ok and "line" in d.reason
    # the cube's two outer planes only: non-planar, accepted
    two = np.r_[0:5, 10:15]
    assert calibrate_dlt(cube_lab[two], uv[two], **kw).ok
    # garbage correspondences (shuffled) give no plausible camera
    shuffled = uv[np.random.default_rng(0).permutation(15)]
    d = calibrate_dlt(cube_lab, shuffled, **kw)
    assert not d.ok or d.rms_px > 5
    with pytest.raises(ValueError, match="min_points"):
        calibrate_dlt(cube_lab, uv, min_points=4, **kw)
    with pytest.raises(ValueError, match="uv"):
        calibrate_dlt(cube_lab, uv[:4], **kw)


def test_batched_dlt_matches_the_single_dlt(rig, rng):
    tg = spiral_target(23)
    T = make_rigid(np.eye(3), capture_centre(rig))
    X = tg.centers_lab(T)
    cam = rig[1]
    uv = cam.project(X)[None] + rng.normal(0, 0.2, (6, len(X), 2))
    P = dlt_batch(X, uv)
    par = camera_parameters(P)
    for b in range(len(uv)):
        d = calibrate_dlt(X, uv[b], width=1024, height=1024, max_skew_px=10)
        assert par["fx"][b] == pytest.approx(d.camera.fx, rel=1e-8)
        assert par["cv"][b] == pytest.approx(d.camera.cv, abs=1e-6)
        np.testing.assert_allclose(par["source"][b], d.camera.source, atol=1e-6)
        np.testing.assert_allclose(par["R"][b], d.camera.R, atol=1e-4)  # skew dropped in d.camera
    exact = camera_parameters(dlt_batch(X, cam.project(X)[None]))
    assert exact["f"][0] == pytest.approx(cam.fx, rel=1e-9)
    np.testing.assert_allclose(exact["source"][0], cam.source, atol=1e-6)
    np.testing.assert_allclose(exact["skew"], 0, atol=1e-6)
