"""The sandwich over a sub-lattice of the region's pixels (likelihood_confidence.SANDWICH_STRIDE,
core.tracking.likelihood_stride): the autocovariance is the pairs' mean product with the first pixel on
the lattice (numpy over the same pairs), the meat the lattice's sum times stride², the covariance near
every pixel's."""

from __future__ import annotations

import numpy as np

import core.tracking.likelihood_confidence as lc
from core.tracking.likelihood_stride import stride_cells

from .test_engine_likelihood import _setup


def test_stride_cells():
    assert stride_cells((128, 96), 1) == 128 * 96
    assert stride_cells((127, 97), 2) == 64 * 49
    assert stride_cells((9, 9), 3) == 9


def test_autocovariance_over_the_lattice_equals_numpys(talus_scene, monkeypatch):
    """With stride 2 each lag's mean product is over the pairs (i, i + Δ) of usable pixels with i on
    the lattice (rows and columns even), for the first half of the lags (Δ_r < 0, or 0 and Δ_c ≤ 0);
    the others their mirror."""
    monkeypatch.setattr(lc, "SANDWICH_STRIDE", 2)
    eng, _, _ = _setup(talus_scene, 2, [0.2, 0, 0, 0, 0.3, 0], highpass_px=2.0, lag_px=3)
    s = eng.step(np.zeros(6), np.full(6, 0.05))
    eng.sandwich(s, np.linalg.inv(s["JJ"]))
    e = eng.residual(s).astype(np.float64)
    used = eng._w.numpy() > 0
    L, n = 3, 7
    for v, (h, w) in enumerate(eng._ref_hw.numpy()):
        ep = np.pad(e[v, :h, :w], L)
        up = np.pad(used[v, :h, :w], L)
        c = np.zeros((n, n))
        for a in range(-L, L + 1):
            for b in range(-L, L + 1):
                dr, dc = (a, b) if (a < 0 or (a == 0 and b <= 0)) else (-a, -b)
                i = (slice(L, L + h, 2), slice(L, L + w, 2))  # (the lattice)
                j = (slice(L + dr, L + dr + h, 2), slice(L + dc, L + dc + w, 2))  # (its partners)
                both = up[i] & up[j]
                c[a + L, b + L] = np.sum((ep[i] * ep[j])[both]) / max(both.sum(), 1)
        np.testing.assert_allclose(eng.autocorrelation[v], c / c[L, L], rtol=1e-5, atol=1e-7)


def test_strided_sandwich_is_near_every_pixels(talus_scene, monkeypatch):
    """The covariance with stride 2 against stride 1 on the same design (a 128² ideal frame, the
    stage's 4 px high-pass: a small region, the lattice's sampling errs more than at 1024²; at 256²
    over 30 bone-frames σ was within 2 % on average, 7.5 % at worst: core.studies.tracking.stage_cuts):
    σ within 15 % per axis, the matrix positive definite."""
    eng, _, _ = _setup(talus_scene, 3, [0.2, -0.1, 0, 0.2, 0, 0.1], highpass_px=4.0)
    s = eng.step(np.zeros(6), np.full(6, 0.05))
    Hinv = np.linalg.inv(s["JJ"])
    monkeypatch.setattr(lc, "SANDWICH_STRIDE", 1)
    C1 = eng.sandwich(s, Hinv)
    monkeypatch.setattr(lc, "SANDWICH_STRIDE", 2)
    C2 = eng.sandwich(s, Hinv)
    r = np.sqrt(np.diag(C2) / np.diag(C1))
    assert np.all(np.abs(r - 1.0) < 0.15), r
    assert np.all(np.linalg.eigvalsh(0.5 * (C2 + C2.T)) > 0)
    monkeypatch.setattr(lc, "SANDWICH_STRIDE", 1)
    np.testing.assert_array_equal(eng.sandwich(s, Hinv), C1)  # (stride 1: every pixel's, as before)
