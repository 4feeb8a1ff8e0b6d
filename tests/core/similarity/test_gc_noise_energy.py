"""GC of debiased gradient magnitudes (``noise_energy``) and the noise-energy calibration helpers."""

import numpy as np
import pytest
from scipy import ndimage

from core.similarity.gradient import (
    debiased_magnitude,
    gradient_correlation,
    noise_gradient_energy,
    quantum_noise_energy,
    white_noise_gradient_gain,
)

N = 128
_Y, _X = np.mgrid[0:N, 0:N].astype(float)


def _bone(t: float) -> np.ndarray:
    """An elliptic bone's line integral shifted by ``t`` px along u, on a faint uniform layer (so
    that Ω, the DRR's support, is the whole image and does not move with the pose)."""
    r2 = (_X - 64 - t) ** 2 / 22**2 + (_Y - 64) ** 2 / 30**2
    return np.sqrt(np.clip(1 - r2, 0, None)) + 0.01


def _optimum(scores, ts) -> float:
    i = int(np.clip(np.argmax(scores), 1, len(ts) - 2))
    a, b, c = scores[i - 1 : i + 2]
    return float(ts[i] + 0.5 * (a - c) / (a - 2 * b + c) * (ts[1] - ts[0]))


def test_debiased_gc_optimum_closer_to_truth():
    # noise four times stronger on the right (fewer photons behind dense structure): it lifts the
    # fluoroscope's magnitudes there, and the plain correlation pulls the bone towards it
    sigma = 1.0
    sd = 0.05 * (1 + 3 / (1 + np.exp(-(_X - 75) / 4)))
    energy = white_noise_gradient_gain(fluoro_sigma=sigma) * ndimage.gaussian_filter(sd**2, sigma)
    ts = np.linspace(-0.75, 0.75, 7)
    drrs = [ndimage.gaussian_filter(_bone(t), sigma, mode="nearest") for t in ts]
    plain, debiased = [], []
    for k in range(4):
        f = _bone(0.0) + sd * np.random.default_rng(k).normal(size=(N, N))
        plain.append(_optimum([gradient_correlation(d, f, fluoro_sigma=sigma) for d in drrs], ts))
        debiased.append(_optimum([gradient_correlation(d, f, fluoro_sigma=sigma, noise_energy=energy)
                                  for d in drrs], ts))
    assert np.mean(plain) > 0.03  # the bias the noise brings (truth: 0)
    assert abs(np.mean(debiased)) < 0.5 * abs(np.mean(plain))


def test_noise_free_and_zero_energy_unchanged():
    d = ndimage.gaussian_filter(_bone(0.3), 1.0)
    f = _bone(0.0)
    assert gradient_correlation(d, f, noise_energy=0.0) == pytest.approx(gradient_correlation(d, f))
    assert gradient_correlation(f, f, noise_energy=np.zeros((N, N))) == pytest.approx(1.0)
    gu, gv = np.array([3.0, 0.1]), np.array([4.0, 0.0])
    np.testing.assert_allclose(debiased_magnitude(gu, gv, 1.0), [np.sqrt(24.0), 0.0])


def test_noise_energy_validation():
    f = _bone(0.0)
    with pytest.raises(ValueError, match="components"):
        gradient_correlation(f, f, components=True, noise_energy=1.0)
    with pytest.raises(ValueError, match="shape"):
        gradient_correlation(f, f, noise_energy=np.ones((4, 4)))
    with pytest.raises(ValueError, match="non-negative"):
        gradient_correlation(f, f, noise_energy=-1.0)


def test_flat_frames_measure_the_white_quantum_energy():
    # two Poisson frames through a half-transmission plate: the energy at full fluence is the
    # filter's white-noise gain over the quanta per pixel; a frame's map is that over its fluence
    g = np.random.default_rng(0)
    n0 = 400.0
    a, b = (g.poisson(0.5 * n0, (N, N)) / n0 for _ in range(2))
    want = white_noise_gradient_gain(fluoro_sigma=1.0) / n0
    assert noise_gradient_energy(a, b, fluoro_sigma=1.0) == pytest.approx(want, rel=0.05)
    fl = np.full((N, N), 0.25)
    np.testing.assert_allclose(quantum_noise_energy(fl, want), 4 * want)
    assert white_noise_gradient_gain() == pytest.approx(0.375)  # Sobel, gain-normalised


@pytest.mark.parametrize("opts", [{}, dict(threshold=0.02, fluoro_sigma=1.0)])
def test_device_scores_match_the_reference(talus_case, opts):
    from core.imaging.edges import gradient
    from core.similarity import similarity
    from core.similarity.batched import BatchedMetric

    c = talus_case
    rng = np.random.default_rng(0)
    poses = c.perturb(rng.normal(0, 2.0, (3, 3)), rng.normal(0, np.deg2rad(2), (3, 3)))
    batch, drrs = c.render(poses), c.drrs(poses)
    energy = []
    for f in c.fluoro:  # a share of the fluoroscope's squared magnitudes, larger where it is darker
        g2 = np.sum(np.square(gradient(ndimage.gaussian_filter(f, opts.get("fluoro_sigma", 0.0)))), axis=0)
        w = np.exp(f - f.mean())
        energy.append(0.3 * np.median(g2) * w / w.mean())
    bm = BatchedMetric("gc", list(c.fluoro), device="cpu", noise_energy=energy, **opts)
    got = bm.evaluate(batch)
    ref = np.array([[similarity("gc", drrs[v][b], c.fluoro[v], noise_energy=energy[v], **opts)
                     for v in range(2)] for b in range(3)])
    np.testing.assert_allclose(got.item[:, :, 0], ref, atol=1e-4, rtol=0)
    plain = BatchedMetric("gc", list(c.fluoro), device="cpu", **opts).evaluate(batch).pose
    assert np.max(np.abs(plain - got.pose)) > 1e-3
    with pytest.raises(ValueError, match="noise_energy"):
        BatchedMetric("gc", list(c.fluoro), device="cpu", components=True, noise_energy=energy)
    with pytest.raises(ValueError, match="noise_energy"):
        BatchedMetric("ncc", list(c.fluoro), device="cpu", noise_energy=energy)
