"""core.tracking.smoothing.smooth_poses with errors correlated from frame to frame (AR(1), coefficient
0.6): the smoother's ML finds the correlation and its sigma covers the errors far better than when it takes
them as independent (correlated=False); on independent errors it finds next to none and changes little."""

from __future__ import annotations

import numpy as np

from core.geometry.transforms import pose_from_params
from tests.core.tracking.test_smoothing import CENTER, _errors, _truth


def _ar_track(phi: float, n: int = 120, seed: int = 0):
    T = _truth(n)
    sigma = np.tile([0.05, 0.05, 0.05, 0.2, 0.2, 0.2], (n, 1))
    g = np.random.default_rng(seed)
    e = np.zeros((n, 6))
    e[0] = g.normal(size=6)
    for t in range(1, n):
        e[t] = phi * e[t - 1] + np.sqrt(1 - phi ** 2) * g.normal(size=6)
    E = e * sigma
    P = np.array([pose_from_params(np.r_[x[:3], np.radians(x[3:])], center=CENTER, base=b)
                  for x, b in zip(E, T, strict=True)])
    return T, P, sigma


def _coverage(s, T):
    return float(np.mean(np.abs(_errors(s.poses, T)) <= 2 * s.sigma))


def test_correlated_errors_found_and_covered():
    from core.tracking.smoothing import smooth_poses

    T, P, sigma = _ar_track(0.6)
    on = smooth_poses(P, sigma, center=CENTER)
    off = smooth_poses(P, sigma, center=CENTER, correlated=False)
    assert np.all(off.correlation == 0) and on.correlation.mean() > 0.3
    assert _coverage(on, T) > _coverage(off, T) + 0.1
    assert on.to_dict()["correlation"] == np.round(on.correlation, 3).tolist()


def test_independent_errors_left_alone():
    from core.tracking.smoothing import smooth_poses

    T, P, sigma = _ar_track(0.0, seed=1)
    on = smooth_poses(P, sigma, center=CENTER)
    off = smooth_poses(P, sigma, center=CENTER, correlated=False)
    assert on.correlation.max() <= 0.2
    assert abs(_coverage(on, T) - _coverage(off, T)) < 0.05
