"""core.tracking.engine_likelihood.same_array is numpy.array_equal of two arrays, NaN included: an array
with a NaN is not equal to itself (a NaN pose is not taken for the last design's centre)."""

from __future__ import annotations

import numpy as np


def test_same_array_is_array_equal():
    from core.tracking.engine_likelihood import same_array

    x = np.array([0.1, -0.2, 0.3, 0.0, 1e-3, 2.0])
    nan = x.copy()
    nan[2] = np.nan
    cases = [(x, x), (x, x.copy()), (x, -x), (x, x[:5]), (nan, nan), (nan, nan.copy()),
             (np.zeros(6), -np.zeros(6)), (np.array([[1, 2]], np.int32), np.array([[1, 2]], np.int32)),
             (x.reshape(2, 3), x.reshape(3, 2))]
    for a, b in cases:
        assert same_array(a, b) == np.array_equal(a, b), (a, b)
