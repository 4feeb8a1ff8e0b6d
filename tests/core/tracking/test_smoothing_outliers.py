"""core.tracking.smoothing.smooth_poses with a frame far off its neighbours. A frame off by 0.5 mm
(10 sigma) is pulled in by the robust weights. A frame the tracker FLAGGED 1-5 mm off is followed with
the defaults (measured here on test_smoothing's trajectory, 80 frames, sigma 0.05 mm / 0.2 deg, noise 1x,
seeds 3 and 4: the smoothed pose there 0.96-1.01 / 1.97-2.02 / 4.92-4.99 mm off, its weight 1): the
bursts take the spike (out and back) for a transient, and beyond ~2 mm no process noise keeps the scale k
within max_scale, so the least smoothing is taken. With flagged_weight=0 it is pulled in (0.007-0.033
mm). The strict xfail marks the defaults' behaviour as a known fault: it turns into a failure once the
smoother pulls such a frame in."""

from __future__ import annotations

import numpy as np
import pytest

from tests.core.tracking.test_smoothing import CENTER, _errors, _noisy, _truth


def _track(mm: float, seed: int = 3):
    T = _truth(80)
    sigma = np.tile([0.05, 0.05, 0.05, 0.2, 0.2, 0.2], (len(T), 1))
    P, _ = _noisy(T, sigma, 1.0, seed=seed)
    off = np.eye(4)
    off[0, 3] = mm
    P[40] = off @ P[40]
    return T, P, sigma, np.arange(len(T)) == 40


def test_a_frame_half_a_millimetre_off_is_pulled_in():
    from core.tracking.smoothing import smooth_poses

    T, P, sigma, _ = _track(0.5)
    s = smooth_poses(P, sigma, center=CENTER)
    assert np.linalg.norm(_errors(s.poses, T)[40, :3]) < 0.05 and s.weights[40] < 0.5


def test_a_flagged_frame_skipped_is_pulled_in():
    from core.tracking.smoothing import smooth_poses

    for mm in (1.0, 2.0, 5.0):
        T, P, sigma, fl = _track(mm)
        s = smooth_poses(P, sigma, center=CENTER, flagged=fl, flagged_weight=0.0)
        assert np.linalg.norm(_errors(s.poses, T)[40, :3]) < 0.05


@pytest.mark.xfail(strict=True, reason="known: the defaults follow a flagged frame 1-5 mm off (module docs)")
def test_a_flagged_frame_far_off_is_pulled_in_with_the_defaults():
    from core.tracking.smoothing import smooth_poses

    for mm in (1.0, 2.0, 5.0):
        T, P, sigma, fl = _track(mm)
        s = smooth_poses(P, sigma, center=CENTER, flagged=fl)
        assert np.linalg.norm(_errors(s.poses, T)[40, :3]) < 0.05, mm
