"""The trajectory post-pass (core.tracking.flags_post): a frame off its neighbours' fit is flagged
once the trial is tracked, good frames of a smooth noisy track are not, and track() journals it."""

from __future__ import annotations

import numpy as np
import pytest

from core.geometry.transforms import pose_from_params
from core.tracking import flags_post
from core.tracking.flags_post import FLAG, apply_trajectory_flags, trajectory_flags, trajectory_residuals
from core.tracking.results import FrameResult, TrackingResult
from tests.core.tracking.track_helpers import C, walking_track


@pytest.fixture(autouse=True)
def _trajectory_pass_alone(monkeypatch):
    """These tests judge the trajectory post-pass alone: the first frame's backward registration
    (:mod:`core.tracking.backward_check`, tests of its own) off."""
    from core.tracking import backward_check

    monkeypatch.setattr(backward_check, "backward_check", lambda *a, **k: [])  # as backward_limit=None


def _track(n=40, noise=(0.01, 0.05), seed=1, off=None):
    """Poses of a bone in walking-like smooth motion (mm, degrees per frame) with registration noise;
    ``off``: (frame, mm, degrees) added to one frame."""
    def shift(k, p):
        if off is not None and k == off[0]:
            p[0] += off[1]
            p[5] += np.radians(off[2])

    return walking_track(n, noise, seed, shift)


def _result(P, flags=None, name="tibia"):
    res = {(name, k): FrameResult(name, k, P[k], 0.8, 10, 0.0, True, tuple((flags or {}).get(k, ())))
           for k in range(len(P))}
    return TrackingResult((name,), tuple(range(len(P))), res, "complete", 1.0)


def test_a_frame_off_the_track_is_flagged_and_the_smooth_noisy_track_is_not():
    P = _track()
    assert trajectory_flags(np.arange(len(P)), P, C) == {}
    bad = _track(off=(17, 0.0, 0.5))  # 0.5 deg in one frame: 10x the per-axis noise
    got = trajectory_flags(np.arange(len(bad)), bad, C)
    assert list(got) == [17]
    assert got[17].startswith(FLAG) and "deg" in got[17]
    order = np.random.default_rng(0).permutation(len(bad))  # frames in any order (a backward run)
    assert trajectory_flags(order, bad[order], C) == got
    R = trajectory_residuals(np.arange(len(bad)), bad, C)
    np.testing.assert_allclose(trajectory_residuals(order, bad[order], C), R[order])
    shifted = _track(off=(30, 0.12, 0.0))  # 0.12 mm: 12x the translation noise
    assert list(trajectory_flags(np.arange(len(shifted)), shifted, C)) == [30]


def test_noise_free_tracks_and_short_trials_are_not_judged():
    P = _track(noise=(0.0, 0.0))
    R = trajectory_residuals(np.arange(len(P)), P, C)
    # a parabola through ±4 frames follows the motion to well within the floor; at the trial's ends, through
    # the 8 frames on one side (flags_ends), to within half of it
    mid, ends = R[4:-4], np.r_[R[:4], R[-4:]]
    assert np.nanmax(mid[:, 0]) < flags_post.FLOOR[0] / 5 and np.nanmax(mid[:, 1]) < flags_post.FLOOR[1] / 5
    assert np.nanmax(ends[:, 0]) < flags_post.FLOOR[0] / 2 and np.nanmax(ends[:, 1]) < flags_post.FLOOR[1] / 2
    assert trajectory_flags(np.arange(len(P)), P, C) == {}  # below the floor
    short = _track(n=flags_post.MIN_FRAMES - 1, off=(3, 0.0, 2.0))
    assert trajectory_flags(np.arange(len(short)), short, C) == {}


def test_apply_flags_good_frames_only_keeps_converged_and_is_idempotent():
    P = _track(off=(17, 0.0, 0.5))
    P2 = P.copy()
    P2[25] = np.nan  # a frame without a pose: left out of the fits
    res = _result(P2, flags={9: ("score drop (0.5 < 0.85 x recent median 0.8)",)})
    out, changed = apply_trajectory_flags(res, {"tibia": C})
    assert [fr.frame for fr in changed] == [17]
    fr = out.results[("tibia", 17)]
    assert fr.flags[-1].startswith(FLAG) and fr.converged  # the registration's outcome stays
    assert out.results[("tibia", 9)].flags == res.results[("tibia", 9)].flags  # judged by its own check
    assert [r.frame for r in out.flagged] == [9, 17]
    again, changed2 = apply_trajectory_flags(out, {"tibia": C})
    assert changed2 == [] and again.results[("tibia", 17)].flags == fr.flags
    # a stricter limit afterwards takes the earlier post-pass flag off
    none, changed3 = apply_trajectory_flags(out, {"tibia": C}, limit=100.0)
    assert [r.frame for r in changed3] == [17] and not none.results[("tibia", 17)].flags


def test_track_flags_after_the_run_and_journals_the_frame_again(monkeypatch):
    from core.tracking import trial
    from core.tracking.options import TrackingOptions

    P = _track(n=20, off=(11, 0.0, 0.5))

    class _Bone:
        name, centroid = "tibia", C

    class _Renderer:
        volumes = (None,)

    def frame(run, f, imgs, frame_, todo, state, skip):
        return {0: FrameResult("tibia", f, P[f], 0.8, 10, 0.0, True)}

    monkeypatch.setattr(trial, "track_frame", frame)
    seen = []
    res = trial.track(_Renderer(), [_Bone()], lambda f: [np.zeros((4, 4))], range(20),
                      keyframes={"tibia": {0: P[0]}}, record_result=seen.append)
    assert [(r.frame, bool(r.flags)) for r in seen[20:]] == [(11, True)]
    assert [r.frame for r in res.flagged] == [11] and res.results[("tibia", 11)].flags[0].startswith(FLAG)
    seen.clear()
    off = trial.track(_Renderer(), [_Bone()], lambda f: [np.zeros((4, 4))], range(20),
                      keyframes={"tibia": {0: P[0]}}, record_result=seen.append,
                      options=TrackingOptions(trajectory_limit=None))
    assert not off.flagged and len(seen) == 20
    with pytest.raises(ValueError, match="trajectory_limit"):
        TrackingOptions(trajectory_limit=0.5)


@pytest.mark.parametrize("k", [2, 3, 5])
def test_every_kth_frame_tracked_is_judged_alike(k):
    """Tracking every k-th frame: the window counts tracked frames, so the check still judges them."""
    bad = _track(n=40 * k, off=(17 * k, 0.0, 0.5))
    sel = np.arange(0, len(bad), k)
    R = trajectory_residuals(sel, bad[sel], C)
    assert np.isfinite(R).all(axis=1).sum() >= len(sel) - 2
    assert list(trajectory_flags(sel, bad[sel], C, near=None)) == [17 * k]
    got = trajectory_flags(sel, bad[sel], C)  # frames next to it that stand off too (k = 2: three)
    assert next(iter(got)) == 17 * k and "next to" not in got[17 * k]
    assert all("next to flagged frames" in m and abs(f - 17 * k) <= 4 * k for f, m in list(got.items())[1:])


def _rotated(P, f, deg):
    """``P`` with frame ``f`` turned by ``deg`` more about z (through C)."""
    from core.geometry.transforms import params_from_pose

    Q = P.copy()
    p = params_from_pose(P[f], center=C, base=np.eye(4))
    p[5] += np.radians(deg)
    Q[f] = pose_from_params(p, center=C, base=np.eye(4))
    return Q


@pytest.mark.parametrize("seed", [1, 2])
def test_a_frame_off_beside_a_flagged_one_is_flagged_with_near(seed):
    """A frame 0.15 deg off (3x the noise) two frames from one 0.5 deg off the other way: within the
    limit once the far one leaves its fit, over it with the far one in; flagged as next to flagged
    frames (the acceptance trial's tibia frame 81 beside frame 79), not without ``near``; the far one
    alone flags only itself."""
    P = _track(seed=seed)
    fr = np.arange(len(P))
    spike = _rotated(P, 20, 0.5)
    assert list(trajectory_flags(fr, spike, C)) == [20]
    pair = _rotated(spike, 22, -0.15)
    got = trajectory_flags(fr, pair, C)
    assert list(got) == [20, 22] and got[22].startswith(f"{FLAG} next to flagged frames")
    assert list(trajectory_flags(fr, pair, C, near=None)) == [20]
    assert list(trajectory_flags(fr, pair, C, near=2.0)) == [20]  # without them it is within 2x the limit


def test_a_restored_frame_flagged_only_off_the_trajectory_feeds_as_a_good_one():
    """Resumed runs: the post-pass's flag came after the run that made the frame, so the restored
    frame feeds the σ history as it did in that run (an "uncertain" one does not)."""
    from core.tracking.frame_state import _BoneState

    P = _track(n=3)
    conf = {"translation_mm": 0.01, "rotation_deg": 0.05}
    states = {}
    cases = (("good", ()), ("trajectory", (f"{FLAG} (test)",)), ("uncertain", ("uncertain (test)",)))
    for label, flag in cases:
        st = _BoneState()
        for k in range(3):
            fl = flag if k == 1 else ()
            st.add(k, FrameResult("tibia", k, P[k], 0.8, 10, 0.0, True, fl, confidence=conf))
        states[label] = st
    assert len(states["good"].sigmas) == len(states["trajectory"].sigmas) == 3
    assert len(states["uncertain"].sigmas) == 2
    assert len(states["trajectory"].history) == 3
