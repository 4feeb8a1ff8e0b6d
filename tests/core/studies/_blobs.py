"""Test images shared by the studies' tests."""

import numpy as np


def blobs(p, shape=(40, 48)):
    """Six Gaussian blobs, blob k shifted along u (k even) or v (k odd) by p[k] pixels."""
    v, u = np.mgrid[0:shape[0], 0:shape[1]].astype(float)
    out = np.zeros(shape)
    for k in range(6):
        cu, cv = 8 + 16 * (k % 3), 12 + 16 * (k // 3)
        du, dv = (p[k], 0.0) if k % 2 == 0 else (0.0, p[k])
        out += np.exp(-((u - cu - du) ** 2 + (v - cv - dv) ** 2) / (2 * 2.5**2))
    return out
