"""core.studies.tracking.stage_contraction's measures on a stand-in engine (a quadratic χ² whose
curvature is θ times Gauss–Newton's): Gauss–Newton's contraction 1 - θ, θ per axis and along the
weakest direction, and the frames part's summary."""

from __future__ import annotations

import numpy as np
import pytest

from core.studies.tracking.stage_contraction import _summary, curvature_ratios, gauss_newton


class _Engine:
    def __init__(self, theta: float) -> None:
        self.H = np.diag([4.0, 3.0, 2.0, 1.5, 1.0, 0.5])
        self.theta = theta
        self.x_star = np.array([0.1, -0.05, 0.08, 0.2, -0.1, 0.05])

    def step(self, x, h):
        e = np.asarray(x, dtype=float) - self.x_star
        return {"JJ": self.H / self.theta, "Jr": -self.H @ e, "chi2": float(e @ self.H @ e)}


def test_gauss_newton_contracts_by_one_minus_theta_and_the_ratios_find_theta():
    eng = _Engine(0.7)
    g = gauss_newton(eng, tol=1e-6, iters=60)
    np.testing.assert_allclose(g["x"], eng.x_star, atol=1e-5)
    assert g["contraction"] == pytest.approx([0.3] * len(g["contraction"]), abs=1e-3)
    r = curvature_ratios(eng, g["x"])
    assert r["theta_axes"] == pytest.approx([0.7] * 6, abs=1e-3)
    assert r["theta_weakest"] == pytest.approx(0.7, abs=1e-3)
    assert gauss_newton(_Engine(1.0))["steps"] <= 2  # (the model's curvature: one step, one to confirm)


def test_summary_reports_steps_spread_and_error_over_the_bound():
    rows = [{"frame": f, "reference": "similarity",
             "fewer": {"steps": {"truth": 3, "similarity": 4},
                       "error": {"truth": [0.1, 0, 0, 0.2, 0, 0], "similarity": [0.3, 0, 0.4, 0, 0, 0.5]},
                       "spread": [0.2, 0, 0.4, 0.2, 0, 0.5]}} for f in (1, 2)]
    s = _summary(rows, ["fewer"], {"rms_mm": 0.25, "rms_deg": 1.0})["fewer"]
    assert s["steps_mean"] == 3.5 and s["steps_from_reference"] == 4.0
    assert s["error_rms_mm"] == pytest.approx(0.5) and s["over_bound_mm"] == pytest.approx(2.0)
    assert s["error_rms_deg"] == pytest.approx(0.5) and s["over_bound_deg"] == pytest.approx(0.5)
    assert s["spread_max_mm"] == pytest.approx(0.4)
