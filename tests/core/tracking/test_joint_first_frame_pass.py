"""Joint tracking's first-frame second round as sequential tracking's second pass
(:data:`core.tracking.frame_step.FIRST_FRAME_AS_PASS`, on in this module; ideal 128² views, CPU device):
one bone at a time (the bones before it at this round's poses), from its keyframe with the first
frame's options, with the restart check of round 0. In lockstep the round subtracted every neighbour at
its round-0 pose, so with three bones the talus saw the tibia 0.86° off and ended 0.11-0.12° off; and
the round ran without the restart check, so a flag of round 0's check (an ambiguous optimum) was
dropped."""

from __future__ import annotations

import numpy as np
import pytest

from core.tracking.register import RegistrationOptions

REG = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")


def _error(P, truth, center) -> tuple[float, float]:
    from core.tracking.checks import pose_delta

    d = pose_delta(truth, P, center)
    return float(np.linalg.norm(d[:3])), float(np.rad2deg(np.linalg.norm(d[3:])))


@pytest.fixture(autouse=True)
def _as_pass(monkeypatch):
    """FIRST_FRAME_AS_PASS on (off by default since the lockstep round's 1024² cost)."""
    import core.tracking.frame_step as fs

    monkeypatch.setattr(fs, "FIRST_FRAME_AS_PASS", True)


def _spy(monkeypatch) -> list:
    """Every register_checked call of frame_step: (bone, others' poses, guess, verify, result)."""
    import core.tracking.frame_step as fs

    real = fs.register_checked
    seen: list = []

    def spy(*a, **k):
        got = real(*a, **k)
        seen.append((a[3], None if a[9] is None else (np.array(a[9][0]), list(a[9][1])), np.array(a[5]),
                     k.get("verify"), got))
        return got

    monkeypatch.setattr(fs, "register_checked", spy)
    return seen


def test_second_round_one_bone_at_a_time_verified(talus_calcaneus_128, monkeypatch):
    import core.tracking.frame_step as fs
    from core.tracking.trial import TrackingOptions, track

    assert fs.FIRST_FRAME_SECOND_ROUND and fs.FIRST_FRAME_AS_PASS  # (the default; the module's fixture)
    sc, models, r, frames = talus_calcaneus_128
    keys = {m.name: {0: sc.poses(0)[k]} for k, m in enumerate(models)}
    o = TrackingOptions(mode="joint", verify_restarts=0, registration=REG)
    seen = _spy(monkeypatch)
    track(r, models, frames.__getitem__, [0], keyframes=keys, options=o)
    assert [s[0] for s in seen] == [0, 1, 0, 1]
    assert [s[3] for s in seen] == [True, True, True, True]  # the second round checked as round 0
    (_, o0, _, _, a0), (_, o1, _, _, a1), (_, o2, g2, _, a2), (_, o3, g3, _, _) = seen
    assert o0 is None and np.array_equal(o1[0][0], a0.result.pose)  # round 0: the bones before
    np.testing.assert_array_equal(o2[0][0], a1.result.pose)  # the talus: the calcaneus's round-0 pose
    np.testing.assert_array_equal(o3[0][0], a2.result.pose)  # the calcaneus: the talus's round-1 pose
    np.testing.assert_array_equal(g2, a0.result.pose)  # checked from round 0's unflagged poses
    np.testing.assert_array_equal(g3, a1.result.pose)


def _ambiguous(monkeypatch, times: int) -> list:
    """verify_start reporting the talus's optimum ambiguous in its first ``times`` checks (a restart
    2 mm / 3° away scoring the same) and confirming every other; the calls (bone) in order."""
    import core.tracking.attempt as at
    from core.tracking.verify import StartCheck

    calls: list = []

    def check(renderer, frame, *, bone, result, **k):
        calls.append(bone)
        amb = bone == 0 and calls.count(0) <= times
        return StartCheck(result, False, amb, (float(result.score),), ((2.0, 3.0),), 0)

    monkeypatch.setattr(at, "verify_start", check)
    return calls


@pytest.mark.parametrize("times", [2, 1])
def test_round_0_flag_kept_unless_the_second_round_clears_it(talus_calcaneus_128, monkeypatch, times):
    """Round 0 flags the talus (its restart check: an ambiguous optimum). The second round runs the
    same check: still ambiguous (``times`` 2), the flag stays; confirmed there (1), it is cleared, the
    talus checked from its keyframe (round 0 flagged). In lockstep (the switch off) the second round ran
    no restart check and the flag was dropped either way."""
    import core.tracking.frame_step as fs
    from core.tracking.trial import TrackingOptions, track

    sc, models, r, frames = talus_calcaneus_128
    keys = {m.name: {0: sc.poses(0)[k]} for k, m in enumerate(models)}
    o = TrackingOptions(mode="joint", verify_restarts=1, registration=REG)
    calls = _ambiguous(monkeypatch, times)
    seen = _spy(monkeypatch)
    res = track(r, models, frames.__getitem__, [0], keyframes=keys, options=o)
    assert calls == [0, 1, 0, 1]
    assert any(f.startswith("ambiguous optimum") for f in seen[0][4].flags)  # round 0 flagged
    np.testing.assert_array_equal(seen[2][2], keys["talus"][0])  # round 1 checked from the keyframe
    flags = res.results[("talus", 0)].flags
    assert any(f.startswith("ambiguous optimum") for f in flags) == (times == 2)
    assert not res.results[("calcaneus", 0)].flags
    monkeypatch.setattr(fs, "FIRST_FRAME_AS_PASS", False)  # lockstep: no check in the second round
    monkeypatch.setattr(fs, "FIRST_FRAME_AGAIN_MOVED", False)  # (as before it)
    calls.clear()
    res = track(r, models, frames.__getitem__, [0], keyframes=keys, options=o)
    assert calls == [0, 1] and not res.results[("talus", 0)].flags


@pytest.fixture(scope="module")
def three_bones_128():
    """The study's ideal 128² tibia-talus-calcaneus scene (frame 0) and its draw-0 keyframes 5 mm / 5°
    off (:mod:`core.studies.tracking.first_frame_keyframes`)."""
    from core.studies.tracking.first_frame_keyframes import keyframes, scene

    built = scene(("tibia", "talus", "calcaneus"))
    return built, keyframes(built[0], built[1], 0, 5.0)


def test_three_bones_talus_with_the_tibia_of_this_round(three_bones_128, monkeypatch):
    """Draw 0 of the study: the talus 0.0243 mm / 0.1214° off in lockstep (the tibia subtracted at its
    round-0 pose, 0.86° off); one bone at a time 0.0005 mm / 0.0049° (sequentially 0.0086°), the tibia
    the same 0.0227° (it is registered first either way), the calcaneus 0.0176 → 0.0021°."""
    from core.tracking.trial import TrackingOptions, track

    (sc, models, r, frames), keys = three_bones_128
    o = TrackingOptions(mode="joint", joint_rounds=1, verify_restarts=0, registration=REG,
                        trajectory_limit=None)
    seen = _spy(monkeypatch)
    res = track(r, models, frames.__getitem__, [0], keyframes=keys, options=o)
    assert [s[0] for s in seen] == [0, 1, 2, 0, 1, 2] and all(s[3] for s in seen)
    tibia1 = seen[3][4].result.pose
    o4 = seen[4][1]  # the talus's second round: the tibia of this round, the calcaneus of round 0
    assert o4[1] == [0, 2]
    np.testing.assert_array_equal(o4[0][0], tibia1)
    np.testing.assert_array_equal(o4[0][1], seen[2][4].result.pose)
    errors = [_error(res.results[(m.name, 0)].pose, sc.poses(0)[k], m.centroid) for k, m in enumerate(models)]
    assert errors[1][0] < 0.005 and errors[1][1] < 0.02  # the talus (0.1214° in lockstep)
    assert errors[0][1] < 0.05 and errors[2][1] < 0.02  # the tibia, the calcaneus
