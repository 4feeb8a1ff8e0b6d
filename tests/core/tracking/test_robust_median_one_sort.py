"""The robust factors' median with both views' keys in one sort
(core.tracking.likelihood_kernels.MEDIAN_ONE_SORT): the same scale and factors, to the bit, as a sort a
view and as np.median, for one and two views, odd and even counts, zeros, NaN and a view with no used
pixel (Warp's CPU device)."""

from __future__ import annotations

import numpy as np
import pytest


def _factors(e, w, one_sort: bool, monkeypatch):
    import warp as wp

    import core.tracking.likelihood_kernels as lk

    monkeypatch.setattr(lk, "MEDIAN_ONE_SORT", one_sort)
    bufs: dict = {}
    f = lk.robust_factors_device(wp.array(e.astype(np.float32), dtype=wp.float32, device="cpu"),
                                 wp.array(w.astype(np.float32), dtype=wp.float32, device="cpu"), 2.5,
                                 bufs=bufs)
    return f.numpy(), bufs["rf_scale"].numpy(), bufs["rf_local"].numpy()


@pytest.mark.parametrize("case", ["two", "one", "even", "zeros", "empty"])
def test_one_sort_median_is_the_per_view_sorts(case, monkeypatch):
    g = np.random.default_rng(7)
    nv = 1 if case == "one" else 2
    e = g.normal(0.0, 1.0, (nv, 41, 29))
    w = g.uniform(0.5, 2.0, e.shape)
    w[0, :, 20:] = 0.0  # padded layout
    if nv == 2:
        w[1, 30:, :] = 0.0
    if case == "even":
        w[0, 0, :20] = 0.0  # 40 · 20 used
    if case == "zeros":  # a zero residual over a patch: local RMS 0 inside it, and NaN
        e[:, 2:30, :] = 0.0
        e[0, 39, 1] = np.nan
    if case == "empty":
        w[1] = 0.0
    e = np.where(w > 0, e, 0.0) if case != "zeros" else e
    f1, s1, l1 = _factors(e, w, True, monkeypatch)
    f0, s0, l0 = _factors(e, w, False, monkeypatch)
    np.testing.assert_array_equal(l1, l0)
    np.testing.assert_array_equal(s1, s0)
    np.testing.assert_array_equal(f1, f0)
    want = np.array([np.median(x[x >= 0]) if np.any(x >= 0) else 0.0 for x in l1], dtype=np.float32)
    want = np.where(np.isfinite(want) & (want > 0), want, 0.0).astype(np.float32)
    np.testing.assert_array_equal(s1, want)
    if case == "zeros":
        assert np.sum(l1 == 0.0) > 100 and np.any(np.isnan(l1[0]))
    if case == "empty":
        assert s1[1] == 0.0 and np.all(f1[1] == 0.0)
