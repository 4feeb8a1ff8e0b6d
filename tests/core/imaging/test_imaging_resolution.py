"""MTF, PSF and Richardson–Lucy deconvolution against known PSFs (thesis §3.4)."""

import json

import numpy as np
import pytest

from core.imaging.deconvolution import richardson_lucy, richardson_lucy_varying
from core.imaging.mtf import gaussian_mtf, line_pair_modulation, slanted_edge_mtf
from core.imaging.psf import PSFGrid, gaussian_psf, psf_from_pinholes, psf_mtf
from core.synthetic import ImagingModel, pinhole_frames
from core.synthetic.analytic import attenuation_per_mm, box_line_integrals
from core.synthetic.calib_objects import face_frame

ROI = (70, 80, 100, 260)  # around the edge (it passes near the principal point), in the crop


@pytest.fixture(scope="module")
def edge(camera1024):
    """Line integrals of a 10 mm aluminium block on the intensifier, its edge tilted by 5°,
    point-sampled (no pixel aperture), so the edge's MTF is the PSF's: a 440 x 260 crop of the
    1024² view starting at (u, v) = (400, 300)."""
    T = face_frame(camera1024, thickness_mm=10.0, offset_mm=(60.0, 0.0), angle_rad=np.radians(5.0))
    return box_line_integrals(camera1024, T, (60.0, 200.0, 5.0), attenuation_per_mm("aluminium", 60.0),
                              roi=(400, 300, 260, 440), supersample=1)


@pytest.fixture(scope="module")
def fluoro(camera1024):
    """Thesis-like chain without distortion/glare: MTF50 0.5 cycles/mm, ~430 quanta per pixel."""
    return ImagingModel.fluoroscope(camera1024, rng=0, distortion=None, glare_fraction=0.0)


@pytest.fixture(scope="module")
def edge_image(edge, fluoro):
    return fluoro.to_float(fluoro.apply(edge, rng=1))


def test_slanted_edge_mtf_matches_the_known_psf(edge, edge_image, fluoro, camera1024):
    px = camera1024.pixel_size
    r = slanted_edge_mtf(edge_image, pixel_mm=px, roi=ROI)
    assert np.degrees(r.edge_angle_rad) == pytest.approx(-5.0, abs=0.2)
    upto = r.frequency <= r.nyquist
    assert r.frequency[upto][-1] > 0.95 * r.nyquist
    ana = gaussian_mtf(r.frequency, fluoro.psf_sigma_px * px)
    assert np.abs(r.mtf - ana)[upto].max() < 0.05  # within 5 % (of full modulation) up to Nyquist
    assert r.mtf50 == pytest.approx(0.5, rel=0.05)  # the preset's MTF50 (thesis Fig. 3.7)
    assert r.limit == pytest.approx(np.sqrt(np.log(10) / 2) / np.pi / (fluoro.psf_sigma_px * px), rel=0.05)
    # a sharp PSF (σ = 0.7 px): the discrete kernel's exact MTF (aliasing included) is the reference
    sharp = ImagingModel(psf_sigma_px=0.7, photons_per_pixel=2000.0, read_noise_dn=3.0)
    rs = slanted_edge_mtf(sharp.to_float(sharp.apply(edge, rng=2)), pixel_mm=px, roi=ROI)
    from core.synthetic.calibration import psf_image

    ref = psf_mtf(psf_image(sharp, 15), rs.frequency * px)
    up = rs.frequency <= rs.nyquist
    assert ref[up][-1] > 0.1 and np.abs(rs.mtf - ref)[up].max() < 0.05
    json.dumps(r.to_dict())


def test_line_pair_modulation_is_the_mtf(camera1024):
    """Sinusoidal bar groups blurred by a Gaussian: modulation = input modulation × MTF(f)."""
    sigma = 1.5
    model = ImagingModel(psf_sigma_px=sigma, photons_per_pixel=5000.0)
    freqs = (0.05, 0.1, 0.15, 0.2)  # cycles per pixel
    u = np.arange(400)
    L = np.zeros((100, 400))
    rois = []
    for k, f in enumerate(freqs):
        L[:, k * 100 : (k + 1) * 100] = 0.5 + 0.3 * np.sin(2 * np.pi * f * u[k * 100 : (k + 1) * 100])
        rois.append((k * 100 + 20, 20, 60, 60))
    img = model.expected_dn(L) - model.dark_dn
    m = line_pair_modulation(img, rois, axis="u")
    # transmission exp(-L) has modulation tanh(0.3) for a sinusoidal line integral (to first order)
    m_in = line_pair_modulation(model.gain_dn * np.exp(-L), rois, axis="u")
    np.testing.assert_allclose(m / m_in, gaussian_mtf(np.array(freqs), sigma), atol=0.03)
    assert np.all(np.diff(m) < 0)
    with pytest.raises(ValueError, match="roi"):
        line_pair_modulation(img, [(390, 0, 50, 50)])


def test_psf_from_pinhole_frames(camera1024):
    model = ImagingModel.fluoroscope(camera1024, rng=0, distortion=None, glare_fraction=0.0)
    fr = pinhole_frames(camera1024, model, n_frames=16, rng=3, psf_size=21)
    est = psf_from_pinholes(fr.image, size=21, dark=model.dark_dn)
    assert len(est.kernels) == 7
    np.testing.assert_allclose(np.sort(est.centers_uv[:, 0]), np.sort(fr.distorted_uv[:, 0]), atol=0.3)
    assert est.psf.sum() == pytest.approx(1.0) and est.psf.argmax() == 21 * 10 + 10
    assert est.peak_normalised().max() == pytest.approx(1.0)
    assert np.corrcoef(est.psf.ravel(), fr.psf.ravel())[0, 1] > 0.98
    true_fwhm = 2.3548 * model.psf_sigma_px
    assert est.fwhm_px == pytest.approx(true_fwhm, rel=0.1)  # a 0.3 mm hole widens it slightly
    # without a dark level the crop borders give the dark field
    est2 = psf_from_pinholes(fr.image, size=21)
    assert np.abs(est2.psf - est.psf).max() < 0.1 * est.psf.max()
    with pytest.raises(ValueError, match="no pinhole spot"):
        psf_from_pinholes(np.full((64, 64), 60.0) + np.random.default_rng(0).normal(0, 1, (64, 64)))


def test_rl_raises_mtf50_within_a_noise_bound(edge_image, fluoro, camera1024):
    """10 iterations: MTF50 up >= 1.3x, background noise <= 2x (undamped); damped at 1 σ the
    noise stays within 10 % while MTF50 still rises >= 10 % (thesis §3.4.3, Fig. 3.9)."""
    px = camera1024.pixel_size
    psf = gaussian_psf(fluoro.psf_sigma_px)
    flat = (slice(150, 350), slice(170, 250))  # inside the aluminium, away from the edge
    before = slanted_edge_mtf(edge_image, pixel_mm=px, roi=ROI).mtf50
    n0 = edge_image[flat].std()
    out = richardson_lucy(edge_image, psf, iterations=10)
    assert out.dtype == np.float32 and 0 <= out.min() and out.max() <= 1
    assert slanted_edge_mtf(out, pixel_mm=px, roi=ROI).mtf50 > 1.3 * before
    assert out[flat].std() < 2.0 * n0
    assert out[flat].mean() == pytest.approx(edge_image[flat].mean(), abs=1e-3)  # flux preserved
    damped = richardson_lucy(edge_image, psf, iterations=10, damping=1.0,
                             photons_per_unit=fluoro.photons_per_pixel)
    assert slanted_edge_mtf(damped, pixel_mm=px, roi=ROI).mtf50 > 1.1 * before
    assert damped[flat].std() < 1.1 * n0
    one = richardson_lucy(edge_image, psf, iterations=1)
    assert n0 < one[flat].std() < out[flat].std()  # more iterations, more noise
    np.testing.assert_array_equal(richardson_lucy(edge_image, psf, iterations=0), edge_image)
    with pytest.raises(ValueError, match="photons_per_unit"):
        richardson_lucy(edge_image, psf, damping=1.0)
    with pytest.raises(ValueError, match="odd-sized"):
        richardson_lucy(edge_image, np.ones((4, 4)))


def test_spatially_varying_rl_beats_one_global_psf():
    """Blur growing from σ = 0.8 px at the centre to 2.4 px at the corners (blended per node, the
    model the varying RL assumes): the varying deconvolution restores the periphery better."""
    rng = np.random.default_rng(0)
    H = W = 240
    sharp = np.full((H, W), 0.8, np.float32)
    for cu, cv in rng.uniform(8, 232, size=(160, 2)):  # small dark discs everywhere
        v, u = np.ogrid[:H, :W]
        sharp[(u - cu) ** 2 + (v - cv) ** 2 < 4.0] = 0.3
    c = np.array([20.0, 120.0, 220.0])
    sig = np.array([[2.4, 1.6, 2.4], [1.6, 0.8, 1.6], [2.4, 1.6, 2.4]])
    grid = PSFGrid(c, c, np.stack([[gaussian_psf(sig[a, b], 15) for b in range(3)] for a in range(3)]))
    wv, wu = grid.weights((H, W))
    import cv2

    blurred = np.zeros((H, W), np.float32)
    for a in range(3):
        for b in range(3):
            blurred += np.outer(wv[a], wu[b]).astype(np.float32) * cv2.filter2D(
                sharp, -1, grid.kernels[a, b].astype(np.float32), borderType=cv2.BORDER_REFLECT)
    noisy = (rng.poisson(blurred * 30000.0) / 30000.0).astype(np.float32)
    var = richardson_lucy_varying(noisy, grid, iterations=30)
    glob = richardson_lucy(noisy, grid.kernels[1, 1], iterations=30)
    corner = (slice(0, 60), slice(0, 60))

    def err(x):
        return np.sqrt(np.mean((x[corner] - sharp[corner]) ** 2))

    # (the centre's small PSF leaves the corners as blurred as they were: 0.045 vs 0.044 RMS;
    # the corners' own PSF takes 15 % off, what a 2.4 px blur of 2 px discs allows)
    assert err(var) < 0.9 * err(glob) and err(var) < 0.9 * err(noisy)
    centre = (slice(100, 140), slice(100, 140))
    assert np.abs(var[centre] - glob[centre]).mean() < 0.01  # the same kernel at the centre
    back = PSFGrid.from_dict(json.loads(json.dumps(grid.to_dict())))
    np.testing.assert_allclose(back.kernels, grid.kernels, rtol=1e-12)
    with pytest.raises(ValueError, match="increasing"):
        PSFGrid(c[::-1], c, grid.kernels)
