"""Veiling glare: measured from rendered lead-disc frames against the generator's glare, undone
by the pipeline's glare step, and measured by the session calibration."""

import json

import numpy as np
import pytest
from scipy import ndimage

from core.imaging.flatfield import build_flatfield
from core.imaging.glare import GlareEstimate, disc_profile, estimate_glare, remove_glare
from core.imaging.pipeline import GlareStep, Pipeline
from core.render.attenuation import attenuation_per_mm
from core.synthetic import ImagingModel, foot_rig
from core.synthetic.analytic import cylinder_line_integrals
from core.synthetic.calib_objects import face_frame


@pytest.fixture(scope="module")
def camera():
    return foot_rig(seed=0, pixels=256)[0]  # 1.17 mm pixels


def _disc(cam, diameter_mm=60.0):
    return cylinder_line_integrals(cam, face_frame(cam, thickness_mm=2.0), diameter_mm / 2, 1.0,
                                   attenuation_per_mm("lead", 60.0), supersample=3, average="fluence")


@pytest.mark.parametrize("fraction, sigma_mm", [(0.05, 20.0), (0.08, 12.0)])
def test_estimate_recovers_the_generators_glare(camera, fraction, sigma_mm):
    model = ImagingModel.fluoroscope(camera, rng=0, distortion=None, aperture_radius=1.0,
                                     glare_fraction=fraction, glare_sigma_mm=sigma_mm)
    L = _disc(camera)
    g = np.random.default_rng(1)
    discs = [model.apply(L, rng=g) for _ in range(4)]
    flats = np.stack([model.apply(np.zeros_like(L), rng=g) for _ in range(10)])
    # what a lab has: raw frames; the glare's faint profile over the mean empty field (not smoothed)
    ff = build_flatfield(flats, dark=model.dark_dn)
    field = ndimage.binary_erosion(ff.gain > 0.5 * np.percentile(ff.gain, 99), iterations=12)
    flat = flats.mean(axis=0) - model.dark_dn
    imgs = [np.where(field, (d - model.dark_dn) / np.where(field, flat, 1.0), 0.0) for d in discs]
    est = estimate_glare(imgs, mask=field)
    true_sigma = sigma_mm / camera.pixel_size
    assert est.fraction == pytest.approx(fraction, rel=0.04)
    assert est.sigma_px == pytest.approx(true_sigma, rel=0.03)
    assert 0 < est.fraction_sd < 0.01 and 0 < est.sigma_px_sd < 0.1 * true_sigma
    assert abs(est.transmission) < 0.01 and est.scale == pytest.approx(1.0, abs=0.01)
    assert est.radius_px == pytest.approx(30.0 / camera.pixel_size, rel=0.02) and est.n_frames == 4
    d = est.to_dict(pixel_mm=camera.pixel_size)
    assert d["sigma_mm"] == pytest.approx(sigma_mm, rel=0.03) and json.dumps(d)


def test_estimate_refuses_frames_without_a_whole_disc(camera):
    with pytest.raises(ValueError, match="no dark"):
        estimate_glare(np.ones((64, 64)))
    img = np.ones((64, 64))
    img[:20, 20:40] = 0.02  # an opaque region cut by the image's edge
    with pytest.raises(ValueError, match="edge of the field"):
        estimate_glare(img)


def test_disc_profile():
    r = np.array([0.0, 10.0, 20.0, 1000.0])
    p = disc_profile(r, 10.0, 1e-3 * 10)
    assert p[0] == pytest.approx(1.0) and p[1] == pytest.approx(0.5, abs=1e-3) and p[-1] == 0
    assert disc_profile(0.0, 10.0, 10.0) == pytest.approx(1 - np.exp(-0.5))


@pytest.mark.parametrize("aperture", [None, 1.0])
def test_remove_glare_undoes_the_generators_glare(camera, aperture):
    m = ImagingModel(glare_fraction=0.05, glare_sigma_px=20.0 / camera.pixel_size, aperture_radius=aperture)
    L = _disc(camera, 80.0) + 0.5 * (np.arange(256)[None, :] > 180)  # a disc and a step of tissue
    x = np.exp(-L)
    y = m.to_float(m.expected_dn(L))
    out = remove_glare(y, m.glare_fraction, m.glare_sigma_px)
    inside = ndimage.binary_erosion(y > 0, iterations=2)
    assert np.abs(y - x)[inside].max() > 0.02
    assert np.abs(out - x)[inside].max() < 2e-3
    assert np.all(out[y == 0] == 0) and out.dtype == np.float32
    np.testing.assert_array_equal(remove_glare(y, 0.0, 5.0), y)


def test_glare_step_in_the_standard_chain(camera):
    m = ImagingModel(glare_fraction=0.05, glare_sigma_px=17.0, dark_dn=60.0)
    ff = build_flatfield(np.stack([m.flatfield((256, 256))] * 2), dark=60.0)
    est = GlareEstimate(0.05, 17.0, 0.001, 0.3, 0.4, 0.0, 1.0, (128.0, 128.0), 25.0, 0.001, 2, 1000)
    pipe = Pipeline.standard(flatfield=ff, glare=est)
    assert [s.kind for s in pipe.steps] == ["dark", "flatfield", "glare"]
    raw = m.apply(_disc(camera, 80.0))
    out = pipe(raw)
    back = Pipeline.from_json(pipe.to_json())
    assert pipe.to_dict()["version"] == 2 and Pipeline.standard(flatfield=ff).to_dict()["version"] == 1
    np.testing.assert_array_equal(back(raw), out)
    assert isinstance(back.steps[2], GlareStep) and back.steps[2].sigma_px == 17.0
    # the disc's middle reads the glare before, ~0 after
    assert pipe.steps[1](pipe.steps[0](raw))[128, 128] > 0.005 and out[128, 128] < 1e-3
    with pytest.raises(ValueError, match="fraction"):
        GlareStep(1.0, 10.0)
    with pytest.raises(ValueError, match="sigma_px"):
        GlareStep(0.05, 0.0)


def test_session_calibration_measures_glare(tmp_path):
    from core.calibration.session import distortion_step, flatfield_step, prepare, refit_distortion
    from core.io import read_session
    from core.synthetic.session import write_calibration_session

    out = tmp_path / "session"
    write_calibration_session(out, pixels=256, seed=0, n_spiral=1, n_grid=2, n_lattice=0, n_dark=2, n_flat=4)
    truth = json.loads((out / "truth" / "truth.json").read_text())["imaging"]
    setup = prepare(read_session(out))
    dist = distortion_step(setup, flatfield_step(setup))
    for c in dist.cameras:
        t = truth[c.name]
        assert [s.kind for s in c.pipeline.steps] == ["dark", "flatfield", "glare", "undistort"]
        assert c.glare.n_frames == 2
        assert c.glare.fraction == pytest.approx(t["glare_fraction"], rel=0.05)
        assert c.glare.sigma_px == pytest.approx(t["glare_sigma_px"], rel=0.05)
        assert c.pipeline.steps[2].fraction == c.glare.fraction
    again = refit_distortion(setup, dist, 0, "poly(4,4)")
    assert again.cameras[0].glare is dist.cameras[0].glare
    assert [s.kind for s in again.cameras[0].pipeline.steps][2] == "glare"
    # a session without glare frames gives the chain without the step
    plain = tmp_path / "plain"
    write_calibration_session(plain, pixels=256, seed=0, n_spiral=1, n_grid=1, n_lattice=0, n_dark=1,
                              n_flat=2, n_glare=0)
    s2 = prepare(read_session(plain))
    d2 = distortion_step(s2, flatfield_step(s2))
    assert d2.cameras[0].glare is None and "glare" not in [s.kind for s in d2.cameras[0].pipeline.steps]

