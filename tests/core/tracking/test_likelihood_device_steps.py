"""A refinement's steps on the device (core.tracking.likelihood_device_steps, engine_likelihood.
DEVICE_STEPS): the same poses, confidences, steps, renders and flags as the host's loop (CPU device, the
recorded steps: ideal 128² views of the talus and calcaneus side by side; the talus's noisy frame; an
uphill stop and the iterations spent), within the float64 solves' rounding."""

from __future__ import annotations

import numpy as np
import pytest

from tests.core.tracking.stage_helpers import engine_at, noisy_start, stage_calls


def _close(a, b) -> None:
    """Equal structure, numbers within the solves' rounding (σ: 1e-6 relative)."""
    if isinstance(a, dict):
        assert a.keys() == b.keys()
        for k in a:
            _close(a[k], b[k])
    elif isinstance(a, (str, bool, type(None))):
        assert a == b
    else:
        np.testing.assert_allclose(np.asarray(b, dtype=float), np.asarray(a, dtype=float), rtol=1e-6,
                                   atol=1e-12)


def _same(a, b, rtol=1e-9):
    assert a.timing["likelihood_taken"] == b.timing["likelihood_taken"]
    assert a.timing["likelihood_steps"] == b.timing["likelihood_steps"] > 0
    assert a.timing["likelihood_renders"] == b.timing["likelihood_renders"]
    assert a.evaluations == b.evaluations
    np.testing.assert_allclose(b.pose, a.pose, rtol=rtol, atol=1e-12)
    np.testing.assert_allclose(b.fit.covariance, a.fit.covariance, rtol=1e-7, atol=0)


def test_device_steps_are_the_host_loop_side_by_side(talus_calcaneus_128, monkeypatch):
    import core.tracking.engine_likelihood as el
    from core.tracking.final_stage import final_stages

    monkeypatch.setattr(el, "STEP_GRAPH", True)
    r, frame, calls, _ = stage_calls(talus_calcaneus_128)
    out = {}
    for on in (False, True):
        monkeypatch.setattr(el, "DEVICE_STEPS", on)
        out[on] = final_stages(r, frame, calls)
    for a, b in zip(out[False], out[True], strict=True):
        assert a.timing["likelihood_taken"] == 1
        _same(a, b)


@pytest.mark.parametrize("mode", [True, "render"])
def test_device_steps_are_the_host_loop_noisy(talus_scene, monkeypatch, mode):
    """The whole registration with its stage (the robust round, the sandwich after its first step; "render":
    the robust refinement's first step on the host)."""
    import core.tracking.engine_likelihood as el
    from core.tracking.register import register

    monkeypatch.setattr(el, "STEP_GRAPH", True)
    frame, start, o = noisy_start(talus_scene)
    model, r = talus_scene["model"], talus_scene["renderer"]
    got = []
    for on in (False, mode):
        monkeypatch.setattr(el, "DEVICE_STEPS", on)
        got.append(register(r, frame, bone=0, initial_pose=start, center=model.centroid, options=o))
    _same(*got)


@pytest.mark.parametrize("case", ["uphill", "spent", "to_tol"])
def test_device_steps_stops(talus_scene, monkeypatch, case):
    """The engine's refine from a start off the optimum: iterations spent (iters 2), an uphill stop
    (every rise uphill: UPHILL_RESOLVED 0, STOP_PRED 0) and refinements to tol (TO_TOL)."""
    import core.tracking.engine_likelihood as el

    monkeypatch.setattr(el, "STEP_GRAPH", True)
    eng = engine_at(talus_scene)
    x0 = np.array([0.3, -0.2, 0.1, 0.3, -0.2, 0.2])
    kw = {"iters": 2} if case == "spent" else {"iters": 12}
    if case == "uphill":
        monkeypatch.setattr(el, "UPHILL_RESOLVED", 0.0)
        monkeypatch.setattr(el, "STOP_PRED", 0.0)
    token = el.TO_TOL.set(True) if case == "to_tol" else None
    try:
        res = []
        for on in (False, True):
            monkeypatch.setattr(el, "DEVICE_STEPS", on)
            eng.renders = 0
            res.append((eng.refine(x0, **kw), eng.renders, eng._last[2].copy()))
    finally:
        if token is not None:
            el.TO_TOL.reset(token)
    (a, ra, la), (b, rb, lb) = res
    assert a["iterations"] == b["iterations"] and ra == rb
    if case == "spent":
        assert a["iterations"] == 2
    np.testing.assert_allclose(b["x"], a["x"], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(lb, la, rtol=1e-9, atol=1e-12)
    assert a["chi2"] == pytest.approx(b["chi2"], rel=1e-9)
    assert (a["design"] is None) == (b["design"] is None)
    np.testing.assert_allclose(b["covariance"], a["covariance"], rtol=1e-7)


def test_device_steps_track_as_the_host_loop(walking_talus, monkeypatch):
    """The talus tracked over 8 frames of the ideal 128² walk (the stage's steps recorded, as on a CUDA
    device): poses, scores, flags, notes, evaluations, confidences and the stage's steps and moves the
    host loop's, within the solves' rounding."""
    import core.tracking.engine_likelihood as el
    from tests.core.tracking.test_one_bone_shared_upload import _track

    monkeypatch.setattr(el, "STEP_GRAPH", True)
    runs = []
    for on in (False, True):
        monkeypatch.setattr(el, "DEVICE_STEPS", on)
        runs.append(_track(walking_talus))
    a, b = runs
    assert a.results.keys() == b.results.keys()
    for key, x in a.results.items():
        y = b.results[key]
        np.testing.assert_allclose(y.pose, x.pose, rtol=1e-9, atol=1e-9)
        assert (x.flags, x.notes, x.evaluations, x.retried) == (y.flags, y.notes, y.evaluations, y.retried)
        assert x.score == pytest.approx(y.score, rel=1e-9, nan_ok=True)
        _close(x.confidence, y.confidence)
        for k in ("likelihood_taken", "likelihood_steps", "likelihood_renders"):
            assert (x.timing or {}).get(k) == (y.timing or {}).get(k)
        for k in ("likelihood_move_mm", "likelihood_move_deg"):
            assert (x.timing or {}).get(k) == pytest.approx((y.timing or {}).get(k), rel=1e-9, abs=1e-12)
    print("bitwise", all(np.array_equal(a.results[k].pose, b.results[k].pose) for k in a.results))
