"""core.tracking.smoothing on short tracks. With a handful of innovations the scale ``k`` cannot be told
from the data: the concentrated likelihood flattens as the process noise grows, ``k`` falls towards 0 and
the smoothed σ with it. Before MIN_INNOVATIONS, 8 frames of the tests' walk (σ 0.05 mm) with a flagged
frame 2 mm off had ``k`` < 0.1 on 70 of 72 coordinates over 12 draws and covered 4 % of the errors within
2σ (σ_x 1e-4 mm against errors of 0.05-0.16 mm); a coordinate with fewer than MIN_INNOVATIONS innovations
(frames taken for outliers not counted) now keeps the σ given (``k`` = 1). Longer tracks are unchanged."""

from __future__ import annotations

import numpy as np

from tests.core.tracking.test_smoothing import CENTER, _noisy, _truth

SIGMA = [0.05, 0.05, 0.05, 0.2, 0.2, 0.2]


def _run(n: int, seed: int, outlier: bool):
    from core.tracking.smoothing import smooth_poses

    T = _truth(80)[:n]
    sigma = np.tile(SIGMA, (n, 1))
    P, _ = _noisy(T, sigma, 1.0, seed=seed)
    fl = np.zeros(n, bool)
    if outlier:
        P[n // 2, 0, 3] += 2.0
        fl[n // 2] = True
    s = smooth_poses(P, sigma, center=CENTER, flagged=fl)
    e = np.array([(s.poses[k, :3, :3] @ CENTER + s.poses[k, :3, 3]) - (T[k, :3, :3] @ CENTER + T[k, :3, 3])
                  for k in range(n)])
    keep = np.ones(n, bool)
    keep[n // 2] = not outlier
    return s, np.abs(e[keep]) <= 2 * s.sigma[keep, :3]


def test_a_short_track_keeps_the_sigma_given():
    from core.tracking.smoothing import MIN_INNOVATIONS

    assert MIN_INNOVATIONS == 10
    inside = []
    for n, outlier in ((6, False), (8, True), (10, True)):
        for seed in range(4):
            s, ok = _run(n, seed, outlier)
            assert np.all(s.scale == 1.0) and np.all(s.correlation == 0.0), (n, seed)
            assert s.outliers == ([n // 2] if outlier else [])
            inside.append(ok)
    assert np.mean(np.concatenate(inside)) > 0.85  # (0.04-0.74 for 8-12 frames with the outlier before)


def test_a_longer_track_still_fits_its_scale():
    for seed in range(2):
        s, ok = _run(20, seed, True)
        assert s.outliers == [10] and not np.allclose(s.scale, 1.0) and ok.mean() > 0.6
