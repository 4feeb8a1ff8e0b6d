"""The Gauss–Newton search's host arithmetic trimmed without changing a bit: the moments' Gauss–Newton
algebra (engine_search.moments_to_newton), the closed-form fit of a step's 13 costs (_residuals) and the
Levenberg–Marquardt step (_solve, tell) against the code they replaced (copied here as it was), on random
inputs and on searches of noisy quadratics, compared to the bit (``tobytes``)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest


# ---------------------------------------------------------------- the code replaced (as it was)
def _old_moments_to_newton(M, h, weights=None):
    from core.tracking.engine_search import _scale2

    M = np.asarray(M, dtype=np.float64).reshape(-1, 9, 9)
    h = np.asarray(h, dtype=float)
    nv = len(M)
    w = [1.0 / nv] * nv if weights is None else list(np.asarray(weights, float) / np.sum(weights))
    n = M[:, 0, 0]
    every = all(a >= 2 for a in n.tolist())
    ok = None if every else n >= 2
    m = M[:, 0] / (n if every else np.where(ok, n, 1.0))[:, None]
    C = (M - n[:, None, None] * (m[:, :, None] * m[:, None, :])) * _scale2(h)
    caa, cbb, cab = C[:, 1, 1], C[:, 2, 2], C[:, 1, 2]
    if every:
        every = all(a > 0 and b > 0 for a, b in zip(caa.tolist(), cbb.tolist(), strict=True))
    if not every:
        ok = (n >= 2) & (caa > 0) & (cbb > 0)
    if every:
        cb = cbb
        sq = np.sqrt(caa * cbb)
    elif not ok.any():
        return np.zeros(nv), np.zeros(6), np.zeros((6, 6))
    else:
        every = False
        cb = np.where(ok, cbb, 1.0)
        sq = np.sqrt(np.where(ok, caa, 1.0) * cb)
    r = cab / sq
    cbd = C[:, 2, 3:]
    dr = C[:, 1, 3:] / sq[:, None] - r[:, None] * cbd / cb[:, None]
    cb3 = cb[:, None, None]
    jtj = (C[:, 3:, 3:] - cbd[:, :, None] * cbd[:, None, :] / cb3) / cb3
    g = np.zeros(6)
    H = np.zeros((6, 6))
    rl = r.tolist()
    if every:
        r_out = r
        for v in range(nv):
            g -= w[v] * dr[v]
            H += w[v] * max(rl[v], 0.05) * jtj[v]
    else:
        r_out = np.zeros(nv)
        for v in range(nv):
            if ok[v]:
                rv = rl[v]
                r_out[v] = rv
                g -= w[v] * dr[v]
                H += w[v] * max(rv, 0.05) * jtj[v]
    return r_out, g, 0.5 * (H + H.T)


def _old_residuals(s, alpha=1.0):
    h = np.asarray(s.h, dtype=float)
    q = 0.5 * alpha * h * h * s.H.diagonal()
    y = np.array(s.costs, dtype=float)
    y[1::2] -= q
    y[2::2] -= q
    c0 = np.add.reduce(y) / 13
    g = (y[1::2] - y[2::2]) / (2.0 * h)
    hg = h * g
    res = y - c0
    res[1::2] = y[1::2] - (c0 + hg)
    res[2::2] = y[2::2] - (c0 - hg)
    coef = np.empty(7)
    coef[0] = c0
    coef[1:] = g
    return coef, res


def _old_lm():
    from core.tracking import engine_search as es

    class OldLM(es.LevenbergMarquardt):
        def _solve(self, s, lam_):
            A = np.multiply(self.alpha, s.H, order="C")
            dg = np.maximum(A.diagonal(), 1e-12)
            A.reshape(36)[::7] += lam_ * dg
            try:
                d = np.linalg.solve(A, -s.g)
            except np.linalg.LinAlgError:
                d = -s.g / dg
            u = np.maximum.reduce(np.abs(d) / self.tr)
            return d / u if u > 1 else d

        def tell(self, s) -> None:
            h = self.h
            self.evals += es._N
            self.gens += 1
            g_moments = s.g
            if self.gradient == "corrected":
                s = replace(s, g=s.g + self._correction(s))
            best = self.best
            cost = s.cost
            if best is not None and not cost <= best.cost + max(self.noise, 1e-7):
                self.lam = max(10.0 * self.lam, 0.5)
                if self.lam > 1e4:
                    self.reason, self.done = "stalled", True
                    return
                d = self._solve(best, self.lam)
                self.x = (best.x + d).clip(self._lo_in, self._hi_in)
                return
            if best is not None:
                dx = s.x - best.x
                den = float(dx @ best.H @ dx)
                num = float((g_moments - self._best_g) @ dx)
                if den > 0 and num > 0 and (np.abs(dx) <= 4 * h).all():
                    self.alpha = float(min(max(num / den, 0.5), 1.5))
            self.best, self._best_g = s, g_moments
            self._coef, res = _old_residuals(s, self.alpha)
            self.noise = math.sqrt(float(res @ res) / 6.0)
            self.lam = max(self.lam / 10.0, 1e-7)
            d = self._solve(s, self.lam)
            tol = self.tol_x
            if (all(v < tol for v in np.abs(d).tolist())
                    or 0.5 * self.alpha * d @ s.H @ d < self.tol_noise * self.noise):
                self.reason, self.done = "tol_x", True
                self.final_x = (s.x + d).clip(self.lo, self.hi)
                return
            self.x = (s.x + d).clip(self._lo_in, self._hi_in)

        def result(self):
            res = super().result()
            if self.best is None:
                return res
            # (the fit as it was made: the Hessian copied, then scaled)
            assert res.model.H.tobytes() == (self.alpha * np.array(self.best.H)).tobytes()
            return res

    return OldLM


# ---------------------------------------------------------------- helpers
def _moments(rng, nv: int, npix: int = 400, contrast=True) -> np.ndarray:
    """Moment matrices of z = (1, a, b, δ_1..δ_6) over random pixels, as the device sums them."""
    out = []
    for _ in range(nv):
        a = rng.normal(size=npix)
        b = 0.7 * a + rng.normal(scale=0.5, size=npix) if contrast else np.full(npix, 0.3)
        D = rng.normal(size=(npix, 6)) * rng.uniform(0.01, 2.0, size=6) + 0.2 * b[:, None]
        z = np.column_stack([np.ones(npix), a, b, D]) * rng.uniform(0.5, 3.0)
        z[:, 0] = 1.0
        out.append(z.T @ z)
    return np.array(out)


def _same(a, b) -> None:
    for x, y in zip(a, b, strict=True):
        assert np.asarray(x).tobytes() == np.asarray(y).tobytes()


# ---------------------------------------------------------------- the tests
@pytest.mark.parametrize("nv", [1, 2, 3, 4])
def test_moments_to_newton_as_before(nv):
    from core.tracking.engine_search import moments_to_newton

    rng = np.random.default_rng(nv)
    for i in range(150):
        M = _moments(rng, nv, npix=int(rng.integers(20, 600)))
        h = np.array([0.25, 0.25, 0.25, 0.5, 0.5, 0.5]) * rng.uniform(0.5, 4.0)
        if i % 5 == 1:  # a view without contrast, or too few pixels: the general path
            v = int(rng.integers(nv))
            M[v] = _moments(rng, 1, contrast=False)[0] if i % 2 else np.diag([1.0] + [0.0] * 8)
        got, want = moments_to_newton(M, h), _old_moments_to_newton(M, h)
        _same(got, want)
        assert got[0].shape == (nv,) and got[1].shape == (6,) and got[2].shape == (6, 6)
        w = rng.uniform(0.1, 1.0, size=nv)
        _same(moments_to_newton(M, h, weights=w), _old_moments_to_newton(M, h, weights=w))
    # a zero product's sign kept (the sums from 0, in the views' order)
    M = _moments(rng, 2)
    M[:, 3:, :] = 0.0
    M[:, :, 3:] = 0.0
    _same(moments_to_newton(M, np.ones(6)), _old_moments_to_newton(M, np.ones(6)))
    M[0, 1, 1] = np.nan  # a NaN: the general path, as before
    _same(moments_to_newton(M, np.ones(6)), _old_moments_to_newton(M, np.ones(6)))


def _step(rng, x, h, *, scale=1.0):
    from core.tracking.engine_search import GaussNewtonStep, step_design

    A = rng.normal(size=(6, 6))
    H = A @ A.T * scale + np.eye(6) * 1e-3
    X = step_design(x, h)
    costs = 0.5 + 0.5 * np.einsum("bi,ij,bj->b", X, H, X) + rng.normal(scale=1e-3, size=13)
    return GaussNewtonStep(np.array(x), np.array(h), costs, rng.uniform(size=(13, 2)), H @ x, H,
                           rng.uniform(size=2))


def test_residuals_as_before():
    from core.tracking.engine_search import _residuals

    rng = np.random.default_rng(5)
    for _ in range(300):
        h = rng.uniform(0.05, 2.0, size=6)
        s = _step(rng, rng.normal(size=6), h, scale=rng.uniform(0.01, 100.0))
        alpha = float(rng.uniform(0.5, 1.5))
        _same(_residuals(s, alpha), _old_residuals(s, alpha))
        _same(_residuals(s), _old_residuals(s))


def test_levenberg_marquardt_as_before():
    """Searches of noisy quadratics (some with the step's trust box and the search box binding, some
    rejected steps), the new state machine and the old one fed the same steps: the same iterates."""
    from core.tracking.engine_search import GaussNewtonStep, LevenbergMarquardt, step_design

    OldLM = _old_lm()
    rng = np.random.default_rng(11)
    reasons = set()
    for trial in range(60):
        A = rng.normal(size=(6, 6))
        Ht = A @ A.T + np.eye(6) * rng.uniform(0.01, 1.0)
        xt = rng.normal(size=6) * rng.uniform(0.1, 5.0)
        noise = 10.0 ** rng.uniform(-6, -1)
        kw = dict(step=np.array([0.25] * 3 + [0.5] * 3), lower=-np.full(6, 6.0), upper=np.full(6, 6.0),
                  tol_x=float(rng.choice([0.02, 0.5])), max_generations=8,
                  gradient="corrected" if trial % 4 == 3 else "moments")
        x0 = rng.normal(size=6)
        new, old = LevenbergMarquardt(x0, **kw), OldLM(x0, **kw)
        srng = np.random.default_rng(trial)
        while True:
            xn, xo = new.ask(), old.ask()
            assert (xn is None) == (xo is None)
            if xn is None:
                break
            assert xn.tobytes() == xo.tobytes()
            h = new.h
            X = step_design(xn, h) - xt
            c = 0.5 * np.einsum("bi,ij,bj->b", X, Ht, X) + srng.normal(scale=noise, size=13)
            Hs = Ht * srng.uniform(0.6, 1.4)
            s = GaussNewtonStep(xn.copy(), h.copy(), c, srng.uniform(size=(13, 2)),
                                Hs @ (xn - xt) + srng.normal(scale=noise, size=6), Hs, srng.uniform(size=2))
            new.tell(s)
            old.tell(s)
            for a in ("x", "lam", "alpha", "noise", "reason", "done", "evals", "gens", "final_x"):
                va, vb = getattr(new, a), getattr(old, a)
                assert np.asarray(va).tobytes() == np.asarray(vb).tobytes(), a
        ra, rb = new.result(), old.result()
        reasons.add(ra.reason)
        assert ra.x.tobytes() == rb.x.tobytes() and ra.fun == rb.fun and ra.reason == rb.reason
        assert ra.model.H.tobytes() == rb.model.H.tobytes() and ra.model.c0 == rb.model.c0
    assert {"tol_x", "max_generations"} <= reasons


def test_solve_shortened_and_singular_as_before():
    from core.tracking.engine_search import GaussNewtonStep, LevenbergMarquardt

    OldLM = _old_lm()
    rng = np.random.default_rng(2)
    kw = dict(step=0.25, lower=-np.full(6, 9.0), upper=np.full(6, 9.0))
    new, old = LevenbergMarquardt(np.zeros(6), **kw), OldLM(np.zeros(6), **kw)
    for i in range(200):
        A = rng.normal(size=(6, 6))
        H = A @ A.T * 10.0 ** rng.uniform(-4, 2)
        g = rng.normal(size=6) * 10.0 ** rng.uniform(-3, 2)
        if i % 10 == 0:
            H = np.zeros((6, 6))  # the damping's floor alone
        if i % 10 == 1:
            H[2] = np.nan  # a NaN: no shortening, as np.maximum.reduce had it
        if i % 10 == 2:
            H[0], H[:, 0] = 0.0, 0.0
        s = GaussNewtonStep(np.zeros(6), np.full(6, 0.25), np.zeros(13), np.zeros((13, 2)), g, H, np.zeros(2))
        for lam in (1e-7, 1e-3, 0.5, 50.0):
            a, b = new._solve(s, lam), old._solve(s, lam)
            assert a.tobytes() == b.tobytes()


def test_solve6_is_numpys_solve():
    from core.tracking.engine_search import _solve6

    rng = np.random.default_rng(8)
    for _ in range(200):
        A = rng.normal(size=(6, 6))
        b = rng.normal(size=6)
        assert _solve6(A, b).tobytes() == np.linalg.solve(A, b).tobytes()
    with pytest.raises(np.linalg.LinAlgError):
        _solve6(np.zeros((6, 6)), np.ones(6))
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.solve(np.zeros((6, 6)), np.ones(6))


def test_step_design_as_before():
    from core.tracking.engine_search import _DESIGN, step_design

    rng = np.random.default_rng(4)
    for i in range(100):
        h = rng.uniform(0.01, 3.0, size=6) if i % 3 else np.full(6, 0.25)
        x = rng.normal(size=6) * 10.0 ** rng.uniform(-3, 2)
        got = step_design(x, h)
        assert got.tobytes() == (np.asarray(x, dtype=float) + _DESIGN * np.asarray(h, dtype=float)).tobytes()
        got[:] = 0.0  # (the caller's own array: the kept offsets unchanged)
        assert step_design(x, h).tobytes() == (x + _DESIGN * h).tobytes()
    assert step_design([0.0] * 6, 0.5).tobytes() == (_DESIGN * 0.5).tobytes()


def test_host_poses_as_before():
    """One or two rows' cross-product matrices from Python floats: the poses of the array fill."""
    from core.tracking.engine_render import host_poses
    from tests.core.tracking.test_search_host_exact import _old_host_poses

    rng = np.random.default_rng(6)
    base = np.eye(4)
    base[:3, :3] = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    base[:3, 3] = rng.normal(size=3) * 50.0
    c = rng.normal(size=3) * 30.0
    for B in (1, 2, 3, 13, 0):
        for i in range(60):
            X = rng.normal(size=(B, 6)) * 10.0 ** rng.uniform(-9, 1)
            if i % 7 == 0 and B:
                X[0, 3:] = 0.0  # (no rotation: the small-angle branch)
            got, want = host_poses(X, base, c), _old_host_poses(X, base, c)
            assert got.shape == want.shape and got.tobytes() == want.tobytes()
