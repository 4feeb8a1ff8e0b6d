"""The stage's rotation vector through scipy's NumPy rotation backend (core.tracking.likelihood_host._rotvec)
against scipy's public Rotation: the same values to the bit, random and small rotations."""

from __future__ import annotations

import numpy as np


def test_rotvec_is_scipys():
    from scipy.spatial.transform import Rotation

    from core.tracking.likelihood_host import _rotvec

    rng = np.random.default_rng(7)
    for i in range(600):
        if i % 2:
            R = Rotation.random(random_state=rng).as_matrix()
        else:  # (down to the series scipy takes for small angles)
            R = Rotation.from_rotvec(rng.normal(size=3) * 10.0 ** rng.uniform(-9, -1)).as_matrix()
        Rm = np.ascontiguousarray(R.reshape(1, 3, 3))
        np.testing.assert_array_equal(_rotvec(Rm), Rotation.from_matrix(Rm, assume_valid=True).as_rotvec())
