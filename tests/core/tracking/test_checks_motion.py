"""The motion, relative-σ and flagged-first-frame checks of core.tracking.checks (no tracking)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from core.geometry.transforms import pose_from_params
from core.tracking.checks import MOTION_FLOOR, confirmable, failures, motion_check, sigma_check
from core.tracking.options import TrackingOptions
from core.tracking.trial import _BoneState

O = TrackingOptions()
C = np.array([10.0, -5.0, 30.0])


def _pose(p):
    return pose_from_params(np.r_[p[:3], np.radians(p[3:])], center=C, base=np.eye(4))


def _walk(n, noise=0.02, seed=0):
    """A bone accelerating smoothly (0.8 mm and 0.6 deg per frame, growing), registered with noise."""
    g = np.random.default_rng(seed)
    out = []
    for f in range(n):
        p = np.array([0.8 * f + 0.01 * f * f, 0.3 * f, -0.2 * f, 0.6 * f, 0.1 * f, 0.005 * f * f])
        out.append((f, _pose(p + g.normal(scale=noise, size=6))))
    return out, lambda f: _pose(np.array([0.8 * f + 0.01 * f * f, 0.3 * f, -0.2 * f, 0.6 * f, 0.1 * f,
                                          0.005 * f * f]))


def _res(pose, score=0.5):
    return SimpleNamespace(score=score, converged=True, reason="", pose=pose)


def test_motion_check_passes_the_track_and_flags_a_pose_off_it():
    hist, truth = _walk(12)
    assert motion_check(truth(12), hist, 12, C) == []
    # a valid image of the bone 2.5 mm and 2 deg along its path later: within max_jump, off the motion
    off = truth(12) @ np.linalg.inv(truth(0)) @ _pose(np.array([2.5, 0, 0, 0, 0, 0])) @ truth(0)
    f = motion_check(off, hist, 12, C)
    assert len(f) == 1 and f[0].startswith("unexpected motion") and not confirmable(f[0]), f
    # the same pose through failures(), with the history and the frame number
    f = failures(_res(off), truth(12), C, [0.5] * 12, O, start_score=0.5, history=hist, frame=12)
    assert any(x.startswith("unexpected motion") for x in f), f
    # too little history: not judged
    assert motion_check(off, hist[:4], 4, C) == []


def test_the_motion_limit_has_a_floor_and_grows_with_the_frame_gap():
    hist, truth = _walk(12, noise=0.0)  # residuals ~0: the floor sets the limit
    p = truth(12).copy()
    p[0, 3] += 0.8 * MOTION_FLOOR[0]
    assert motion_check(p, hist, 12, C) == []
    p[0, 3] += 0.4 * MOTION_FLOOR[0]
    assert motion_check(p, hist, 12, C)
    # three frames on (the frames between flagged): the reach of a constant acceleration, 6x
    q = truth(14).copy()
    q[0, 3] += 3.0 * MOTION_FLOOR[0]
    assert motion_check(q, hist, 14, C) == []


def test_a_corrected_wrong_start_is_not_flagged_by_the_motion():
    hist, truth = _walk(12)
    start = truth(12).copy()
    start[:3, 3] += [4.0, -3.0, 1.0]  # the search started 5 mm off (a stale guess)
    f = failures(_res(truth(12)), start, C, [0.5] * 12, O, start_score=0.5, jump_factor=O.retry_factor,
                 history=hist, frame=12)
    assert f == [], f


def test_sigma_check_is_relative_to_the_bone_and_needs_history():
    good = [(0.15, 0.9)] * 8
    conf = {"translation_mm": 0.2, "rotation_deg": 1.2, "well_posed": True}
    assert sigma_check(conf, good) == []
    wide = {"translation_mm": 0.2, "rotation_deg": 3.5, "well_posed": True}
    f = sigma_check(wide, good)
    assert len(f) == 1 and f[0].startswith("uncertain") and "recent" in f[0], f
    assert sigma_check(wide, good[:3]) == []  # too few frames to judge
    flat = {"translation_mm": None, "rotation_deg": None, "well_posed": False}
    assert sigma_check(flat, good)[0].startswith("uncertain (the pose is not determined")
    assert sigma_check(None, good) == []


def test_a_flagged_first_frame_is_the_reference_until_a_good_score():
    # the wrist radius with the Gauss-Newton global search (one H100): frame 0099 flagged (not
    # converged) at 0.391, frame 0158 17 mm away at 0.283, which nothing compared with
    f = failures(_res(np.eye(4), 0.283), np.eye(4), C, [], O, reference=0.391)
    assert len(f) == 1 and f[0].startswith("low score against the flagged first frame"), f
    assert not confirmable(f[0])
    assert failures(_res(np.eye(4), 0.40), np.eye(4), C, [], O, reference=0.391) == []
    assert failures(_res(np.eye(4), 0.283), np.eye(4), C, [0.30] * 3, O, reference=0.391) == []
    st = _BoneState()
    st.add_flagged(0.391)
    st.add_flagged(0.2)
    assert st.reference == 0.391
    st.add_good(5, np.eye(4), 0.40, {"translation_mm": 0.1, "rotation_deg": 0.5})
    assert st.sigmas == [(0.1, 0.5)] and st.start_score == 0.40
    st2 = _BoneState()
    st2.add_good(0, np.eye(4), 0.5)
    st2.add_flagged(0.1)
    assert st2.reference is None


def test_a_frame_flagged_only_uncertain_still_feeds_the_guesses():
    from core.tracking.results import FrameResult

    st = _BoneState()
    conf = {"translation_mm": 0.1, "rotation_deg": 0.5}
    st.add(0, FrameResult("b", 0, np.eye(4), 0.5, 1, 0.0, True, (), False, conf))
    st.add(1, FrameResult("b", 1, np.eye(4), 0.45, 1, 0.0, False, ("uncertain (confidence)",), False, conf))
    assert [f for f, _ in st.history] == [0, 1] and st.scores == [0.5, 0.45] and st.sigmas == [(0.1, 0.5)]
    st.add(2, FrameResult("b", 2, np.eye(4), 0.2, 1, 0.0, False, ("score collapse", "uncertain (x)"), False,
                          conf))
    st.add(3, FrameResult("b", 3, None, float("nan"), 0, 0.0, False, ("outside the field of view",)))
    assert [f for f, _ in st.history] == [0, 1] and st.reference is None


def test_the_jump_limit_grows_with_a_stale_guess():
    hist, truth = _walk(12, noise=0.0)
    far = truth(11).copy()
    far[0, 3] += 6.0  # 6 mm from the guess: over max_jump (4 mm) one frame on
    kw = {"start_score": 0.5, "history": hist[:11], "frame": 11}
    assert any(x.startswith("pose jump") for x in failures(_res(far), truth(11), C, [0.5] * 11, O, **kw))
    kw = {"start_score": 0.5, "history": hist[:9], "frame": 11}  # two frames flagged: the guess 3 steps on
    assert not any(x.startswith("pose jump") for x in failures(_res(far), truth(11), C, [0.5] * 9, O, **kw))


def test_the_guess_is_the_motion_checks_prediction_and_limits_are_the_recent_medians():
    """predict_pose's velocity guess is the prediction motion_miss judges a pose against (the same
    bytes; the guess handed out is the caller's own array), and the limits are limit x the median of
    the recent misses (numpy's median)."""
    from core.tracking.checks import _distance, _miss, _reach, motion_miss, pose_delta, step_pose
    from core.tracking.frame_state import predict_pose

    hist, truth = _walk(9, seed=3)
    (f0, T0), (f1, T1) = hist[-2], hist[-1]
    want = step_pose(pose_delta(T0, T1, C) * (9 - f1) / (f1 - f0), T1, C)
    g = predict_pose(hist, 9, C)
    assert g.tobytes() == want.tobytes() and g.flags.writeable
    g[0, 3] += 100.0  # the caller's array: the next guess and the check are unchanged
    assert predict_pose(hist, 9, C).tobytes() == want.tobytes()
    dt, dr, lim_t, lim_r, m = motion_miss(truth(9), hist, 9, C, n=5, limit=6.0, floor=(0.0, 0.0))
    assert (dt, dr) == _distance(want, truth(9), C)
    med = np.median([_miss(*hist[j - 2], *hist[j - 1], *hist[j], C) for j in range(4, 9)], axis=0)
    assert m == 5 and (lim_t, lim_r) == (6.0 * med[0] * _reach(f0, f1, 9), 6.0 * med[1] * _reach(f0, f1, 9))


def test_a_prediction_passed_in_is_the_one_judged_against():
    """The frame step hands the check its frame's prediction (motion_prediction, also the velocity
    guess): the same flags as computing it; a different prediction moves the measured miss."""
    from core.tracking.checks import _distance, motion_miss
    from core.tracking.frame_state import motion_prediction, predict_pose

    hist, truth = _walk(12, seed=4)
    pred = motion_prediction(hist, 12, C)
    g = predict_pose(hist, 12, C, prediction=pred)
    assert g.tobytes() == predict_pose(hist, 12, C).tobytes() and g is not pred
    assert motion_prediction(hist[:1], 12, C) is None
    off = _pose(np.array([10.4, 3.6, -2.4, 7.2, 1.2, 0.72]) + np.r_[2.0, 0, 0, 0, 0, 0])
    for pose in (truth(12), off):
        assert motion_check(pose, hist, 12, C, prediction=pred) == motion_check(pose, list(hist), 12, C)
    moved = pred.copy()
    moved[0, 3] += 1.0
    got = motion_miss(truth(12), hist, 12, C, prediction=moved)
    assert got[:2] == _distance(moved, truth(12), C)
    assert motion_miss(truth(12), hist, 12, C)[:2] == _distance(pred, truth(12), C)  # kept limits, own pose
