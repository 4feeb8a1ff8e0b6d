"""The trajectory check's pair rule (core.tracking.flags_pairs through flags_post.trajectory_review): two
consecutive frames off together, each in the other's fit, are flagged; a single spike flags as before;
a smooth noisy track stays unflagged; pair=None is the check before the rule."""

from __future__ import annotations

import numpy as np

from core.tracking.flags_post import FLAG, trajectory_review
from tests.core.tracking.track_helpers import C, walking_track

N = 60


def _track(seed: int, turns=None) -> np.ndarray:
    """The tests' walking track (0.01 mm / 0.05 deg noise per axis), frame ``k`` turned ``turns[k]``
    degrees more about z."""

    def shift(k, p):
        p[5] += np.radians((turns or {}).get(k, 0.0))

    return walking_track(N, (0.01, 0.05), seed, shift)


def _flags(P, **kw):
    """The check's flags; the rule for frames next to flagged ones off the same way (``along``, judged
    after this one on what it left: tests of its own, test_flags_along) off unless given."""
    return trajectory_review(np.arange(len(P)), P, C, **{"along": None, **kw})[0]


def test_a_pair_off_together_is_flagged_where_the_check_before_missed_it():
    caught = 0
    for seed in range(8):  # 0.25 and 0.275 deg: 5x the noise per axis, each in the other's fit
        P = _track(seed, {30: 0.25, 31: 0.275})
        before, now = _flags(P, pair=None), _flags(P)
        assert set(before) <= set(now)  # the rule only adds flags; theirs as they were
        assert all(now[f] == before[f] for f in before)
        if {30, 31} <= set(now) and not {30, 31} <= set(before):
            caught += 1
            for f, g in ((30, 31), (31, 30)):
                if f not in before:
                    assert now[f].startswith(f"{FLAG} with frame {g} (") and "without both" in now[f]
    assert caught >= 3  # seeds 2 (one of them flagged before), 4 and 6 (neither)
    P = _track(4, {30: 0.25, 31: 0.275})
    assert {30, 31}.isdisjoint(_flags(P, pair=None)) and {30, 31} <= set(_flags(P))


def test_a_single_spike_flags_as_before():
    for seed in range(6):
        P = _track(seed, {30: 0.5})
        before, now = _flags(P, pair=None), _flags(P)
        assert 30 in now
        assert now == before  # its neighbours, pulled by it, are not taken for a pair


def test_a_smooth_noisy_track_is_not_flagged_by_the_rule():
    extra = 0
    for seed in range(20):
        P = _track(seed)
        before, now = _flags(P, pair=None), _flags(P)
        assert set(before) <= set(now)
        extra += len(set(now) - set(before))
    assert extra <= 2  # of 1200 good frames
    P = walking_track(N, (0.0, 0.0), 1)
    assert _flags(P) == {}  # noise-free: below the floor


def test_the_batched_pair_scale_is_the_pairs_one_by_one():
    from core.tracking.flags_fit import _Table
    from core.tracking.flags_pairs import pair_residuals, pair_scale

    P = _track(3, {30: 0.25, 31: 0.275})
    P[[12, 40, 41]] = np.nan  # frames without a pose: windows not full, pairs broken
    fr = np.arange(N) * 2  # every 2nd frame tracked
    ok = np.all(np.isfinite(P.reshape(N, -1)), axis=1)
    t = _Table(fr, P, ok, C, 4, 2)
    for which in (ok, ok & (np.arange(N) % 3 == 0)):
        vals = [x for i in np.flatnonzero(which) if (r := pair_residuals(t, ok, int(i))) is not None
                for x in r if np.all(np.isfinite(x))]
        med, m = pair_scale(t, ok, which)
        assert m == len(vals) > 8
        np.testing.assert_allclose(med, np.median(vals, axis=0), rtol=0, atol=1e-12)
