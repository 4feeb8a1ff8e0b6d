"""likelihood_solve.LEAN_SOLVES: the steps' host tables solved by solve_tables (the entries gathered from
above the diagonal, the differences' scales in two products, "lin" and "M" made where read) and the 6×6
system by solve6 / inv6 give the same quantities to the bit as the triangle mirrored with numpy.triu,
solve_moments and numpy.linalg.solve / inv, for every model; a stage with them (and
likelihood_confidence.COV_ON_READ) gives the same pose, covariances, steps and autocorrelation to the bit as
without (128² talus, Warp's CPU device)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.core.tracking.stage_helpers import engine_at, noisy_start


def _table(g, nv, nz):
    Z = g.normal(size=(nv, 300, nz)) * g.uniform(0.1, 10.0, size=nz)
    Z[:, :, 8] = 1.0
    return np.einsum("vni,vnj->vij", Z, Z)


@pytest.mark.parametrize("model", [(0, False, 0), (0, True, 0), (1, False, 0), (1, True, 0), (0, False, 1),
                                   (1, True, 2)])
@pytest.mark.parametrize("tri", [False, True])
def test_solve_tables_is_the_mirror_and_solve_moments_to_the_bit(model, tri):
    import core.tracking.likelihood_solve as ls
    from core.tracking.likelihood_kernels import NZ

    bg, others, extra = model
    nz = NZ + extra
    g = np.random.default_rng(3)
    for t in range(30):
        nv = 1 + t % 2
        M = _table(g, nv, nz)
        h = np.full(6, 0.05) if t % 3 == 0 else g.uniform(0.01, 0.1, 6)
        T = (np.triu(M) if tri else M).reshape(nv, -1).copy()
        M0 = T.reshape(nv, nz, nz).copy()
        if tri:
            M0 += np.swapaxes(np.triu(M0, 1), 1, 2)
        a = ls.solve_moments(M0, h, bg, others, extra)
        a["M"] = M0
        b = ls.solve_tables(T, h, bg, others, extra, tri)
        T[...] = np.nan  # (the pinned table written again: the result keeps its own copy)
        for k in a:
            np.testing.assert_array_equal(np.asarray(a[k]), np.asarray(b[k]), err_msg=k)
        np.testing.assert_array_equal(ls.solve6(a["JJ"], a["Jr"]), np.linalg.solve(a["JJ"], a["Jr"]))
        np.testing.assert_array_equal(ls.inv6(a["JJ"]), np.linalg.inv(a["JJ"]))


def test_singular_systems_raise_linalgerror():
    import core.tracking.likelihood_solve as ls

    with pytest.raises(np.linalg.LinAlgError):
        ls.solve_tables(np.zeros((2, 144)), np.full(6, 0.05), tri=True)
    with pytest.raises(np.linalg.LinAlgError):
        ls.solve_moments(np.zeros((2, 12, 12)), np.full(6, 0.05))
    with pytest.raises(np.linalg.LinAlgError):
        ls.solve6(np.zeros((6, 6)), np.ones(6))
    with pytest.raises(np.linalg.LinAlgError):
        ls.inv6(np.zeros((6, 6)))


def test_a_stage_is_the_same_to_the_bit(talus_scene, monkeypatch):
    import core.tracking.likelihood_confidence as lc
    import core.tracking.likelihood_solve as ls
    from core.tracking.register import register

    model, r = talus_scene["model"], talus_scene["renderer"]
    frame, start, o = noisy_start(talus_scene)
    out = []
    for lean in (False, True):
        monkeypatch.setattr(ls, "LEAN_SOLVES", lean)
        monkeypatch.setattr(lc, "COV_ON_READ", lean)
        res = register(r, frame, bone=0, initial_pose=start, center=model.centroid, options=o)
        assert res.timing["likelihood_taken"] == 1
        out.append(res)
    a, b = out
    np.testing.assert_array_equal(a.pose, b.pose)
    for f in ("covariance", "covariance_independent"):
        np.testing.assert_array_equal(np.asarray(getattr(a.fit, f)), np.asarray(getattr(b.fit, f)))
    assert a.timing["likelihood_steps"] == b.timing["likelihood_steps"]


def test_the_autocorrelation_read_from_the_device_is_the_copy(talus_scene, monkeypatch):
    import core.tracking.likelihood_confidence as lc

    eng = engine_at(talus_scene)
    s = eng.step(np.zeros(6), np.full(6, 0.05))
    out = []
    for on in (False, True):
        monkeypatch.setattr(lc, "COV_ON_READ", on)
        out.append((eng.sandwich(s, np.linalg.inv(s["JJ"])), eng.autocorrelation))
    np.testing.assert_array_equal(out[0][0], out[1][0])
    assert np.all(np.isfinite(out[0][1]))
    np.testing.assert_array_equal(out[0][1], out[1][1])
