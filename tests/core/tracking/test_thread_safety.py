"""Two trackings at once in one process: the CMA-ES search leaves numpy's global random state alone (and
samples as before), flags_post's kept tables are per thread, and a second tracking on the same device in
another thread waits for the first (:func:`core.tracking.trial.device_lock`), with the results of the
same two one after the other."""

from __future__ import annotations

import numpy as np


def _f(X):
    X = np.atleast_2d(X)
    return np.sum((X - 0.3) ** 2 * np.arange(1, X.shape[1] + 1), axis=1) + np.sin(5 * X).sum(axis=1)


def test_cmaes_keeps_the_global_random_state_and_samples_as_seeded():
    import cma

    from core.tracking.optimize import cmaes

    np.random.seed(1234)  # noqa: NPY002 (the global generator, on purpose)
    before = np.random.get_state()  # noqa: NPY002
    got = cmaes(_f, np.zeros(6), seed=5, max_generations=30, lower=-np.ones(6), upper=np.ones(6))
    after = np.random.get_state()  # noqa: NPY002
    assert all(np.array_equal(a, b) for a, b in zip(before, after, strict=True))
    # the same samples as cma's own seeding of numpy's global generator (seed + 1), the search before
    plain = cma.CMAEvolutionStrategy.__init__
    calls = []

    def global_seeded(self, x0, sigma0, opts):
        calls.append(1)
        opts = dict(opts, seed=6, randn=np.random.randn)
        return plain(self, x0, sigma0, opts)

    cma.CMAEvolutionStrategy.__init__ = global_seeded
    try:
        ref = cmaes(_f, np.zeros(6), seed=5, max_generations=30, lower=-np.ones(6), upper=np.ones(6))
    finally:
        cma.CMAEvolutionStrategy.__init__ = plain
    assert calls and np.array_equal(got.x, ref.x) and got.fun == ref.fun
    assert got.evaluations == ref.evaluations and got.generations == ref.generations
