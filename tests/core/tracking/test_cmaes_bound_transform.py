"""optimize.cmaes's boundary handling (optimize._bound_transform): cma's BoundTransform with its identity
domain returned at once gives the same populations, values and result to the bit as the package's own, with
solutions inside the box, in its margins, beyond it, and with one-sided or no bounds."""

from __future__ import annotations

import numpy as np
import pytest


def _run(monkeypatch, reference: bool, fun, **kw):
    import cma

    from core.tracking import optimize as opt

    if reference:
        monkeypatch.setattr(opt, "_bound_transform", lambda: cma.BoundTransform)
    seen = []

    def f(X):
        seen.append(np.array(X))
        return fun(X)

    r = opt.cmaes(f, **kw)
    monkeypatch.undo()
    return r, seen


def _rastrigin(X):
    return np.sum(X**2 - 3 * np.cos(2 * np.pi * X), axis=1)


CASES = [
    # the tracker's global search: population 24, steps well inside ±bounds
    dict(x0=np.zeros(6), sigma0=np.r_[3.0, 3, 3, 4, 4, 4], lower=-np.r_[10.0, 10, 10, 12, 12, 12],
         upper=np.r_[10.0, 10, 10, 12, 12, 12], popsize=24, max_generations=40, tol_x=0.05),
    # steps as wide as the box: most samples in the margins or beyond
    dict(x0=np.full(6, 0.5), sigma0=2.0, lower=-np.ones(6), upper=np.ones(6), popsize=12, max_generations=25,
         tol_x=1e-3),
    # one-sided and missing bounds
    dict(x0=np.zeros(4), sigma0=1.0, lower=np.r_[-0.5, -np.inf, -2.0, -np.inf],
         upper=np.r_[np.inf, 0.3, 2.0, np.inf], max_generations=30),
    dict(x0=np.zeros(3), sigma0=0.7, lower=None, upper=None, max_generations=15),
]


@pytest.mark.parametrize("case", range(len(CASES)))
def test_same_as_the_package(monkeypatch, case):
    for seed in range(3):
        for fun in (_rastrigin, lambda X: np.sum((X - 0.9) ** 2, axis=1)):  # (an optimum outside the box)
            kw = dict(CASES[case], seed=seed)
            got, seen = _run(monkeypatch, False, fun, **kw)
            want, seen0 = _run(monkeypatch, True, fun, **kw)
            assert len(seen) == len(seen0)
            assert all(np.array_equal(a, b) for a, b in zip(seen, seen0, strict=True))
            assert np.array_equal(got.x, want.x) and got.fun == want.fun
            assert (got.evaluations, got.generations, got.reason) == (
                want.evaluations, want.generations, want.reason)


def test_identity_domain_object_returned():
    from core.tracking import optimize as opt

    bt = opt._bound_transform()([[-1.0, -2.0], [1.0, 2.0]])
    y = np.array([0.1, -0.2])
    assert bt.repair(y) is y
    z = np.array([0.99, 0.0])  # in the upper margin: transformed as by the package
    import cma

    got = bt.repair(z)
    np.testing.assert_array_equal(got, cma.BoundTransform([[-1.0, -2.0], [1.0, 2.0]]).repair(z))
    assert got[0] < 0.99 and z[0] == 0.99
