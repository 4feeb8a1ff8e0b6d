"""core.tracking.smoothing.smooth_poses: the weights it returns are those of the fit it returns, also where
the robust rounds stop at MAX_ROUNDS before the weights settle (the weights computed after the last fit were
returned, the fit made with the ones before). The outlier search is off here: it would take that frame
before the robust rounds judge it (test_smoothing_outliers)."""

from __future__ import annotations

import numpy as np

from tests.core.tracking.test_smoothing import CENTER, _noisy, _truth


def test_the_weights_are_the_returned_fits(monkeypatch):
    import core.tracking.smoothing as sm

    T = _truth(80)
    sigma = np.tile([0.05, 0.05, 0.05, 0.2, 0.2, 0.2], (len(T), 1))
    P, _ = _noisy(T, sigma, 1.0, seed=3)
    off = np.eye(4)
    off[0, 3] = 0.5  # frame 40 0.5 mm off (10 sigma): the robust rounds down-weight it
    P[40] = off @ P[40]
    settled = sm.smooth_poses(P, sigma, center=CENTER, transients=None, outliers=None)
    assert settled.weights[40] < 0.5
    monkeypatch.setattr(sm, "MAX_ROUNDS", 0)  # one fit only, every frame at weight 1
    one = sm.smooth_poses(P, sigma, center=CENTER, transients=None, outliers=None)
    assert np.all(one.weights == 1.0)
    plain = sm.smooth_poses(P, sigma, center=CENTER, transients=None, outliers=None, robust=None)
    np.testing.assert_allclose(one.poses, plain.poses)
