"""The image-intensifier image chain: noise statistics, blur, roll-off, distortion, 12 bits."""

from dataclasses import replace

import numpy as np
import pytest

from core.synthetic.distortion import Distortion
from core.synthetic.imaging import ImagingModel, gaussian_blur, quantum_noise, rolloff_gain
from core.synthetic.rig import foot_rig


@pytest.fixture(scope="module")
def cam():
    return foot_rig(seed=0, pixels=256)[0]


def test_poisson_variance_equals_mean_in_counts():
    rng = np.random.default_rng(0)
    for n0, level in ((50.0, 1.0), (200.0, 0.3)):
        s = quantum_noise(np.full((400, 400), level), n0, rng)
        counts = s * n0
        assert counts.mean() == pytest.approx(level * n0, rel=0.01)
        assert counts.var() == pytest.approx(counts.mean(), rel=0.03)
        assert np.allclose(counts, np.rint(counts))  # whole quanta


def test_model_noise_at_dose_in_dn():
    m = ImagingModel(photons_per_pixel=100.0, gain_dn=3000.0, dark_dn=50.0)
    L = np.full((300, 300), np.log(2.0))  # half the fluence
    img = m.apply(L, rng=1).astype(float)
    assert img.mean() == pytest.approx(50 + 1500, rel=0.005)
    # DN variance = gain^2 * (I/I0) / N0 (+ 1/12 from rounding)
    assert img.var() == pytest.approx(3000.0**2 * 0.5 / 100 + 1 / 12, rel=0.05)


def test_blur_preserves_the_sum():
    rng = np.random.default_rng(2)
    img = np.zeros((128, 160))
    img[30:90, 40:120] = rng.uniform(size=(60, 80))
    for m in (ImagingModel(psf_sigma_px=2.5), ImagingModel(psf_kernel=np.outer([1, 4, 6, 4, 1], [1, 2, 1]))):
        out = m.blur(img)
        assert out.sum() == pytest.approx(img.sum(), rel=1e-9)
        assert out.max() < img.max()
    # an object touching the border: reflecting borders still keep the sum
    edge = np.zeros((64, 64))
    edge[:, :5] = 1.0
    assert gaussian_blur(edge, 3.0).sum() == pytest.approx(edge.sum(), rel=1e-9)
    # wide veiling glare (downsampled path) keeps it to a fraction of a per cent
    glare = ImagingModel(psf_sigma_px=1.0, glare_fraction=0.1, glare_sigma_px=40.0)
    assert glare.blur(img).sum() == pytest.approx(img.sum(), rel=5e-3)


def test_rolloff_centre_to_edge_ratio():
    g = rolloff_gain((201, 301), 0.6)
    assert g[100, 150] == pytest.approx(1.0)
    a2 = 0.6**-0.5 - 1  # g(r) = 1 / (1 + a2 r^2)^2 with r = 1 at half the shorter side (100.5 px)
    assert g[100, 150 + 100] == pytest.approx(1 / (1 + a2 * (100 / 100.5) ** 2) ** 2)
    assert g[100, 250] == pytest.approx(0.6, abs=0.005)
    assert np.all(np.diff(g[100, 150:]) < 0) and g[0, 0] < 0.6
    flat = ImagingModel(rolloff_edge=0.6, dark_dn=10.0).flatfield((201, 301))
    assert (flat[100, 250] - 10) / (flat[100, 150] - 10) == pytest.approx(g[100, 250])


def test_quantisation_range_and_dtype():
    m = ImagingModel(photons_per_pixel=30.0, read_noise_dn=20.0, dark_dn=5.0, gain_dn=4000.0)
    L = np.linspace(-1.0, 12.0, 200 * 200).reshape(200, 200)  # over-exposed to opaque
    img = m.apply(L, rng=3)
    assert img.dtype == np.uint16
    assert img.min() == 0 and img.max() == 4095
    assert np.all(img <= 4095)
    with pytest.raises(ValueError, match="saturates"):
        ImagingModel(gain_dn=4090.0, dark_dn=10.0)
    with pytest.raises(ValueError, match="rng"):
        m.apply(L)


def test_flatfield_correction_recovers_transmission(cam):
    d = Distortion.random(cam, 1)
    m = ImagingModel(rolloff_edge=0.5, distortion=d, dark_dn=80.0)
    L = np.full(cam.image_shape, 0.7)
    f = m.to_float(m.apply(L))
    assert f.dtype == np.float32 and 0.0 <= f.min() and f.max() <= 1.0
    np.testing.assert_allclose(f[20:-20, 20:-20], np.exp(-0.7), atol=2.5e-3)  # 12-bit rounding
    assert m.to_float(m.apply(np.zeros(cam.image_shape))).min() > 0.99


def test_distortion_and_aperture_in_the_chain(cam):
    d = Distortion.random(cam, 4)
    m = ImagingModel(distortion=d, aperture_radius=0.9)
    L = np.zeros(cam.image_shape)
    p = np.array([200.0, 60.0])
    v, u = np.mgrid[0 : cam.height, 0 : cam.width]
    L += 3.0 * np.exp(-((u - p[0]) ** 2 + (v - p[1]) ** 2) / (2 * 2.0**2))
    sig = 1.0 - m.expected_signal(L)
    q = d.forward(p)
    win = (np.abs(u - q[0]) < 10) & (np.abs(v - q[1]) < 10)
    cen = np.array([(u * sig)[win].sum(), (v * sig)[win].sum()]) / sig[win].sum()
    assert np.linalg.norm(cen - q) < 0.1
    flat = m.flatfield(cam.image_shape)
    assert flat[0, 0] == 60.0 and flat[128, 128] > 3000  # dark outside the round field
    assert m.to_float(m.apply(L))[0, 0] == 0.0


def test_fluoroscope_preset_and_determinism(cam):
    m = ImagingModel.fluoroscope(cam, rng=0)
    assert m.photons_per_pixel == pytest.approx(5000 * cam.pixel_size**2)
    assert m.psf_sigma_px * cam.pixel_size == pytest.approx(0.3748, rel=1e-3)  # MTF50 0.5 c/mm
    assert m.distortion is not None and m.read_noise_dn > 0
    L = np.zeros(cam.image_shape)
    L[100:150, 80:200] = 1.2
    a, b = m.apply(L, rng=5), m.apply(L, rng=5)
    np.testing.assert_array_equal(a, b)
    assert np.any(a != m.apply(L, rng=6))
    assert ImagingModel.fluoroscope(cam, rng=0).distortion == m.distortion
    assert ImagingModel.fluoroscope(cam, rng=1).distortion != m.distortion
    d = m.to_dict()
    assert d["distortion"]["model"] == "pincushion+s-twist" and d["order"][0] == "beer-lambert"
    sharp = replace(m, psf_sigma_px=0.0, glare_fraction=0.0)
    assert sharp.blur(L).sum() == pytest.approx(L.sum())
