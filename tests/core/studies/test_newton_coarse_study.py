"""The coarse-view Gauss–Newton study's trace (:func:`core.studies.tracking.newton_coarse.traced`)
on a scripted quadratic: no renderer, fast."""

import numpy as np

from core.studies.tracking.newton_coarse import traced
from core.tracking import engine_search as es
from core.tracking.engine_search import GaussNewtonStep, gauss_newton_search
from core.tracking.engine_search import step_design as design


class _Quadratic:
    def __init__(self, A, xs, D):
        self.A, self.xs, self.D = A, xs, D

    def step(self, x, h):
        d = design(x, h) - self.xs
        costs = 0.5 * np.einsum("ij,jk,ik->i", d, self.A, d)
        return GaussNewtonStep(np.array(x), np.array(h), costs, np.zeros((13, 2)),
                               self.A @ (x - self.xs) - self.D, self.A.copy(), np.zeros(2))


def test_traced_records_each_step_and_restores_the_search():
    A = np.diag([4.0, 3.0, 2.0, 1.0, 1.5, 2.5])
    xs = np.array([0.3, -0.2, 0.1, 0.4, -0.3, 0.2])
    cost = _Quadratic(A, xs, np.array([0.2, 0, 0, 0, 0, -0.1]))
    h = np.array([0.25] * 3 + [0.5] * 3)
    box = np.full(6, 5.0)
    tell = es.LevenbergMarquardt.tell
    records: list = []
    with traced(records):
        r = gauss_newton_search(cost, np.zeros(6), step=h, lower=-box, upper=box, gradient="corrected")
    assert es.LevenbergMarquardt.tell is tell
    (rec,) = records
    assert len(rec) == r.generations and rec[-1]["reason"] == "tol_x"
    # the moments' secant is the search's α: the scores are the moments' quadratic here
    later = [row for row in rec if "secant_moments" in row]
    assert later and all(abs(row["secant_moments"] - 1.0) < 1e-3 for row in later)
    assert np.allclose(rec[0]["correction"], [0.2, 0, 0, 0, 0, -0.1], atol=1e-4)
    np.testing.assert_allclose(r.x, xs, atol=1e-3)
