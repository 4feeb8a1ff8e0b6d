import numpy as np
import pytest

from core.tracking import optimize as opt

C = np.array([1.0, -2.0, 0.5, 3.0, -1.0, 0.2])
W = np.array([1.0, 2.0, 3.0, 1.0, 2.0, 3.0])


class Quadratic:
    """Batched test function; counts calls to check one call per generation."""

    def __init__(self, c=C):
        self.c, self.calls, self.points = np.asarray(c), 0, 0

    def __call__(self, X):
        X = np.atleast_2d(X)
        self.calls += 1
        self.points += len(X)
        return (((X - self.c) ** 2) * W).sum(axis=1)


@pytest.mark.parametrize("method, kwargs, tol", [
    (opt.cmaes, {"sigma0": 2.0, "tol_x": 1e-4}, 1e-3),
    (opt.pso, {}, 1e-2),
    (opt.pattern_search, {"step": 1.0, "tol_x": 1e-4}, 1e-3),
    (opt.nelder_mead, {"step": 0.5, "tol_x": 1e-5, "tol_fun": 1e-10}, 1e-3),
    (opt.powell, {}, 1e-3),
])
def test_optimisers_find_the_minimum(method, kwargs, tol):
    f = Quadratic()
    r = method(f, np.zeros(6), lower=-10, upper=10, **kwargs)
    assert np.abs(r.x - C).max() < tol
    assert r.converged and r.reason in ("tol_x", "tol_fun")
    assert r.evaluations == f.points and r.generations == f.calls
    assert r.fun == pytest.approx(f(r.x[None])[0])
    assert r.time_s >= 0


def test_population_methods_batch_each_generation():
    f = Quadratic()
    r = opt.cmaes(f, np.zeros(6), sigma0=1.0, popsize=16, max_generations=5, tol_x=0)
    assert r.reason == "max_generations" and not r.converged
    assert f.calls == 1 + 5 + 1 and f.points == 1 + 5 * 16 + 1  # x0, 5 generations, the final mean
    f = Quadratic()
    opt.pattern_search(f, np.zeros(6), step=1.0, max_generations=3, tol_x=0)
    assert f.points == 1 + 3 * 12


def test_bounds_are_respected():
    far = np.array([20.0, 0, 0, 0, 0, 0])
    for method in (opt.cmaes, opt.pso, opt.pattern_search, opt.powell):
        r = method(Quadratic(far), np.zeros(6), lower=-5, upper=5)
        assert np.all(np.abs(r.x) <= 5 + 1e-9)
        assert r.x[0] == pytest.approx(5.0, abs=0.05)


def test_cancel_and_budget():
    calls = []

    def cancel():
        calls.append(1)
        return len(calls) > 3

    r = opt.cmaes(Quadratic(), np.zeros(6), cancel=cancel)
    assert r.reason == "cancelled" and not r.converged
    r = opt.pso(Quadratic(), np.zeros(6), n_particles=10, max_evaluations=35)
    assert r.reason == "max_evaluations" and not r.converged and r.evaluations < 50
    r = opt.nelder_mead(Quadratic(), np.zeros(6), cancel=lambda: True)
    assert r.reason == "cancelled"


def test_autoscoper_pso_settings_and_validation():
    assert opt.AUTOSCOPER_PSO["n_particles"] == 100
    assert opt.AUTOSCOPER_PSO["c1"] == opt.AUTOSCOPER_PSO["c2"] == 1.5
    f = Quadratic()
    r = opt.pso(f, np.zeros(6), **opt.AUTOSCOPER_PSO, max_generations=2)
    assert f.points == 100 * 3 and r.generations == 3
    with pytest.raises(ValueError, match="x0"):
        opt.cmaes(Quadratic(), np.full(6, 20.0), lower=-1, upper=1)
    with pytest.raises(ValueError, match="sigma0"):
        opt.cmaes(Quadratic(), np.zeros(6), sigma0=0)
    with pytest.raises(ValueError, match="lower, upper"):
        opt.pso(Quadratic(), np.zeros(6), lower=1, upper=1)
    with pytest.raises(ValueError, match="n_particles"):
        opt.pso(Quadratic(), np.zeros(6), n_particles=0)
    with pytest.raises(ValueError, match="fun"):
        opt.pattern_search(lambda X: np.zeros(3), np.zeros(6))
