"""The likelihood stage's refinement with the steps' secant length (engine_likelihood.SECANT_STEPS,
likelihood_steps.SecantScale) on a stand-in for the engine's device work (a quadratic χ² whose
curvature is below Gauss–Newton's, as on the trial's blurred frames: core.studies.tracking.
stage_contraction): the same pose in fewer steps, θ carried to the next refinement, and
convergence where the curvature's ratio differs by direction."""

from __future__ import annotations

import numpy as np
import pytest


class _Quadratic:
    """A stand-in for the engine's device work: χ² = χ²₀ + (x - x*)ᵀ H (x - x*), ``JᵀWJ`` H's
    eigenvalues over ``theta`` (one number, or one per eigenvector, the weakest first)."""

    def __init__(self, theta) -> None:
        rng = np.random.default_rng(3)
        Q = np.linalg.qr(rng.normal(size=(6, 6)))[0]
        w = np.array([2.0, 3.0, 5.0, 10.0, 20.0, 40.0])
        self.H = (Q * w) @ Q.T
        self.JJ = (Q * (w / np.broadcast_to(np.asarray(theta, dtype=float), (6,)))) @ Q.T
        self.x_star = np.array([0.2, -0.1, 0.15, 0.3, -0.2, 0.1])
        self.x = None

    def result(self) -> dict:
        e = self.x - self.x_star
        return {"chi2": 1000.0 + float(e @ self.H @ e), "JJ": self.JJ, "Jr": -self.H @ e}


def _engine(theta):
    from core.tracking.engine_likelihood import LikelihoodEngine

    q = _Quadratic(theta)

    class Stand(LikelihoodEngine):
        def __init__(self) -> None:  # (none of the device state)
            self.n_pixels, self._theta, self._fast, self._cov_host = 1000, 1.0, False, None

        def step_launch(self, x, h, *, reuse=False, chord=False):
            q.x = np.asarray(x, dtype=float)

        def step_result(self):
            return q.result()

    return Stand(), q


@pytest.mark.parametrize("secant", [False, True])
def test_refinement_reaches_the_same_pose_in_fewer_steps(monkeypatch, secant):
    """The engine's refinement to tol (no STOP_PRED stop) on a χ² whose curvature is 0.6 of
    Gauss–Newton's: the same pose (to tol), in 5 steps with SECANT_STEPS instead of 12, and the
    engine keeps the θ it measured (at least 1/1.6) for its next refinement."""
    import core.tracking.engine_likelihood as el

    monkeypatch.setattr(el, "STOP_PRED", 0.0)
    monkeypatch.setattr(el, "SECANT_STEPS", secant)
    eng, q = _engine(0.6)
    out = eng.refine(np.zeros(6), iters=40, tol=(1e-5, 1e-5), sandwich=False)
    np.testing.assert_allclose(out["x"], q.x_star, atol=1e-4)
    if secant:
        assert out["iterations"] <= 5 and eng._theta == pytest.approx(1 / 1.6)
    else:
        assert out["iterations"] >= 10 and eng._theta == 1.0  # (each step 0.4 of the one before)


def test_secant_steps_converge_where_the_curvature_ratio_differs_by_direction(monkeypatch):
    """θ 0.35 along JᵀWJ's weakest direction and 1 along its stiffest (the step's θ set by the weak
    one): the secant length still converges to the same pose (a step at most 1.6 Gauss–Newton's:
    -0.6 a step along the stiff one), in fewer steps than Gauss–Newton over four refinements, each
    after the first taking the θ of the one before (``reuse``: the robust round's)."""
    import core.tracking.engine_likelihood as el

    monkeypatch.setattr(el, "STOP_PRED", 0.0)
    n = {}
    for secant in (False, True):
        monkeypatch.setattr(el, "SECANT_STEPS", secant)
        eng, q = _engine([0.35, 0.6, 0.8, 0.9, 0.95, 1.0])
        n[secant] = []
        for rep in range(4):
            out = eng.refine(np.full(6, 0.1 * rep), iters=60, tol=(1e-5, 1e-5), sandwich=False, reuse=rep > 0)
            np.testing.assert_allclose(out["x"], q.x_star, atol=1e-4)
            n[secant].append(out["iterations"])
    assert sum(n[True]) < sum(n[False])


def test_a_frames_first_refinement_starts_from_gauss_newton(monkeypatch):
    """A refinement without ``reuse`` (a frame's first) starts at θ 1 whatever the engine measured
    before, so a frame's result does not depend on the frames before; with ``reuse`` (the robust
    round) from the engine's θ: its first step already lengthened."""
    import core.tracking.engine_likelihood as el

    monkeypatch.setattr(el, "STOP_PRED", 0.0)
    monkeypatch.setattr(el, "SECANT_STEPS", True)
    fresh, q = _engine(0.6)
    first = fresh.refine(np.zeros(6), iters=1, sandwich=False)
    eng, _ = _engine(0.6)
    eng._theta = 0.7
    again = eng.refine(np.zeros(6), iters=1, sandwich=False)
    np.testing.assert_array_equal(again["x"], first["x"])  # (one Gauss–Newton step: 0.6 of the way)
    np.testing.assert_allclose(first["x"], 0.6 * q.x_star)
    eng._theta = 0.7
    robust = eng.refine(np.zeros(6), iters=1, sandwich=False, reuse=True)
    np.testing.assert_allclose(robust["x"], 0.6 / 0.7 * q.x_star)
