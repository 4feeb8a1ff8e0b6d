"""The registration's ``idle`` hook (host work while the device works on the first Gauss–Newton
step) and the motion check's limits computed ahead (core.tracking.checks.motion_limits)."""

from __future__ import annotations

import numpy as np

from core.geometry.transforms import pose_from_params
from core.tracking import checks
from core.tracking.checks import motion_limits, motion_miss
from core.tracking.cost import prepare_frame
from core.tracking.engine import engine_cost, gauss_newton_search
from core.tracking.register import RegistrationOptions, register

H = np.array([0.25] * 3 + [0.5] * 3)
BOX = np.array([5.0] * 6)


def _start(sc, frame_index, offset):
    c = sc["model"].centroid
    truth = sc["scene"].poses(frame_index)[0]
    off = np.asarray(offset, dtype=float)
    return pose_from_params(np.r_[off[:3], np.radians(off[3:])], center=c, base=truth)


def test_register_runs_idle_once_during_the_first_step_and_registers_alike(talus_scene):
    sc = talus_scene
    m = sc["model"]
    frame = prepare_frame(sc["fluence"](1))
    start = _start(sc, 1, [1.0, 1.0, -1.0, -1.0, 1.5, 1.0])
    o = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")
    kw = dict(bone=0, initial_pose=start, center=m.centroid, options=o, outline=m.outline)
    plain = register(sc["renderer"], frame, **kw)
    eng = engine_cost(sc["renderer"], bone=0, views=(0, 1), scale=1.0, term=o.terms[0])
    seen = []

    def idle():  # while the first step is in flight: submitted, not collected
        seen.append((eng.batches.get(13, 0), eng._pending is not None))

    res = register(sc["renderer"], frame, idle=idle, **kw)
    assert seen == [(0, True)]
    assert np.array_equal(res.pose, plain.pose) and res.score == plain.score
    assert res.evaluations == plain.evaluations and res.reason == plain.reason


def test_idle_runs_once_without_a_step():
    """A search cancelled before its first step, and a registration without a Gauss–Newton level, run
    the callable all the same, once."""
    calls = []
    res = gauss_newton_search(None, np.zeros(6), step=H, lower=-BOX, upper=BOX, cancel=lambda: True,
                              idle=lambda: calls.append(1))
    assert calls == [1] and res.reason == "cancelled"


def test_register_without_newton_levels_runs_idle(talus_scene):
    from core.tracking.register import Level

    sc = talus_scene
    m = sc["model"]
    frame = prepare_frame(sc["fluence"](1))
    start = _start(sc, 1, [0.3, 0.0, 0.0, 0.0, 0.3, 0.0])
    o = RegistrationOptions(bounds=(5.0, 5.0), search="local",
                            levels=(Level(scale=2.0, method="pattern", sigma=(1.0, 1.0), max_generations=2),))
    calls = []
    register(sc["renderer"], frame, bone=0, initial_pose=start, center=m.centroid, options=o,
             outline=m.outline, idle=lambda: calls.append(1))
    assert calls == [1]


def _walk(n, c):
    g = np.random.default_rng(3)
    out = []
    for f in range(n):
        p = np.array([0.8 * f, 0.3 * f, -0.2 * f, np.radians(0.6 * f), 0.0, np.radians(0.01 * f * f)])
        out.append((f, pose_from_params(p + g.normal(scale=0.01, size=6), center=c, base=np.eye(4))))
    return out


def test_motion_limits_ahead_are_those_motion_miss_computes():
    c = np.array([10.0, -5.0, 30.0])
    hist = _walk(12, c)
    pose = hist[-1][1] @ pose_from_params(np.array([0.5, 0, 0, 0, 0, 0.01]), center=c, base=np.eye(4))
    checks._BOUNDS.clear()
    cold = motion_miss(pose, hist, 12, c)
    checks._BOUNDS.clear()
    motion_limits(hist, 12, c)
    assert id(hist) in checks._BOUNDS  # kept for the check after the registration
    kept = checks._BOUNDS[id(hist)]
    assert motion_miss(pose, hist, 12, c) == cold
    assert checks._BOUNDS[id(hist)] is kept  # found, not computed again
    # a history that changed (a pose appended) is computed afresh
    hist.append((12, pose))
    motion_limits(hist, 13, c)
    assert checks._BOUNDS[id(hist)] is not kept


def test_register_with_a_stage_prefetches_its_rows_in_the_idle_slot(talus_scene, monkeypatch):
    """register.STAGE_PREFETCH: the stage's rows uploaded once while the first step is in flight, at the
    initial pose, before the caller's idle work; the registration the same to the bit as without."""
    import core.tracking.final_stage as fs
    import core.tracking.register as reg

    sc = talus_scene
    m = sc["model"]
    frame = prepare_frame(sc["fluence"](2))
    start = _start(sc, 2, [0.4, -0.3, 0.2, 0.3, 0.0, -0.2])
    o = RegistrationOptions(bounds=(3.0, 3.0), search="newton", final="likelihood", final_highpass_px=2.0)
    kw = dict(bone=0, initial_pose=start, center=m.centroid, options=o)
    eng = engine_cost(sc["renderer"], bone=0, views=(0, 1), scale=1.0, term=o.terms[0])
    plain = fs.stage_prefetch
    seen = []

    def spy(*a, **k):
        seen.append(("prefetch", eng._pending is not None, np.array_equal(k["pose"], start)))
        return plain(*a, **k)

    monkeypatch.setattr(fs, "stage_prefetch", spy)
    monkeypatch.setattr(reg, "STAGE_PREFETCH", False)
    off = register(sc["renderer"], frame, **kw)
    assert seen == []
    monkeypatch.setattr(reg, "STAGE_PREFETCH", True)
    on = register(sc["renderer"], frame, idle=lambda: seen.append("caller"), **kw)
    assert seen == [("prefetch", True, True), "caller"]
    assert on.timing["likelihood_taken"] == off.timing["likelihood_taken"] == 1
    np.testing.assert_array_equal(on.pose, off.pose)
    np.testing.assert_array_equal(np.asarray(on.fit.covariance), np.asarray(off.fit.covariance))
    assert on.evaluations == off.evaluations
