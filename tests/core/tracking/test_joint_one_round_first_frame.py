"""Joint tracking's first frame with one round (``TrackingOptions.joint_rounds`` 1, the default since
8dbdcc2) and with two: round 0 of a first frame is verified either way (``verify`` of
:func:`core.tracking.attempt.register_checked`: ``first and rnd == 0``), a second round is not; with
one round a bone has only the bones registered before it in the frame subtracted (nothing known
yet; :data:`core.tracking.frame_step.JOINT_KEYFRAMES`, off, would subtract the others' keyframes); a
second round in lockstep subtracts each bone's round-0 pose (ideal 128² views, CPU device). The tests
pin the lockstep round (``FIRST_FRAME_AS_PASS`` off; on by default, the second round of a first frame
is sequential tracking's second pass: ``test_joint_first_frame_pass.py``). With
:data:`core.tracking.frame_step.FIRST_FRAME_SECOND_ROUND` (on by default) a first frame gets the second
round whatever the rounds: the test turns it off to see the rounds as asked, and checks the default too."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.mark.parametrize("rounds", [1, 2])
def test_first_frame_rounds_verify_and_neighbours(talus_calcaneus_128, monkeypatch, rounds):
    import core.tracking.frame_step as fs
    from core.tracking.register import RegistrationOptions
    from core.tracking.trial import TrackingOptions, track

    sc, models, r, frames = talus_calcaneus_128
    calls: list[tuple] = []
    real = fs.register_checked

    def spy(renderer, frame, bone, i, start, *a, **k):
        got = real(renderer, frame, bone, i, start, *a, **k)
        others = a[4]
        calls.append((i, k["verify"], None if others is None else np.array(others[0]),
                      None if got.result is None else got.result.pose))
        return got

    monkeypatch.setattr(fs, "register_checked", spy)
    monkeypatch.setattr(fs, "FIRST_FRAME_SECOND_ROUND", False)  # the rounds as asked (the default: one more)
    monkeypatch.setattr(fs, "FIRST_FRAME_AS_PASS", False)  # the second round in lockstep
    monkeypatch.setattr(fs, "FIRST_FRAME_AGAIN_MOVED", False)  # (the lockstep round as before)
    keys = {m.name: {0: sc.poses(0)[k]} for k, m in enumerate(models)}  # keyframes only: a first frame
    reg = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")
    o = TrackingOptions(mode="joint", joint_rounds=rounds, verify_restarts=0, registration=reg)
    res = track(r, models, frames.__getitem__, [0], keyframes=keys, options=o)
    assert [c[0] for c in calls] == [0, 1] * rounds  # round 0 one bone after the other (no history)
    assert [c[1] for c in calls] == [True, True] + [False, False] * (rounds - 1)  # round 0 verified
    assert calls[0][2] is None  # the talus first: nothing registered yet to subtract
    np.testing.assert_array_equal(calls[1][2][0], calls[0][3])  # the calcaneus: the talus's new pose
    if rounds == 2:  # the second round in lockstep: each bone with the other's round-0 pose
        np.testing.assert_array_equal(calls[2][2][0], calls[1][3])
        np.testing.assert_array_equal(calls[3][2][0], calls[0][3])
    for m in models:
        assert res.results[(m.name, 0)].pose is not None


def test_one_round_gets_a_second_round_in_the_first_frame_by_default(talus_calcaneus_128, monkeypatch):
    """FIRST_FRAME_SECOND_ROUND on (the default): joint tracking with one round registers a first frame
    twice; in lockstep (FIRST_FRAME_AS_PASS off) the second round not verified and each bone with the
    other's round-0 pose, as two rounds do."""
    import core.tracking.frame_step as fs
    from core.tracking.register import RegistrationOptions
    from core.tracking.trial import TrackingOptions, track

    assert fs.FIRST_FRAME_SECOND_ROUND
    sc, models, r, frames = talus_calcaneus_128
    calls: list[tuple] = []
    real = fs.register_checked

    def spy(renderer, frame, bone, i, start, *a, **k):
        got = real(renderer, frame, bone, i, start, *a, **k)
        calls.append((i, k["verify"], None if a[4] is None else np.array(a[4][0]),
                      None if got.result is None else got.result.pose))
        return got

    monkeypatch.setattr(fs, "register_checked", spy)
    monkeypatch.setattr(fs, "FIRST_FRAME_AS_PASS", False)  # the second round in lockstep
    monkeypatch.setattr(fs, "FIRST_FRAME_AGAIN_MOVED", False)  # (the lockstep round as before)
    keys = {m.name: {0: sc.poses(0)[k]} for k, m in enumerate(models)}
    reg = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")
    o = TrackingOptions(mode="joint", verify_restarts=0, registration=reg)
    assert o.joint_rounds == 1
    track(r, models, frames.__getitem__, [0], keyframes=keys, options=o)
    assert [c[0] for c in calls] == [0, 1, 0, 1]
    assert [c[1] for c in calls] == [True, True, False, False]
    np.testing.assert_array_equal(calls[2][2][0], calls[1][3])  # the talus with the calcaneus's round-0 pose
    np.testing.assert_array_equal(calls[3][2][0], calls[0][3])
