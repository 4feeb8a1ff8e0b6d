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


def _scripted_step(x, h, H, g, d, c0, rough=None):
    """A step at ``x`` whose 13 scores have the central differences ``d`` about a quadratic of
    Hessian ``H`` (plus ``rough``, a pattern the fit leaves as residuals) and whose moments give
    ``g`` and ``H``."""
    c = np.empty(13)
    c[0] = c0
    q = 0.5 * h * h * np.diag(H)
    c[1::2] = c0 + h * d + q
    c[2::2] = c0 - h * d + q
    if rough is not None:
        c = c + rough
    return GaussNewtonStep(np.array(x, float), np.array(h, float), c, np.zeros((13, 2)), np.array(g, float),
                           np.array(H, float), np.zeros(2))


def test_the_secant_alpha_holds_the_correction_fixed():
    """α is the moments' gradient change along the step over the model's: the correction's own
    change between the step's ends (its running mean moving) is no curvature."""
    H = np.diag([4.0, 3.0, 2.0, 1.0, 1.5, 2.5])
    h = np.array([0.25] * 3 + [0.5] * 3)
    box = np.full(6, 5.0)
    lm = LevenbergMarquardt(np.zeros(6), step=h, lower=-box, upper=box, gradient="corrected")
    xs = np.array([0.3, -0.2, 0.1, 0.4, -0.3, 0.2])
    x1 = np.zeros(6)
    g1 = 0.8 * H @ (x1 - xs)  # the true curvature is 0.8 H
    lm.tell(_scripted_step(x1, h, H, g1, g1 + 0.0, 1.0))  # the scores agree with the moments here
    x2 = x1 + np.array([0.1, -0.05, 0.05, 0.2, -0.1, 0.1])
    g2 = 0.8 * H @ (x2 - xs)
    D2 = np.array([0.0, 0.0, 0.0, 0.3, 0.0, 0.0])  # ... and differ here: the correction's mean moves
    lm.tell(_scripted_step(x2, h, H, g2, g2 + D2, 0.9))
    assert lm.best.x is not None and np.allclose(lm.best.x, x2)
    assert lm.alpha == pytest.approx(0.8, abs=1e-12)
    # the corrected gradients' change would have read the correction's move as curvature
    dx = x2 - x1
    assert (0.8 * dx @ H @ dx + 0.5 * D2 @ dx) / (dx @ H @ dx) > 0.9


def test_the_correction_is_shrunk_along_the_hessians_eigenvectors():
    """A correction significant in two coordinates whose part along the Hessian's weakest
    direction is within its noise: that part is dropped (it would move the pose most), the
    strong part kept; shrunk by coordinates, it moved the search's end along the weak direction."""
    th = np.radians(12.0)  # the weak direction: mostly the last coordinate, some of the fourth
    R = np.eye(6)
    R[3, 3] = R[5, 5] = np.cos(th)
    R[3, 5], R[5, 3] = -np.sin(th), np.sin(th)
    lam = np.array([0.05, 0.04, 0.045, 0.03, 0.035, 0.0015])
    H = R @ np.diag(lam) @ R.T
    uw, us = R[:, 5], R[:, 3]
    h = np.array([0.3] * 3 + [0.6] * 3)
    # the 13 scores' roughness: the same pattern at every step (the cost's own), left by the fit
    rough = np.zeros(13)
    rough[0], rough[1::2], rough[2::2] = -6e-3, 1e-3, 1e-3
    D = 0.006 * us + 0.0004 * uw  # the scores' differences less the moments' gradient
    xs = np.zeros(6)
    box = np.full(6, 5.0)
    lm = LevenbergMarquardt(np.array([0.1, 0, 0, 0.2, 0, 0.8]), step=h, lower=-box, upper=box,
                            gradient="corrected", max_generations=8)
    while (x := lm.ask()) is not None:
        g = H @ (x - xs)
        lm.tell(_scripted_step(x, h, H, g, g + D, 0.5 * (x - xs) @ H @ (x - xs), rough))
    r = lm.result()
    # the weak part's noise: σ_c² / 2h², σ_c the residuals' RMS; the part itself well below it
    from core.tracking.engine_search import _residuals

    _, res = _residuals(_scripted_step(xs, h, H, np.zeros(6), D, 0.0, rough), 1.0)
    var = float(res @ res) / 6.0 / (2.0 * h * h)
    assert (0.0004 ** 2) < 0.5 * (uw * uw) @ var and (0.006 ** 2) > 3 * (us * us) @ var
    # the strong part moves the end as its (shrunk) correction says; the weak one not at all
    assert abs(uw @ (r.x - xs)) < 0.02
    assert us @ (r.x - xs) == pytest.approx(-0.006 / lam[3], rel=0.35)
