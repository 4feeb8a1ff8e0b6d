"""core.studies.tracking.stage_cuts' comparison of two variants' stage results (poses over the bound's
σ, the σ ratio, steps) and its error over the bound."""

from __future__ import annotations

import numpy as np
import pytest

from core.studies.tracking.stage_cuts import _over_bound, compare


def test_compare_in_units_of_the_bounds_sigma():
    sig = np.array([0.1, 0.1, 0.2, 0.5, 0.5, 1.0])
    base = [{"error": [0.0] * 6, "sigma": [1.0] * 6, "steps": 3},
            {"error": [0.1, 0, 0, 0, 0, 0], "sigma": [2.0] * 6, "steps": 2}]
    other = [{"error": [0.02, 0, 0, 0, 0, 0], "sigma": [1.1] * 6, "steps": 3},
             {"error": [0.1, 0, 0, 0, 0, 0.5], "sigma": [2.0] * 6, "steps": 4}]
    c = compare(base, other, sig)
    assert c["pose_over_sigma_max"] == pytest.approx(0.5)  # (0.5 degrees over 1.0)
    assert c["pose_over_sigma_rms"][0] == pytest.approx(np.sqrt(0.2 ** 2 / 2), abs=1e-4)
    assert c["sigma_ratio_max_departure"] == pytest.approx(0.1)
    assert c["sigma_ratio_mean"][0] == pytest.approx(1.05)
    assert c["steps_mean"] == [2.5, 3.5]


def test_over_bound():
    rows = [{"error": [0.3, 0.4, 0, 1.0, 0, 0]}, {"error": [0, 0, 0.5, 0, 0, 1.0]}]
    assert _over_bound(rows, {"rms_mm": 0.25, "rms_deg": 0.5}) == [2.0, 2.0]
