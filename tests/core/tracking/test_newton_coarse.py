"""The Gauss–Newton search on coarse pixels: its half-steps and gradient by pixel size
(:func:`core.tracking.register_options.newton_step`) and the domain-corrected gradient of
:class:`core.tracking.engine_search.LevenbergMarquardt`. No renderer: fast."""

import numpy as np
import pytest

from core.tracking import register as reg
from core.tracking.engine_search import GRADIENTS, GaussNewtonStep, LevenbergMarquardt, gauss_newton_search
from core.tracking.engine_search import step_design as design
from core.tracking.register_options import (
    COARSE_NEWTON_MM,
    FINAL_STEP,
    Level,
    default_levels,
    newton_step,
)

# the levels before coarse pixels had their own (1024² views at 0.5 mm voxels: ~0.3 mm pixels at a foot)
_TODAY_NEWTON = Level(scale=1.0, method="gauss_newton", sigma=FINAL_STEP, max_generations=8, tol_x=0.02)


@pytest.mark.parametrize("px", [0.15, 0.2, 0.29, 0.4, 0.59, COARSE_NEWTON_MM])
def test_fine_pixels_keep_the_newton_levels_exactly(px):
    """Up to COARSE_NEWTON_MM (1024² and 512² views of a foot: about 0.2 and 0.4 mm at the bone) the
    levels are today's, to the bit."""
    assert newton_step(px) == (FINAL_STEP, {})
    (lv,) = default_levels(px, search="newton")
    assert lv == _TODAY_NEWTON and lv.to_dict() == _TODAY_NEWTON.to_dict()
    assert default_levels(px, search="global_newton")[-1] == _TODAY_NEWTON
    first, last = reg._newton_fallback(px)
    assert first.sigma == (2 * FINAL_STEP[0], 2 * FINAL_STEP[1]) and first.options == {}
    assert last == _TODAY_NEWTON


def test_coarse_pixels_take_wider_steps_and_the_corrected_gradient():
    step, opts = newton_step(1.6)  # 128² views of a foot
    assert step == (0.72, 1.44) and opts == {"gradient": "corrected"}
    assert newton_step(0.61) == ((0.27, 0.54), {"gradient": "corrected"})
    (lv,) = default_levels(1.6, search="newton")
    assert lv.sigma == (0.72, 1.44) and lv.options == {"gradient": "corrected"}
    assert default_levels(1.6, search="global_newton")[-1] == lv
    first, last = reg._newton_fallback(1.6)
    assert first.scale == 1.0 and first.sigma == (1.44, 2.88) and first.options == {"gradient": "corrected"}
    assert last == lv
    with pytest.raises(ValueError, match="mm_per_px"):
        newton_step(0.0)


class _Biased:
    """A quadratic cost whose moments' gradient misses a constant ``D`` (as the centre's fixed
    domain misses the domain's change): the scores are the cost's own."""

    def __init__(self, A, xs, D):
        self.A, self.xs, self.D = A, xs, D

    def f(self, X):
        d = np.atleast_2d(X) - self.xs
        return 0.5 * np.einsum("ij,jk,ik->i", d, self.A, d)

    def step(self, x, h):
        X = design(x, h)
        costs = self.f(X)
        g = self.A @ (x - self.xs) - self.D
        return GaussNewtonStep(np.array(x), np.array(h), costs, np.zeros((13, 2)), g, self.A.copy(),
                               np.zeros(2))


def test_the_corrected_gradient_finds_the_scores_minimum():
    rng = np.random.default_rng(0)
    Q = rng.normal(size=(6, 6))
    A = Q @ Q.T + 6 * np.eye(6)
    xs = np.array([0.4, -0.3, 0.2, 0.5, -0.6, 0.3])
    D = np.array([0.5, -0.4, 0.3, 0.1, 0.2, -0.3])
    cost = _Biased(A, xs, D)
    h = np.array([0.25] * 3 + [0.5] * 3)
    box = np.full(6, 5.0)
    kw = dict(step=h, lower=-box, upper=box, max_generations=8)
    biased = gauss_newton_search(cost, np.zeros(6), **kw)
    fixed = gauss_newton_search(cost, np.zeros(6), gradient="corrected", **kw)
    # the moments' search stops where their gradient vanishes, off the cost's minimum by A⁻¹D
    np.testing.assert_allclose(biased.x, xs + np.linalg.solve(A, D), atol=1e-3)
    np.testing.assert_allclose(fixed.x, xs, atol=1e-3)
    assert fixed.converged and fixed.reason == "tol_x"
    assert "corrected" in GRADIENTS
    with pytest.raises(ValueError, match="gradient"):
        LevenbergMarquardt(np.zeros(6), step=h, lower=-box, upper=box, gradient="scores?")
