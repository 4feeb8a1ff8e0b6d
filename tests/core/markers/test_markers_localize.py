"""The seven localizers against the exact lattice ground truth, and their failure flags."""

import numpy as np
import pytest

from core.markers import METHODS, RECOMMENDED, STATUS, localize
from core.markers.dft import register_translation

THESIS = [m for m in METHODS if m != RECOMMENDED]


@pytest.mark.parametrize("method", list(METHODS))
def test_noise_free_lattice_is_localised_to_a_few_hundredths(lattice, method):
    res = localize(lattice.expected(), lattice.uv, diameter_px=lattice.diameter_px, method=method)
    assert res.ok.all(), res.counts()
    err = np.linalg.norm(res.uv - lattice.uv, axis=1)
    assert err.max() < (0.012 if method == RECOMMENDED else 0.03), err.max()


def test_recommended_is_precise_and_its_uncertainty_is_calibrated(lattice, lattice_frames):
    res = localize(lattice_frames, lattice.uv, diameter_px=lattice.diameter_px)
    assert res.shape == (30, 21) and res.ok.all()
    err = res.uv - lattice.uv
    scatter = err.std(axis=0)  # per bead and axis
    assert np.abs(err.mean(axis=0)).max() < 0.02  # unbiased
    assert np.sqrt(np.mean(scatter**2)) < 0.03
    ratio = np.sqrt(np.mean(scatter**2)) / np.sqrt(np.mean(res.sigma**2))
    assert 0.75 < ratio < 1.33, ratio  # the predicted sigma matches the observed scatter


def test_recommended_converges_from_guesses_three_radii_off(lattice, lattice_frames):
    g = np.random.default_rng(1)
    r = lattice.diameter_px / 2
    ang = g.uniform(0, 2 * np.pi, (10, 21))
    guesses = lattice.uv + 3.0 * r[:, None] * np.stack([np.cos(ang), np.sin(ang)], -1)
    res = localize(lattice_frames[:10], guesses, diameter_px=lattice.diameter_px)
    assert res.ok.all(), res.counts()
    err = np.linalg.norm(res.uv - lattice.uv, axis=-1)
    assert err.mean() < 0.05 and err.max() < 0.15, (err.mean(), err.max())
    # a one-shot weighted centroid stays near the guess
    gc = localize(lattice_frames[:10], guesses, diameter_px=lattice.diameter_px, method="gaussian_centroid")
    assert np.nanmean(np.linalg.norm(gc.uv - lattice.uv, axis=-1)) > 1.0


def test_iterative_methods_beat_one_shot_gaussian_weighting_from_offset_guesses(lattice):
    img = lattice.expected()
    guesses = lattice.uv + np.array([1.5, -1.0])
    one = localize(img, guesses, diameter_px=lattice.diameter_px, method="gaussian_centroid")
    it = localize(img, guesses, diameter_px=lattice.diameter_px, method="iterative_gaussian", tol=1e-4)
    e1 = np.linalg.norm(one.uv - lattice.uv, axis=1)
    e2 = np.linalg.norm(it.uv - lattice.uv, axis=1)
    assert e1.mean() > 0.2 and e2.max() < 0.03
    assert it.iterations.min() > 2


def test_dft_registration_recovers_subpixel_shifts():
    y, x = np.mgrid[-10:11, -10:11].astype(float)
    shifts = np.array([[0.37, -1.62], [-2.25, 0.08], [0.0, 0.0]])
    img = np.stack([np.exp(-((x - dx) ** 2 + (y - dy) ** 2) / 8.0) for dx, dy in shifts])
    tpl = np.repeat(np.exp(-(x**2 + y**2) / 8.0)[None], 3, axis=0)
    np.testing.assert_allclose(register_translation(img, tpl, upsample=100), shifts, atol=0.011)


@pytest.mark.parametrize("method", list(METHODS))
def test_bad_input_is_flagged_never_silently_wrong(method):
    img = np.full((60, 80), 0.8)
    yy, xx = np.mgrid[0:60, 0:80]
    for u, v in ((40.3, 30.6), (1.2, 30.0)):  # a bead in the middle and one touching the border
        img = img - 0.6 * np.exp(-((xx - u) ** 2 + (yy - v) ** 2) / (2 * 1.8**2))
    rng = np.random.default_rng(0)
    img = img + rng.normal(0, 0.01, img.shape)
    guesses = np.array([[40.0, 30.0], [1.5, 30.0], [-5.0, 10.0], [np.nan, np.nan], [20.0, 45.0]])
    res = localize(img, guesses, diameter_px=6.0, method=method)
    reasons = list(res.reasons())
    tol = 0.3 if method == "gaussian_centroid" else 0.2  # one shot from a guess 0.7 px off
    assert reasons[0] == "ok" and np.linalg.norm(res.uv[0] - [40.3, 30.6]) < tol
    assert reasons[1] == "border"
    assert reasons[2] == "outside"
    assert reasons[3] == "invalid"
    assert reasons[4] == "flat"  # plain background: no bead
    assert np.all(np.isnan(res.uv[1:])) and np.all(np.isnan(res.sigma[1:]))


def test_bright_polarity_and_per_frame_guesses(lattice, lattice_frames):
    frames = 1.0 - lattice_frames[:3]
    guesses = np.repeat(lattice.uv[None], 3, axis=0) + 0.3
    res = localize(frames, guesses, diameter_px=lattice.diameter_px, polarity="bright")
    assert res.ok.all() and np.abs(res.uv - lattice.uv).max() < 0.15
    dark = localize(frames, guesses, diameter_px=lattice.diameter_px)
    assert (dark.status != STATUS["ok"]).mean() > 0.5 or np.nanmax(np.abs(dark.uv - lattice.uv)) > 1


def test_arguments_are_validated(lattice):
    img = lattice.expected()
    with pytest.raises(ValueError, match="method"):
        localize(img, lattice.uv, diameter_px=8, method="magic")
    with pytest.raises(ValueError, match="beta"):
        localize(img, lattice.uv, diameter_px=8, method="iterative_gaussian", beta=2.0)
    with pytest.raises(ValueError, match="guesses"):
        localize(img, lattice.uv[:, :1], diameter_px=8)
    with pytest.raises(ValueError, match="diameter_px"):
        localize(img, lattice.uv, diameter_px=[8, 9])
    with pytest.raises(ValueError, match="frames"):
        localize(np.zeros((2, 2, 2, 2)), lattice.uv, diameter_px=8)
    with pytest.raises(ValueError, match="polarity"):
        localize(img, lattice.uv, diameter_px=8, polarity="grey")
