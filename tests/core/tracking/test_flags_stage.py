"""The trajectory check's frames the final stage moved off the trajectory (core.tracking.flags_stage): a
frame whose search's pose lay on its neighbours' path and whose stage's pose stands off it, by less than
the check's limit, is flagged; the same frame without its search's pose (or with the stage's move
rejected: the search's pose is the pose) is not; a journal's frame keeps the flag."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from core.tracking.flags_post import FLAG, STAGE_FLAG, apply_trajectory_flags, trajectory_review
from core.tracking.results import FrameResult, TrackingResult
from tests.core.tracking.track_helpers import C, walking_track

N = 60


def _track(seed, d=0.0, frame=30):
    """The tests' walking track (0.01 mm / 0.05 deg noise per axis), ``frame`` moved ``d`` mm along x."""
    def shift(k, p):
        if k == frame:
            p[0] += d

    return walking_track(N, (0.01, 0.05), seed, shift)


@pytest.mark.parametrize("seed", [0, 2])
def test_a_frame_the_stage_moved_off_its_path_is_flagged(seed):
    """Frame 30 0.045 mm off along x (about 2.2x the track's median residual: under the check's limit
    2.5x), its search's pose on the path: flagged by the rule alone."""
    P, S = _track(seed, 0.045), _track(seed)
    fr = np.arange(N)
    before, _ = trajectory_review(fr, P, C)
    assert 30 not in before
    got, _ = trajectory_review(fr, P, C, searched=S)
    assert got[30].startswith(f"{STAGE_FLAG} (") and set(got) - {30} == set(before)
    assert trajectory_review(fr, P, C, searched=P)[0] == before  # the move rejected: the pose is the search's
    assert trajectory_review(fr, P, C, searched=S, stage=None)[0] == before
    none = np.full_like(P, np.nan)
    assert trajectory_review(fr, P, C, searched=none)[0] == before


def _result(P, S=None):
    res = {("tibia", k): FrameResult("tibia", k, P[k], 0.8, 10, 0.0, True,
                                     search_pose=None if S is None else S[k]) for k in range(len(P))}
    return TrackingResult(("tibia",), tuple(range(len(P))), res, "complete", 1.0)


def test_apply_flags_takes_the_search_pose_and_a_journal_keeps_the_flag():
    P, S = _track(0, 0.045), _track(0)
    out, changed = apply_trajectory_flags(_result(P, S), {"tibia": C})
    flags = out.results[("tibia", 30)].flags
    assert len(flags) == 1 and flags[0].startswith(STAGE_FLAG)
    assert ("tibia", 30) in {(fr.bone, fr.frame) for fr in changed}
    again, changed = apply_trajectory_flags(out, {"tibia": C})  # idempotent
    assert changed == [] and again.results[("tibia", 30)].flags == flags
    # the frames as a journal gives them back: no search's pose; the rule's flag kept, the others judged
    journal = TrackingResult(out.bones, out.frames, {k: replace(fr, search_pose=None) for k, fr in
                                                     out.results.items()}, "complete", 1.0)
    kept, changed = apply_trajectory_flags(journal, {"tibia": C})
    assert changed == [] and kept.results[("tibia", 30)].flags == flags
    assert apply_trajectory_flags(_result(P), {"tibia": C})[0].results[("tibia", 30)].flags == ()


def test_search_noise_alone_flags_few_frames():
    """The search's poses a noise draw of their own about the same path (as large as the tracked poses'):
    the rule adds at most 1 % of the frames' flags over 20 draws (6 of 1200 when written)."""
    added = 0
    for seed in range(20):
        P, S = walking_track(N, (0.01, 0.05), seed), walking_track(N, (0.01, 0.05), seed + 1000)
        a, _ = trajectory_review(np.arange(N), P, C)
        b, _ = trajectory_review(np.arange(N), P, C, searched=S)
        assert set(a) <= set(b) and all(b[f].startswith(STAGE_FLAG) for f in set(b) - set(a))
        assert all(v.startswith(FLAG) for v in b.values())
        added += len(set(b) - set(a))
    assert added <= 12
