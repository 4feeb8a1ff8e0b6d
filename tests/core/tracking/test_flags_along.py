"""The trajectory check's rule for a frame next to a flagged one and off the same way
(core.tracking.flags_along through flags_post.trajectory_review, ``along``): a frame off with its flagged
neighbour, hidden by that neighbour's pull on its fit, is flagged; one off the other way is the ``near``
rule's; the rule only adds flags, never for a neighbour the run does not judge; along=None is the check
before it."""

from __future__ import annotations

import numpy as np

from core.tracking.flags_post import FLAG, trajectory_review
from tests.core.tracking.track_helpers import C, walking_track


def _track(seed: int, turns=None, n: int = 60) -> np.ndarray:
    """The tests' walking track (0.01 mm / 0.05 deg noise per axis), frame ``k`` turned ``turns[k]``
    degrees more about z."""

    def shift(k, p):
        p[5] += np.radians((turns or {}).get(k, 0.0))

    return walking_track(n, (0.01, 0.05), seed, shift)


def _flags(P, **kw):
    """The check's flags, the trial's ends fitted as when the rule was measured (``ends=False``: the
    window cut at them; with flags_ends the bone's median leaves the end frames out and moves these
    counts by a draw or two)."""
    return trajectory_review(np.arange(len(P)), P, C, **{"ends": False, **kw})[0]


def test_a_frame_off_the_same_way_as_its_flagged_neighbour_is_flagged():
    """Frame 31 0.5 deg off (flagged), frame 30 0.2 deg off the same way (4x the noise per axis; seed 4's
    tibia frames 8 and 7 at b797131 in small): over 20 draws the check before the rule flags frame 30 in
    8, with it in 16; every flag of the check before stays, with its message."""
    before = after = 0
    for seed in range(20):
        P = _track(seed, {30: 0.2, 31: 0.5})
        b, a = _flags(P, along=None), _flags(P)
        assert 31 in b and all(a[f] == b[f] for f in b)
        before, after = before + (30 in b), after + (30 in a)
        if 30 in a and 30 not in b:
            assert a[30].startswith(f"{FLAG} next to flagged frame 31, the same way (")
            assert "from the fit through its neighbours without it" in a[30]
            assert "1.75 x the bone's median" in a[30]
    assert (before, after) == (8, 16)


def test_a_frame_off_the_other_way_is_left_to_the_near_rule():
    """Frame 30 0.2 deg off the other way: the flagged frame's pull moves its fit away from it, the
    ``near`` rule's case (16 of 20 flagged either way); the rule adds none of them."""
    n = 0
    for seed in range(20):
        P = _track(seed, {30: -0.2, 31: 0.5})
        b, a = _flags(P, along=None), _flags(P)
        n += 30 in a
        assert not (30 in a and 30 not in b and "the same way" not in a[30])
        assert 30 not in set(a) - set(b)
    assert n == 16


def test_a_single_spikes_good_neighbours_are_rarely_flagged():
    """A single frame 0.5 deg off: its good neighbours flagged by the rule in 2 of 40 (20 draws), and a
    smooth noisy track without spikes gets no flag from it."""
    extra = 0
    for seed in range(20):
        P = _track(seed, {31: 0.5})
        b, a = _flags(P, along=None), _flags(P)
        extra += len({30, 32} & (set(a) - set(b)))
        P = _track(seed)
        assert _flags(P) == _flags(P, along=None)
    assert extra == 2


def test_a_neighbour_the_run_does_not_judge_makes_no_frame_judged():
    """A frame the run does not judge (a neighbour from the journal, a hand fix), off and taken out of
    the fits, is no flagged frame for the rule: frame 30, flagged next to it in 8 of 20 draws when it is
    judged, never is so when it is not."""
    n = 0
    for seed in range(20):
        P = _track(seed, {30: 0.2, 31: 0.5})
        judged = np.ones(len(P), dtype=bool)
        n += "next to flagged frame 31, the same way" in _flags(P).get(30, "")
        judged[31] = False
        got = trajectory_review(np.arange(len(P)), P, C, judged=judged, ends=False)[0]
        assert 31 not in got and all("next to flagged frame 31, the same way" not in m for m in got.values())
    assert n == 8
