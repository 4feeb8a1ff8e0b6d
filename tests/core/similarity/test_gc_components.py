"""GC of the gradient components (``components=True``): numpy reference and the device metric."""

import numpy as np
import pytest

from core.similarity import gradient_correlation, similarity
from core.similarity.batched import BatchedMetric


def test_reference_is_the_mean_of_the_component_correlations():
    rng = np.random.default_rng(1)
    y, x = np.mgrid[:48, :48]
    img = np.exp(-((x - 20.0) ** 2 + (y - 26.0) ** 2) / 60.0) + 0.3 * (x > 30)
    assert gradient_correlation(img, img, components=True) == pytest.approx(1.0)
    noisy = img + rng.normal(0, 0.05, img.shape)
    got = gradient_correlation(img, noisy, components=True)
    from core.imaging.edges import gradient

    (du, dv), (fu, fv) = gradient(img, operator="sobel"), gradient(noisy, operator="sobel")
    want = 0.5 * (np.corrcoef(du.ravel(), fu.ravel())[0, 1] + np.corrcoef(dv.ravel(), fv.ravel())[0, 1])
    assert got == pytest.approx(want, abs=1e-7)  # rounding-level gradients count as 0
    # a gradient of opposite sign scores -1 (the magnitudes would not tell)
    assert gradient_correlation(img, -img, components=True) == pytest.approx(-1.0)
    assert gradient_correlation(img, -img) == pytest.approx(1.0)


@pytest.mark.parametrize("opts", [{}, dict(dilate=1, threshold=0.02, fluoro_sigma=1.0)])
def test_device_scores_match_the_reference(talus_case, opts):
    c = talus_case
    rng = np.random.default_rng(0)
    t = rng.normal(0, 2.0, (4, 3))
    r = rng.normal(0, np.deg2rad(2), (4, 3))
    t[0] = r[0] = 0
    poses = c.perturb(t, r)
    batch, drrs = c.render(poses), c.drrs(poses)
    bm = BatchedMetric("gc", list(c.fluoro), device="cpu", components=True, **opts)
    got = bm.evaluate(batch)
    ref = np.array([[similarity("gc", drrs[v][b], c.fluoro[v], components=True, **opts) for v in range(2)]
                    for b in range(4)])
    np.testing.assert_allclose(got.item[:, :, 0], ref, atol=1e-4, rtol=0)
    np.testing.assert_allclose(got.pose, ref.mean(axis=1), atol=1e-4, rtol=0)
    mag = BatchedMetric("gc", list(c.fluoro), device="cpu", **opts).evaluate(batch).pose
    assert np.max(np.abs(mag - got.pose)) > 1e-3  # a different metric, not the magnitudes again


def test_components_only_for_gc(talus_case):
    with pytest.raises(ValueError, match="components"):
        BatchedMetric("ncc", list(talus_case.fluoro), device="cpu", components=True)
