"""The Gauss–Newton engine with GC of the gradient components (``components`` option)."""

from __future__ import annotations

import numpy as np
import pytest

from core.geometry.transforms import pose_from_params
from core.studies.tracking.acceptance import pose_errors
from core.tracking.cost import MetricTerm, RegistrationCost, prepare_frame, search_roi
from core.tracking.engine import GaussNewtonCost, gauss_newton_search, step_design, supports

H = np.array([0.25] * 3 + [0.5] * 3)
BOX = np.array([5.0] * 6)
TERM = MetricTerm("gc", 1.0, {"fluoro_sigma_mm": 0.3, "drr_sigma_mm": 0.3, "components": True})


def _setup(sc, frame_no, offset):
    m, r = sc["model"], sc["renderer"]
    frame = prepare_frame(sc["fluence"](frame_no))
    truth = sc["scene"].poses(frame_no)[0]
    off = np.asarray(offset, dtype=float)
    start = pose_from_params(np.r_[off[:3], np.radians(off[3:])], center=m.centroid, base=truth)
    roi = search_roi(r, start, 0, views=(0, 1), center=m.centroid, reach_mm=7.6, points=m.outline)
    gn = GaussNewtonCost(r, bone=0, views=(0, 1), scale=1.0, term=TERM)
    gn.set_frame(frame, base_pose=start, center=m.centroid, roi=roi)
    return frame, truth, start, roi, gn


def test_engine_scores_as_the_cost_and_its_gradient_is_the_costs(talus_scene):
    sc = talus_scene
    assert supports([TERM])
    frame, _, start, roi, gn = _setup(sc, 2, [1.0, -0.8, 0.6, 1.0, -1.0, 1.5])
    rc = RegistrationCost(sc["renderer"], frame, bone=0, base_pose=start, center=sc["model"].centroid,
                          roi=roi, terms=(TERM,))
    X = step_design(np.zeros(6), H)
    np.testing.assert_allclose(gn(X), rc(X), atol=1e-6)
    plain = RegistrationCost(sc["renderer"], frame, bone=0, base_pose=start, center=sc["model"].centroid,
                             roi=roi, terms=(MetricTerm("gc", 1.0, {"fluoro_sigma_mm": 0.3,
                                                                    "drr_sigma_mm": 0.3}),))
    assert np.max(np.abs(plain(X) - rc(X))) > 1e-4  # not the magnitudes' cost
    s = gn.step(np.zeros(6), H)
    np.testing.assert_allclose(s.costs, rc(X), atol=1e-6)
    cd = (s.costs[1::2] - s.costs[2::2]) / (2 * H)
    np.testing.assert_allclose(s.g, cd, rtol=0.05, atol=2e-3 * np.abs(cd).max())
    assert np.all(np.linalg.eigvalsh(s.H) > 0)
    np.testing.assert_allclose(s.r, s.view_scores[0], atol=1e-5)


@pytest.mark.parametrize("offset", [[1.5, -1.0, 1.0, 1.5, -1.0, 2.0], [-2.0, 1.5, -1.0, -2.0, 1.5, -1.0]])
def test_local_search_recovers_a_known_pose(talus_scene, offset):
    """Rendered at a known pose, started 1–2 mm / 1–2° off: back within 0.02 mm / 0.05°."""
    sc = talus_scene
    _, truth, _, _, gn = _setup(sc, 3, offset)
    res = gauss_newton_search(gn, np.zeros(6), step=H, lower=-BOX, upper=BOX, tol_x=0.01, max_generations=10)
    assert res.converged and res.reason == "tol_x"
    err = pose_errors(gn.poses(res.x[None])[0], truth, sc["model"].centroid)
    assert np.linalg.norm(err[:3]) < 0.02 and np.linalg.norm(err[3:]) < 0.05, err
