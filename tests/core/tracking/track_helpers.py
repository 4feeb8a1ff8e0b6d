"""A bone's poses in smooth, walking-like motion with registration noise, shared by the trajectory
check's tests (test_flags_post) and the silent-failure candidate checks' (test_silent_checks)."""

from __future__ import annotations

import numpy as np

from core.geometry.transforms import pose_from_params

C = np.array([5.0, -3.0, 40.0])


def walking_track(n=40, noise=(0.01, 0.05), seed=1, shift=None) -> np.ndarray:
    """``(n, 4, 4)`` poses: translation (mm) and rotation (degrees) smooth in time plus Gaussian
    noise ``noise`` (mm, degrees); ``shift(k, p)`` may change frame ``k``'s parameters ``p`` (mm,
    radians) in place before the pose is made."""
    g = np.random.default_rng(seed)
    t = np.arange(n) / n
    P = []
    for k in range(n):
        p = np.r_[20 * t[k] + 5 * t[k] ** 2, 3 * np.sin(2 * t[k]), -4 * t[k],
                  np.radians([10 * t[k], -6 * t[k] ** 2, 4 * np.sin(3 * t[k])])]
        p[:3] += g.normal(0, noise[0], 3)
        p[3:] += np.radians(g.normal(0, noise[1], 3))
        if shift is not None:
            shift(k, p)
        P.append(pose_from_params(p, center=C, base=np.eye(4)))
    return np.array(P)
