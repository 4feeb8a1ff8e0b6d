"""The search's host path trimmed without changing a bit: the search regions and pixel size
(core.tracking.roi.search_roi with its snap, roi.pixel_mm), the poses of parameter rows
(engine_render.host_poses) and the Levenberg–Marquardt state (engine_search) against the code they
replaced (copied here), on random inputs; and the talus tracked 6 frames with the likelihood stage
(ideal 128² views, Warp's CPU device, the shared upload taken) with those replaced functions put back, and
with the preparation recorded (engine_buffers.PREP_GRAPH), compared with ``==``."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from tests.core.tracking.test_joint_pipeline import _same


# ---------------------------------------------------------------- the code replaced (as it was)
def _old_boxes(cams, lab, table):
    rows, t, f, cc = table[:4]
    xc = rows @ lab.T
    xc += t
    xc = xc.reshape(len(cams), 3, len(lab))
    z = xc[:, 2:]
    zmin = np.fmin.reduce(z, axis=2).ravel()
    uv = xc[:, :2] * f
    if (zmin > 0).all():
        uv /= z
    else:
        with np.errstate(divide="ignore", invalid="ignore"):
            uv /= z
    uv += cc
    behind = (zmin <= 0).tolist()
    lows, highs = uv.min(axis=2).tolist(), uv.max(axis=2).tolist()
    out = []
    for cam, bad, a, b in zip(cams, behind, lows, highs, strict=True):
        W, H = cam.width, cam.height
        if bad:
            lo, hi = (0, 0), (W, H)
        else:
            lo = (min(max(math.floor(a[0]), 0), W), min(max(math.floor(a[1]), 0), H))
            hi = (min(max(math.ceil(b[0]) + 1, 0), W), min(max(math.ceil(b[1]) + 1, 0), H))
        out.append((lo[0], lo[1], max(hi[0] - lo[0], 0), max(hi[1] - lo[1], 0)))
    return out


def _old_search_roi(renderer, pose, bone, *, views, center, reach_mm, margin_px=4, points=None):
    from core.tracking import roi as R

    pose = np.asarray(pose, float)
    views = tuple(int(v) for v in views)
    table = R._camera_table(renderer, views)
    cams, reach_px = table[4], table[5]
    if points is None:
        box = _old_boxes(cams, R._box_lab(renderer, bone, pose), table)
    else:
        P = R._hull_points(points)
        box = _old_boxes(cams, P @ pose[:3, :3].T + pose[:3, 3], table)
    c_lab = pose[:3, :3] @ center + pose[:3, 3]
    out = []
    for cam, v, (u0, v0, w0, h0), f_px in zip(cams, views, box, reach_px, strict=True):
        depth = float(cam.R[2] @ c_lab + cam.t[2])
        grow = margin_px + (math.ceil(reach_mm * f_px / max(depth, 1e-6)) if depth > 0 else 0)
        u0, v0, w0, h0 = int(u0), int(v0), int(w0), int(h0)
        if w0 <= 0 or h0 <= 0:
            raise R.OutsideViewError(f"views: the bone projects outside view {v}")
        lo = (max(u0 - grow, 0), max(v0 - grow, 0))
        hi = (min(u0 + w0 + grow, cam.width), min(v0 + h0 + grow, cam.height))
        if hi[0] <= lo[0] or hi[1] <= lo[1]:
            raise R.OutsideViewError(f"views: the bone projects outside view {v}")
        out.append((lo[0], lo[1], hi[0] - lo[0], hi[1] - lo[1]))
    return np.array(out, dtype=np.int64).reshape(len(views), 4)


def _old_snap_roi(roi, renderer, views, grid=16):
    rows = np.array(roi, dtype=np.int64)
    out = []
    for (u0, v0, w, h), v in zip(rows.tolist(), views, strict=True):
        cam = renderer.cameras[v]
        a0, b0 = (u0 // grid) * grid, (v0 // grid) * grid
        a1 = min(-(-(u0 + w) // grid) * grid, cam.width)
        b1 = min(-(-(v0 + h) // grid) * grid, cam.height)
        out.append((a0, b0, a1 - a0, b1 - b0))
    return np.array(out, dtype=np.int64).reshape(rows.shape)


def _old_mm_per_pixel(renderer, pose, center, views=None):
    views = range(len(renderer.cameras)) if views is None else views
    c = pose[:3, :3] @ center + pose[:3, 3]
    out = []
    for v in views:
        cam = renderer.cameras[v]
        depth = float(cam.R[2] @ c + cam.t[2])
        out.append(depth / max(cam.fx, cam.fy))
    return float(np.mean(out))


def _old_host_poses(X, base, center):
    B = len(X)
    r = np.radians(X[:, 3:])
    th = np.linalg.norm(r, axis=1)
    small = th < 1e-8
    k = r / np.where(small, 1.0, th)[:, None]
    Kx = np.zeros((B, 3, 3))
    Kx[:, 0, 1] = -k[:, 2]
    Kx[:, 0, 2] = k[:, 1]
    Kx[:, 1, 0] = k[:, 2]
    Kx[:, 1, 2] = -k[:, 0]
    Kx[:, 2, 0] = -k[:, 1]
    Kx[:, 2, 1] = k[:, 0]
    s, c = np.sin(th)[:, None, None], (1.0 - np.cos(th))[:, None, None]
    Rd = np.eye(3) + s * Kx + c * (Kx @ Kx)
    if small.any():
        Rd[small] = np.eye(3)
    Rb, tb = base[:3, :3], base[:3, 3]
    c_lab = Rb @ center + tb
    R = Rd @ Rb
    out = np.zeros((B, 4, 4))
    out[:, :3, :3] = R
    out[:, :3, 3] = c_lab + X[:, :3] - R @ center
    out[:, 3, 3] = 1.0
    return out


def _old_lm():
    from core.tracking import engine_search as es

    class OldLM(es.LevenbergMarquardt):
        def __init__(self, x0, *, step, lower, upper, trust=None, **kw) -> None:
            super().__init__(x0, step=step, lower=lower, upper=upper, trust=trust, **kw)
            self.h = np.array(np.broadcast_to(np.asarray(step, dtype=float), (6,)))
            self.tr = (8.0 * self.h if trust is None
                       else np.array(np.broadcast_to(np.asarray(trust, dtype=float), (6,))))
            self._lo_in, self._hi_in = self.lo + self.h, self.hi - self.h
            self.x = np.clip(self.x0, self._lo_in, self._hi_in)

        def _solve(self, s, lam_):
            A = np.multiply(self.alpha, s.H, order="C")
            dg = np.maximum(A.diagonal(), 1e-12)
            A.reshape(36)[::7] += lam_ * dg
            try:
                d = np.linalg.solve(A, -s.g)
            except np.linalg.LinAlgError:
                d = -s.g / dg
            u = (np.abs(d) / self.tr).max()
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
                self.x = np.clip(best.x + d, self._lo_in, self._hi_in)
                return
            if best is not None:
                dx = s.x - best.x
                den = float(dx @ best.H @ dx)
                num = float((g_moments - self._best_g) @ dx)
                if den > 0 and num > 0 and (np.abs(dx) <= 4 * h).all():
                    self.alpha = float(min(max(num / den, 0.5), 1.5))
            self.best, self._best_g = s, g_moments
            self._coef, res = es._residuals(s, self.alpha)
            self.noise = math.sqrt(float(res @ res) / 6.0)
            self.lam = max(self.lam / 10.0, 1e-7)
            d = self._solve(s, self.lam)
            if (np.abs(d) < self.tol_x).all() or 0.5 * self.alpha * d @ s.H @ d < self.tol_noise * self.noise:
                self.reason, self.done = "tol_x", True
                self.final_x = np.clip(s.x + d, self.lo, self.hi)
                return
            self.x = np.clip(s.x + d, self._lo_in, self._hi_in)

    return OldLM


# ---------------------------------------------------------------- the tests
def test_search_regions_and_pixel_size_as_before(talus_scene):
    from core.geometry.transforms import pose_from_params
    from core.tracking.cost import mm_per_pixel
    from core.tracking.roi import OutsideViewError, search_roi

    sc, model, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    P0, c = sc.poses(0)[0], model.centroid
    rng = np.random.default_rng(3)
    outside = 0
    for i in range(300):
        x = rng.normal(size=6) * (150.0 if i % 3 == 0 else 3.0)  # some far outside the views
        pose = pose_from_params(x, base=P0, center=c)
        for pts in (model.outline, None):
            for reach, margin, grid in ((7.6, 4, 16), (2.0, 0, 0), (1.0, 8, 8)):
                kw = dict(views=(0, 1), center=c, reach_mm=reach, margin_px=margin, points=pts)
                try:
                    old = _old_search_roi(r, pose, 0, **kw)
                    old = _old_snap_roi(old, r, (0, 1), grid) if grid else old
                except OutsideViewError:
                    old = None
                try:
                    new = search_roi(r, pose, 0, grid=grid, **kw)
                except OutsideViewError:
                    new = None
                if old is None or new is None:
                    assert old is None and new is None
                    outside += 1
                    continue
                assert new.dtype == old.dtype and np.array_equal(new, old)
        for views in ((0, 1), (1,), None):
            assert mm_per_pixel(r, pose, c, views) == _old_mm_per_pixel(r, pose, c, views)
    assert outside > 0


def test_host_poses_as_before():
    from core.tracking.engine_render import host_poses

    rng = np.random.default_rng(5)
    base = np.eye(4)
    base[:3, :3] = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    base[:3, 3] = rng.normal(size=3) * 50
    center = rng.normal(size=3) * 20
    for B in (1, 13, 24):
        X = rng.normal(size=(B, 6)) * 3
        X[::5, 3:] = 0.0  # no rotation
        X[1::7, 3:] *= 1e-12  # below the small-angle limit
        assert np.array_equal(host_poses(X, base, center), _old_host_poses(X, base, center))


class _Quadratic:
    """A 13-pose step of a noisy quadratic cost (deterministic in x), for the search alone."""

    def __init__(self, seed: int) -> None:
        rng = np.random.default_rng(seed)
        Q = np.linalg.qr(rng.normal(size=(6, 6)))[0]
        self.A = Q @ np.diag(rng.uniform(0.05, 3.0, 6)) @ Q.T
        self.xs = rng.normal(size=6) * 3
        self.noise = rng.choice([0.0, 1e-4, 1e-2])
        self.skew = 1.0 + rng.uniform(-0.3, 0.3)

    def cost(self, x):
        d = x - self.xs
        rng = np.random.default_rng(abs(hash(x.tobytes())) % (2 ** 32))
        return 0.5 * d @ self.A @ d + self.noise * rng.normal() + 0.01 * np.sum(d ** 4)

    def step(self, x, h, idle=None):
        from core.tracking.engine_search import GaussNewtonStep, step_design

        X = step_design(x, h)
        c = np.array([self.cost(p) for p in X])
        g = self.A @ (x - self.xs) + 0.04 * (x - self.xs) ** 3
        return GaussNewtonStep(np.asarray(x, float), np.asarray(h, float), c, np.stack([c, c], 1), g,
                               self.skew * self.A, np.array([0.5, 0.5]))


def test_levenberg_marquardt_as_before():
    from core.tracking.engine_search import LevenbergMarquardt

    OldLM = _old_lm()
    for seed in range(40):
        q = _Quadratic(seed)
        rng = np.random.default_rng(100 + seed)
        b = rng.choice([2.0, 5.0, 20.0])
        kw = dict(step=rng.choice([0.1, 0.25]) * np.ones(6), lower=-b * np.ones(6), upper=b * np.ones(6),
                  tol_x=0.02, max_generations=int(rng.choice([3, 8, 20])),
                  trust=None if seed % 2 else rng.uniform(0.2, 2.0, 6))
        x0 = rng.normal(size=6) * b
        runs = []
        for cls in (LevenbergMarquardt, OldLM):
            lm = cls(x0, **kw)
            path = []
            while (x := lm.ask()) is not None:
                path.append(x.copy())
                lm.tell(q.step(x, lm.h))
            res = lm.result()
            runs.append((np.array(path), res.x, res.fun, res.reason, res.evaluations, lm.alpha, lm.noise))
        a, o = runs
        assert np.array_equal(a[0], o[0]) and np.array_equal(a[1], o[1])
        assert a[2:] == o[2:]


def _shared_on_cpu(mp) -> None:
    """The one-bone shared upload taken on Warp's CPU device (as on a CUDA device; fresh uploads)."""
    import core.tracking.engine_upload as eu

    mp.setattr(eu, "DEVICES", ("cuda", "cpu"))
    mp.setattr(eu, "_UPLOADS", {})
    mp.setattr(eu, "_ACTIVE", {})


def _track(walking_talus):
    from core.tracking.register import RegistrationOptions
    from core.tracking.trial import TrackingOptions, track

    sc, model = walking_talus["scene"], walking_talus["model"]
    keys = {model.name: {0: sc.poses(0)[0]}}
    ro = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")
    o = TrackingOptions(verify_restarts=0, refine_likelihood=True, registration=ro, trajectory_limit=None)
    return track(walking_talus["renderer"], [model], walking_talus["frames"], list(range(6)),
                 keyframes=keys, options=o)


@pytest.fixture(scope="module")
def current(walking_talus):
    """The talus tracked by the current code (the shared upload taken), once for the tests below."""
    import core.tracking.engine_buffers as eb

    with pytest.MonkeyPatch.context() as mp:
        _shared_on_cpu(mp)
        mp.setattr(eb, "PREP_GRAPH", False)  # (the operations run as asked for: the switch's reference)
        return _track(walking_talus)


def test_talus_tracked_as_with_the_code_replaced(walking_talus, current, monkeypatch):
    import core.tracking.cost as cost
    import core.tracking.engine as eng
    import core.tracking.engine_render as er
    import core.tracking.engine_search as es
    import core.tracking.register as reg

    _shared_on_cpu(monkeypatch)
    monkeypatch.setattr(cost, "pixel_mm", _old_mm_per_pixel)

    def search_region(renderer, pose, bone, *, views, center, options, outline=None, snap=True):
        roi = _old_search_roi(renderer, pose, bone, views=views, center=center,
                              reach_mm=options.bounds[0] + math.radians(options.bounds[1]) * 30.0,
                              margin_px=options.margin_px, points=outline)
        return _old_snap_roi(roi, renderer, views) if snap else roi

    monkeypatch.setattr(reg, "search_region", search_region)
    monkeypatch.setattr(er, "host_poses", _old_host_poses)
    monkeypatch.setattr(eng, "host_poses", _old_host_poses)
    monkeypatch.setattr(es, "LevenbergMarquardt", _old_lm())
    old = _track(walking_talus)
    _same(old, current)
    assert all(np.all(np.isfinite(fr.pose)) for fr in current.results.values())


@pytest.mark.parametrize("capture", [False, True])
def test_preparation_recorded_gives_the_same_results(walking_talus, current, monkeypatch, capture):
    """core.tracking.engine_buffers.PREP_GRAPH: each frame's preparation recorded, then run in order (on a
    CUDA device one graph; ``capture``: here too, as Warp's CPU graphs, kept and launched again): the same
    poses, scores, flags and confidences."""
    import warp as wp

    import core.tracking.engine_buffers as eb

    _shared_on_cpu(monkeypatch)
    monkeypatch.setattr(eb, "_CAPTURE_CPU", capture)
    launched = []
    real_launch = wp.capture_launch

    def launch(graph, *a, **k):
        launched.append(graph)
        return real_launch(graph, *a, **k)

    monkeypatch.setattr(wp, "capture_launch", launch)
    replayed = []
    real = eb._EngineBuffers._replay

    def spy(self):
        replayed.append(len(self._rec or ()))
        return real(self)

    monkeypatch.setattr(eb._EngineBuffers, "_replay", spy)
    monkeypatch.setattr(eb, "PREP_GRAPH", True)
    on = _track(walking_talus)
    assert len(replayed) >= 5 and max(replayed) >= 8  # (a new frame: copies, zeroes, launches recorded)
    if capture:  # every recorded preparation launched as a graph, some of them again
        assert len(launched) >= len(replayed) > len(set(map(id, launched))) >= 1
    _same(current, on)
