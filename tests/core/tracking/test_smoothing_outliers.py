"""core.tracking.smoothing.smooth_poses with a frame far off its neighbours. A frame off by 0.5 mm
(10 sigma) is pulled in. A frame the tracker flagged 1-5 mm off was followed with the defaults before the
outlier search (0.96-1.01 / 1.97-2.02 / 4.92-4.99 mm off, its weight 1, on this trajectory: the bursts took
the spike, out and back, for a transient, and beyond ~2 mm no process noise kept the scale k within
max_scale); now the search takes it for an outlier (one frame's variance multiplied explains the spike
better than two bursts) and the scale's bound judges k by the median innovation, so it is pulled in, as
with flagged_weight=0. So are such frames at a trial's ends (the first frames judged on the frames
reversed in time) and three consecutive frames inside it. A run of flagged frames off alike at a trial's
end agrees with itself (a step there) and was followed (frames 0-2 flagged 2 mm off: frame 1 3.49 mm off);
it is now tried as one outlier and pulled in; a run of good flagged frames there, and an unflagged step,
are left as they were."""

from __future__ import annotations

import numpy as np

from tests.core.tracking.test_smoothing import CENTER, _errors, _noisy, _truth


def _track(mm: float, seed: int = 3, frames=(40,)):
    T = _truth(80)
    sigma = np.tile([0.05, 0.05, 0.05, 0.2, 0.2, 0.2], (len(T), 1))
    P, _ = _noisy(T, sigma, 1.0, seed=seed)
    off = np.eye(4)
    off[0, 3] = mm
    for f in frames:
        P[f] = off @ P[f]
    return T, P, sigma, np.isin(np.arange(len(T)), frames)


def test_a_frame_half_a_millimetre_off_is_pulled_in():
    from core.tracking.smoothing import smooth_poses

    T, P, sigma, _ = _track(0.5)
    s = smooth_poses(P, sigma, center=CENTER)
    assert np.linalg.norm(_errors(s.poses, T)[40, :3]) < 0.05 and s.weights[40] < 0.5


def test_a_flagged_frame_skipped_is_pulled_in():
    from core.tracking.smoothing import smooth_poses

    for mm in (1.0, 2.0, 5.0):
        T, P, sigma, fl = _track(mm)
        s = smooth_poses(P, sigma, center=CENTER, flagged=fl, flagged_weight=0.0)
        assert np.linalg.norm(_errors(s.poses, T)[40, :3]) < 0.05


def test_a_flagged_frame_far_off_is_pulled_in_with_the_defaults():
    from core.tracking.smoothing import smooth_poses

    for seed in (3, 4):
        for mm in (1.0, 2.0, 5.0):
            T, P, sigma, fl = _track(mm, seed)
            s = smooth_poses(P, sigma, center=CENTER, flagged=fl)
            assert np.linalg.norm(_errors(s.poses, T)[40, :3]) < 0.05, (seed, mm)
            assert s.outliers == [40] and s.weights[40] < 1e-3 and s.bursts == []


def test_far_off_frames_at_the_ends_and_in_a_row_are_pulled_in():
    from core.tracking.smoothing import smooth_poses

    for frames in ((0,), (79,), (40, 41, 42)):
        for mm in (1.0, 5.0):
            T, P, sigma, fl = _track(mm, 3, frames)
            s = smooth_poses(P, sigma, center=CENTER, flagged=fl)
            e = np.linalg.norm(_errors(s.poses, T)[list(frames), :3], axis=1)
            assert e.max() < 0.1, (frames, mm, e)
            assert sorted(s.outliers) == list(frames)


def test_far_off_frames_after_frames_without_a_pose():
    """Frames 0-4 without a pose: a flagged frame far off inside the trial, and the first posed frame flagged
    off, are still pulled in (the filter runs over the posed frames' span; the first measured frames are
    judged reversed in time)."""
    from core.tracking.smoothing import smooth_poses

    for mm in (1.0, 5.0):
        T, P, sigma, fl = _track(mm)
        P[:5] = np.nan
        s = smooth_poses(P, sigma, center=CENTER, flagged=fl)
        assert np.linalg.norm(_errors(s.poses[40:41], T[40:41])[0, :3]) < 0.05 and s.outliers == [40]
        assert np.all(np.isnan(s.poses[:5])) and np.all(s.weights[:5] == 0)
    T, P, sigma, fl = _track(2.0, frames=(5,))
    P[:5] = np.nan
    s = smooth_poses(P, sigma, center=CENTER, flagged=fl)
    assert np.linalg.norm(_errors(s.poses[5:6], T[5:6])[0, :3]) < 0.1 and s.outliers == [5]


def test_runs_of_flagged_frames_at_the_ends_are_pulled_in():
    from core.tracking.smoothing import smooth_poses

    for frames in ((0, 1), (0, 1, 2), (0, 1, 2, 3, 4), (78, 79), (77, 78, 79)):
        for mm in (1.0, 2.0, 5.0):
            T, P, sigma, fl = _track(mm, 3, frames)
            s = smooth_poses(P, sigma, center=CENTER, flagged=fl)
            e = np.linalg.norm(_errors(s.poses, T)[list(frames), :3], axis=1)
            assert e.max() < 0.1, (frames, mm, e)  # before: up to 3.49 mm (0-2), 2.10 mm (77-79) at 2 mm
            assert sorted(s.outliers) == list(frames) and s.bursts == []


def test_good_flagged_runs_and_unflagged_steps_at_the_ends_are_left_alone():
    from core.tracking.smoothing import END_RUN, smooth_poses
    from core.tracking.smoothing_filter import end_runs

    for frames in ((0, 1, 2, 3), (74, 75, 76, 77, 78, 79)):
        for seed in (3, 4):
            T, P, sigma, fl = _track(0.0, seed, frames)
            s = smooth_poses(P, sigma, center=CENTER, flagged=fl)
            plain = smooth_poses(P, sigma, center=CENTER)
            assert s.outliers == [] and np.allclose(s.poses, plain.poses, atol=1e-9, equal_nan=True)
    T, P, sigma, fl = _track(2.0, 3, (77, 78, 79))
    s = smooth_poses(P, sigma, center=CENTER)  # not flagged: a step at the end, followed as before
    assert not {77, 78, 79} & set(s.outliers) and np.linalg.norm(_errors(s.poses, T)[79, :3]) > 1.0
    fl = np.zeros(10, bool)
    fl[[0, 1, 2, 7, 8, 9]] = True
    ok = np.ones(10, bool)
    ok[1] = False  # taken as far as it may be already: the run at the start stops before it
    start, end = end_runs(fl, ok, END_RUN)
    assert start == [] and [g.tolist() for g in end] == [[8, 9], [7, 8, 9]]
    assert len(end_runs(np.ones(20, bool), np.ones(20, bool), 3)[0]) == 2  # at most 3 frames a run
