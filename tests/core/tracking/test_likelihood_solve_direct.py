"""likelihood_solve.DIRECT_SOLVES: the moment tables' entries gathered at once and the stacked solves
called through numpy.linalg.solve's own gufunc give the same quantities to the bit as through
numpy.linalg.solve, for every model (background, neighbours, extra regressors; one and two views), and
a singular table raises numpy's LinAlgError as before."""

from __future__ import annotations

import numpy as np
import pytest


def _table(g, nv, nz):
    Z = g.normal(size=(nv, 400, nz)) * g.uniform(0.1, 10.0, size=nz)
    Z[:, :, 8] = 1.0
    return np.einsum("vni,vnj->vij", Z, Z)


@pytest.mark.parametrize("model", [(0, False, 0), (0, True, 0), (1, False, 0), (1, True, 0), (0, False, 1),
                                   (1, True, 2)])
def test_direct_solves_are_numpys_to_the_bit(model, monkeypatch):
    import core.tracking.likelihood_solve as ls
    from core.tracking.likelihood_kernels import NZ

    bg, others, extra = model
    g = np.random.default_rng(11)
    for t in range(40):
        M = _table(g, 1 + t % 2, NZ + extra)
        h = g.uniform(0.01, 0.1, 6)
        monkeypatch.setattr(ls, "DIRECT_SOLVES", True)
        a = ls.solve_moments(M, h, bg, others, extra)
        monkeypatch.setattr(ls, "DIRECT_SOLVES", False)
        b = ls.solve_moments(M, h, bg, others, extra)
        assert a.keys() == b.keys()
        for k in a:
            np.testing.assert_array_equal(np.asarray(a[k]), np.asarray(b[k]), err_msg=k)


@pytest.mark.parametrize("direct", [True, False])
def test_a_singular_table_raises_linalgerror(direct, monkeypatch):
    import core.tracking.likelihood_solve as ls

    monkeypatch.setattr(ls, "DIRECT_SOLVES", direct)
    with pytest.raises(np.linalg.LinAlgError):
        ls.solve_moments(np.zeros((2, 12, 12)), np.full(6, 0.05))
