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


def test_singles_from_the_command_line_take_the_correction_and_the_trial(monkeypatch, capsys):
    """--singles 128 needs --correction model (no grid is found at 128²); --trial hard as measured."""
    from core.studies.tracking import newton_coarse

    calls = []
    monkeypatch.setattr(newton_coarse, "singles", lambda **kw: calls.append(kw) or {})
    assert newton_coarse.main(["--singles", "128", "--correction", "model"]) == 0
    assert calls[-1]["pixels"] == 128 and calls[-1]["correction"] == "model"
    assert newton_coarse.main(["--singles", "192", "--trial", "hard"]) == 0
    k = calls[-1]
    assert k["trial"] == "hard" and k["voxel"] == 1.0 and k["starts"] == 4
    assert list(k["frames"]) == [0, 1, 2, 3, 4]
    capsys.readouterr()
