"""Joint tracking's next lockstep round started before the checks of the last
(core.tracking.frame_step): the same results as checking first, on ideal 128² views of the talus
and calcaneus (CPU device), whether the checks pass (the round started ahead is used) or flag a
bone (it is dropped and run again from the checked poses)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest


@pytest.fixture(scope="module")
def two_bones(talus_calcaneus_128):
    return talus_calcaneus_128


def _run(two_bones, monkeypatch, ahead: bool, **opts):
    import core.tracking.frame_step as fs
    import core.tracking.joint as joint
    from core.tracking.register import RegistrationOptions
    from core.tracking.trial import TrackingOptions, track

    sc, models, r, frames = two_bones
    calls = []
    real = joint.register_together

    def counted(*a, **k):  # (the checks run in the round started ahead: not only the motion limits)
        idle = k.get("idle")
        calls.append(idle is not None and "limits_ahead" not in idle.__qualname__)
        return real(*a, **k)

    monkeypatch.setattr(fs, "register_together", counted)
    monkeypatch.setattr(fs, "AHEAD", ahead)
    skip = {m.name: {0: sc.poses(0)[k]} for k, m in enumerate(models)}
    reg = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")
    opts = {"joint_rounds": 2, **opts}  # the round started ahead is the second: two rounds, pinned
    o = TrackingOptions(mode="joint", verify_restarts=0, registration=reg, **opts)
    res = track(r, models, frames.__getitem__, [0, 1], keyframes=skip, skip=skip, options=o)
    return res, calls


def _same(a, b) -> None:
    assert a.results.keys() == b.results.keys()
    for k, x in a.results.items():
        y = b.results[k]
        assert np.asarray(x.pose).tobytes() == np.asarray(y.pose).tobytes(), k
        assert (x.score, x.evaluations, x.flags, x.retried, x.notes) == (y.score, y.evaluations, y.flags,
                                                                          y.retried, y.notes), k
        assert x.confidence == y.confidence, k


def test_round_ahead_gives_the_results_of_checking_first(two_bones, monkeypatch):
    checked_first, calls0 = _run(two_bones, monkeypatch, False)
    ahead, calls1 = _run(two_bones, monkeypatch, True)
    assert calls0 == [False, False] and calls1 == [False, True]  # the second round started ahead, used
    assert not any(fr.flags for fr in ahead.results.values())
    _same(checked_first, ahead)


def test_round_ahead_used_or_dropped_as_the_checks_decide(two_bones, monkeypatch):
    """Every registration flagged (its retries outside the view, so the flagged pose stands): the
    checks keep the poses and the round started ahead is used; where a check moves a pose (here
    the flagged attempts are moved by 1 µm after their checks) it is dropped and run again from
    the checked poses. The results are those of checking first either way."""
    import core.tracking.attempt as attempt
    import core.tracking.frame_step as fs
    from core.tracking.cost import OutsideViewError

    def outside(*a, **k):
        raise OutsideViewError("test")

    monkeypatch.setattr(attempt, "_failures", lambda *a, **k: ["pose jump (test)"])
    monkeypatch.setattr(attempt, "register", outside)
    checked_first, calls0 = _run(two_bones, monkeypatch, False)
    ahead, calls1 = _run(two_bones, monkeypatch, True)
    assert all(fr.retried and fr.flags == ("pose jump (test)",) for fr in ahead.results.values())
    assert calls0 == [False, False] and calls1 == [False, True]
    _same(checked_first, ahead)

    real = fs.register_checked

    def moved(*a, **k):
        got = real(*a, **k)
        if got is not None and got.flags and got.result is not None:
            pose = np.array(got.result.pose, dtype=float)
            pose[0, 3] += 1e-3
            got.result = replace(got.result, pose=pose)
        return got

    monkeypatch.setattr(fs, "register_checked", moved)
    checked_first, calls0 = _run(two_bones, monkeypatch, False)
    ahead, calls1 = _run(two_bones, monkeypatch, True)
    assert calls0 == [False, False] and calls1 == [False, True, False]
    _same(checked_first, ahead)
