import numpy as np
import pytest

from core.tracking.confidence import curvature_confidence, stencil


def test_stencil_shape():
    S = stencil(6)
    assert S.shape == (73, 6) and np.all(S[0] == 0)
    assert len({tuple(r) for r in S}) == 73


def test_curvature_recovers_the_hessian_and_scales_with_noise():
    H = np.diag([4.0, 2.0, 1.0, 0.5, 0.25, 8.0])
    H[0, 1] = H[1, 0] = 0.3

    def make(noise, seed=0):
        g = np.random.default_rng(seed)
        return lambda X: 0.5 * np.einsum("bi,ij,bj->b", X, H, X) + noise * g.normal(size=len(X))

    quiet = curvature_confidence(make(0.0), np.zeros(6), step=(0.5, 0.5))
    np.testing.assert_allclose(quiet.hessian, H, atol=1e-9)
    assert quiet.well_posed and quiet.cost_noise < 1e-9
    loud = curvature_confidence(make(1e-3), np.zeros(6), step=(0.5, 0.5))
    assert loud.cost_noise == pytest.approx(1e-3, rel=0.35)
    assert np.all(loud.sigma > quiet.sigma)
    # the least curved direction is the least certain
    assert np.argmax(loud.sigma) == 4 and np.argmin(loud.sigma) == 5
    expected = np.sqrt(np.diag(2 * loud.cost_noise * np.linalg.inv(loud.hessian)))
    np.testing.assert_allclose(loud.sigma, expected)


def test_flat_direction_is_unbounded():
    f = lambda X: (X[:, :5] ** 2).sum(axis=1)  # noqa: E731  (rz does not change the cost)
    c = curvature_confidence(f, np.zeros(6))
    assert not c.well_posed and np.isinf(c.sigma[5]) and np.all(np.isfinite(c.sigma[:5]))
    assert c.to_dict()["sigma"][5] is None
    with pytest.raises(ValueError, match="x"):
        curvature_confidence(f, np.zeros(5))
