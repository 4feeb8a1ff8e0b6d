"""Joint tracking's first frame (frame_step.FIRST_FRAME_AGAIN_MOVED, on; FIRST_FRAME_AS_PASS off): the second
round in lockstep as before, then side by side again only the bones whose neighbours moved in it by more than
FIRST_FRAME_MOVE_FLOOR, from their poses (ideal 128² views of the talus and calcaneus, Warp's CPU device,
keyframes 5 mm / 5° off); the bones' moves judged without rendering."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from tests.core.tracking.test_joint_first_frame_keyframes import REG, _error, _off_keyframes


def test_moved_around_without_rendering():
    from core.geometry.transforms import pose_from_params
    from core.tracking.frame_step import FIRST_FRAME_MOVE_FLOOR, _moved_around

    assert FIRST_FRAME_MOVE_FLOOR == (0.02, 0.05)
    bones = [SimpleNamespace(centroid=np.zeros(3)) for _ in range(3)]
    ok = SimpleNamespace(result=SimpleNamespace(pose=np.eye(4)), flags=[])
    before = {k: np.eye(4) for k in range(3)}

    def moved(mm=0.0, deg=0.0):
        return pose_from_params(np.r_[mm, 0.0, 0.0, np.radians(deg), 0.0, 0.0], center=np.zeros(3))

    out = {k: ok for k in range(3)}
    eye = np.eye(4)
    assert _moved_around([0, 1, 2], before, {0: moved(0.019), 1: moved(deg=0.049), 2: eye}, out, bones) == []
    # bone 0 moved 0.06 deg: its neighbours go round again, not itself (its neighbours stayed)
    assert _moved_around([0, 1, 2], before, {0: moved(deg=0.06), 1: eye, 2: eye}, out, bones) == [1, 2]
    # 0.03 mm: the same; a flagged bone (or one outside a view) keeps its round's result
    flagged = {**out, 2: SimpleNamespace(result=ok.result, flags=["a flag"])}
    assert _moved_around([0, 1, 2], before, {0: moved(0.03), 1: eye, 2: eye}, flagged, bones) == [1]
    # two bones moved: each has a neighbour that moved
    cur = {0: moved(0.03), 1: moved(deg=0.1), 2: np.eye(4)}
    assert _moved_around([0, 1, 2], before, cur, out, bones) == [0, 1, 2]
    assert _moved_around([0, 1], before, cur, out, bones) == [0, 1]  # only the round's bones


def test_lockstep_round_then_the_moved(talus_calcaneus_128, monkeypatch):
    import core.tracking.frame_step as fs
    from core.tracking.trial import TrackingOptions, track

    sc, models, r, frames = talus_calcaneus_128
    off = _off_keyframes(sc, models)
    assert fs.FIRST_FRAME_AGAIN_MOVED and not fs.FIRST_FRAME_AS_PASS  # the defaults
    rounds, checks = [], []
    real_t, real_c = fs.register_together, fs.register_checked

    def together(renderer, frame, jobs, options, **k):
        rounds.append(([j.bone for j in jobs], [np.array(j.initial_pose) for j in jobs], options.bounds))
        return real_t(renderer, frame, jobs, options, **k)

    def checked(*a, **k):
        got = real_c(*a, **k)
        checks.append((a[3], k.get("pre") is not None, k.get("verify"), np.array(a[5]), got))
        return got

    monkeypatch.setattr(fs, "register_together", together)
    monkeypatch.setattr(fs, "register_checked", checked)
    o = TrackingOptions(mode="joint", joint_rounds=1, verify_restarts=0, registration=REG,
                        trajectory_limit=None)
    res = track(r, models, frames.__getitem__, [0], keyframes=off, options=o)
    # round 0 one at a time; round 1 side by side from round 0's poses, checked from the keyframes as
    # before, not verified (round 0 left them unflagged)
    assert [(b, p) for b, p, *_ in checks[:2]] == [(0, False), (1, False)]
    (b1, s1, w1) = rounds[0]
    assert b1 == [0, 1] and w1 == REG.bounds
    assert all(np.array_equal(s, c[4].result.pose) for s, c in zip(s1, checks[:2], strict=True))
    for (_, p, v, g, _), m in zip(checks[2:4], models, strict=True):
        assert p and not v and np.array_equal(g, off[m.name][0])
    # then again, side by side, the bones whose neighbour moved in round 1, from their round-1 poses,
    # checked from them
    r1 = {c[0]: c[4].result.pose for c in checks[2:4]}
    moved = [i for i in (0, 1) if _apart(checks[1 - i][4].result.pose, r1[1 - i], models[1 - i].centroid)]
    assert moved and [c[0] for c in checks[4:]] == moved
    for c in checks[4:]:
        assert not c[2] and np.array_equal(c[3], r1[c[0]])
    if len(moved) > 1:
        assert rounds[1][0] == moved
        assert all(np.array_equal(s, r1[b]) for b, s in zip(*rounds[1][:2], strict=True))
    for k, m in enumerate(models):  # the talus 0.0xx deg, the calcaneus ...
        e = _error(res.results[(m.name, 0)].pose, sc.poses(0)[k], m.centroid)
        assert e[0] < 0.02 and e[1] < 0.05


def _apart(P, Q, c) -> bool:
    from core.tracking.checks import _distance
    from core.tracking.frame_step import FIRST_FRAME_MOVE_FLOOR

    dt, dr = _distance(P, Q, c)
    return dt > FIRST_FRAME_MOVE_FLOOR[0] or dr > FIRST_FRAME_MOVE_FLOOR[1]
