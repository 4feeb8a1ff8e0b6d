"""Sequential tracking's first frame from keyframes off the truth (ideal 128² views of the talus and
calcaneus, Warp's CPU device, ``sequential_subtract``): the talus, registered first, has the calcaneus
subtracted at its keyframe, where the calcaneus is not, and the negative it leaves pulled the talus
1-2.6° off, unflagged. :data:`core.tracking.frame_step.SEQUENTIAL_SECOND_PASS` (on) registers the
first frame's bones a second time, each with the others at their first pass's poses; frames after the
first are registered as before. The second pass starts from the keyframes, as the first, and is checked
from the first pass's poses; joint tracking's second round does so only with
:data:`~core.tracking.frame_step.FIRST_FRAME_CHECK_FROM_ROUND0` (off)."""

from __future__ import annotations

import numpy as np

from tests.core.tracking.test_joint_first_frame_keyframes import REG, _error, _off_keyframes


def _options(subtract: bool = True):
    from core.tracking.trial import TrackingOptions

    return TrackingOptions(mode="sequential", sequential_subtract=subtract, verify_restarts=0,
                           registration=REG, trajectory_limit=None)


def _spy(monkeypatch) -> list:
    """Every registration of ``track_frame``: (bone, start, guess, bounds, neighbours' (poses, ids),
    verified, attempt)."""
    import core.tracking.frame_step as fs

    seen = []
    real = fs.register_checked

    def spy(*a, **k):
        got = real(*a, **k)
        others = a[9]
        near = None if others is None else (np.array(others[0]), list(others[1]))
        seen.append((a[3], np.array(a[4]), np.array(a[5]), a[6].bounds, near, k.get("verify"), got))
        return got

    monkeypatch.setattr(fs, "register_checked", spy)
    return seen


def test_first_frame_from_keyframes_far_off(talus_calcaneus_128, monkeypatch):
    import core.tracking.frame_step as fs
    from core.tracking.trial import track

    sc, models, r, frames = talus_calcaneus_128
    off = _off_keyframes(sc, models)  # 5 mm / 5° off the truth
    assert fs.SEQUENTIAL_SECOND_PASS  # the default
    seen = _spy(monkeypatch)
    res = track(r, models, frames.__getitem__, [0], keyframes=off, options=_options())
    e = [_error(res.results[(m.name, 0)].pose, sc.poses(0)[k], m.centroid) for k, m in enumerate(models)]
    seen = list(seen)  # (the run's; the spy records the next run too)
    monkeypatch.setattr(fs, "SEQUENTIAL_SECOND_PASS", False)
    old = track(r, models, frames.__getitem__, [0], keyframes=off, options=_options())
    e0 = [_error(old.results[(m.name, 0)].pose, sc.poses(0)[k], m.centroid) for k, m in enumerate(models)]
    # one pass: the talus 0.342 mm / 2.63° off (the calcaneus 0.030 / 0.070), unflagged
    assert e0[0][1] > 1.0 and not old.results[("talus", 0)].flags
    for err in e:  # the talus 0.0024 mm / 0.0096°, the calcaneus 0.0015 / 0.0045 with the second pass
        assert err[0] < 0.02 and err[1] < 0.05
    assert not res.results[("talus", 0)].flags and not res.results[("calcaneus", 0)].flags
    # the registrations: the first pass (verified, the calcaneus at its keyframe for the talus), then the
    # first pass again (from the keyframes, as wide), the other bone at its first pass's pose, each checked
    # from its first pass's pose (from the keyframe 5 mm away, a pose come back would be a jump)
    (b0, s0, g0, w0, o0, v0, a0), (b1, _, _, w1, o1, v1, a1), (b2, s2, g2, w2, o2, v2, a2), \
        (b3, s3, g3, w3, o3, v3, _) = seen[:4]
    assert len(seen) == 4 and (b0, b1, b2, b3) == (0, 1, 0, 1)
    assert (v0, v1, v2, v3) == (True, True, True, True)  # the second pass keeps the restart check too
    assert np.array_equal(s0, off["talus"][0]) and np.array_equal(g0, off["talus"][0])
    assert o0[1] == [1] and np.array_equal(o0[0][0], off["calcaneus"][0])
    assert o1[1] == [0] and np.array_equal(o1[0][0], a0.result.pose)
    assert np.array_equal(s2, off["talus"][0]) and np.array_equal(g2, a0.result.pose)
    assert o2[1] == [1] and np.array_equal(o2[0][0], a1.result.pose)
    assert np.array_equal(s3, off["calcaneus"][0]) and np.array_equal(g3, a1.result.pose)
    assert o3[1] == [0] and np.array_equal(o3[0][0], a2.result.pose)
    assert w0 == w1 == w2 == w3 == (10.0, 10.0)  # the first frame's options (REG widened twice)


def test_later_frames_and_no_subtraction_unchanged(talus_calcaneus_128, monkeypatch):
    import core.tracking.frame_step as fs
    from core.tracking.trial import track

    sc, models, r, frames = talus_calcaneus_128
    given = {m.name: {0: sc.poses(0)[k]} for k, m in enumerate(models)}  # frame 1 from frame 0's poses
    new = track(r, models, frames.__getitem__, [0, 1], keyframes=given, skip=given, options=_options())
    monkeypatch.setattr(fs, "SEQUENTIAL_SECOND_PASS", False)
    old = track(r, models, frames.__getitem__, [0, 1], keyframes=given, skip=given, options=_options())
    for m in models:
        np.testing.assert_array_equal(new.results[(m.name, 1)].pose, old.results[(m.name, 1)].pose)
    monkeypatch.setattr(fs, "SEQUENTIAL_SECOND_PASS", True)
    seen = _spy(monkeypatch)  # nothing subtracted (no stage): one pass, as before
    track(r, models, frames.__getitem__, [0], keyframes=_off_keyframes(sc, models), options=_options(False))
    assert [s[0] for s in seen] == [0, 1] and all(s[4] is None for s in seen)


def test_second_pass_after_a_flagged_first_checked_from_the_keyframe(talus_calcaneus_128, monkeypatch):
    """A first pass left flagged: the second is checked from the keyframe, as the first was (from the
    flagged pose it would pass a jump unflagged)."""
    import core.tracking.frame_step as fs
    from core.tracking.trial import track

    sc, models, r, frames = talus_calcaneus_128
    off = _off_keyframes(sc, models)
    real = fs.register_checked
    seen = []

    def flagged(*a, **k):  # the talus's first pass flagged
        got = real(*a, **k)
        if a[3] == 0 and not any(b == 0 for b, _, _ in seen):  # the talus's first pass only
            got.flags = [*got.flags, "a flag"]
        seen.append((a[3], np.array(a[5]), k.get("verify")))
        return got

    monkeypatch.setattr(fs, "register_checked", flagged)
    track(r, models, frames.__getitem__, [0], keyframes=off, options=_options())
    (b0, g0, _), (b1, _, _), (b2, g2, v2), (b3, g3, _) = seen
    assert (b0, b1, b2, b3) == (0, 1, 0, 1) and v2  # the second pass verified as the first
    assert np.array_equal(g2, off["talus"][0]) and np.array_equal(g0, g2)  # the talus: from its keyframe
    assert not np.array_equal(g3, off["calcaneus"][0])  # the calcaneus: from its unflagged first pass


def test_joint_second_round_checked_from_round_0(talus_calcaneus_128, monkeypatch):
    """Joint tracking's first-frame second round (FIRST_FRAME_SECOND_ROUND) from keyframes 5 mm / 5° off:
    checked from round 0's poses (FIRST_FRAME_CHECK_FROM_ROUND0, off by default: it left the tibia of a
    three-bone scene 0.39-0.50° off) it is not taken for a jump from the keyframes and retried."""
    import core.tracking.frame_step as fs
    from core.tracking.trial import TrackingOptions, track

    sc, models, r, frames = talus_calcaneus_128
    off = _off_keyframes(sc, models)
    o = TrackingOptions(mode="joint", joint_rounds=1, verify_restarts=0, registration=REG,
                        trajectory_limit=None)
    assert not fs.FIRST_FRAME_CHECK_FROM_ROUND0  # the default
    monkeypatch.setattr(fs, "FIRST_FRAME_CHECK_FROM_ROUND0", True)
    monkeypatch.setattr(fs, "FIRST_FRAME_AS_PASS", False)  # (the lockstep round's switch)
    monkeypatch.setattr(fs, "FIRST_FRAME_AGAIN_MOVED", False)  # (the lockstep round as before)
    seen = _spy(monkeypatch)
    res = track(r, models, frames.__getitem__, [0], keyframes=off, options=o)
    assert [s[0] for s in seen] == [0, 1, 0, 1]
    for (_, _, g, _, _, v, a), first in zip(seen[2:], seen[:2], strict=True):
        assert not v and not a.retried and np.array_equal(g, first[6].result.pose)
    # the talus 0.0062 mm / 0.0019°, the calcaneus 0.0084 / 0.0052 at 857 and 724 evaluations (from the
    # keyframes: 0.0013 / 0.0048 and 0.0088 / 0.0089 at 1688 and 1435, the second round retried)
    for k, m in enumerate(models):
        e = _error(res.results[(m.name, 0)].pose, sc.poses(0)[k], m.centroid)
        assert e[0] < 0.02 and e[1] < 0.05
