"""The trajectory check's frames whose neighbours are all flagged (core.tracking.flags_post, ``reach``):
judged from the nearest frames judged good further away on both sides — a bad one flagged, a good one
not — and a frame it cannot judge so noted as unchecked, not flagged, but for one whose frames judged good
lie on one side only (a trial's end): flagged for review by default (``one_sided``, flags_gaps.ONE_SIDED),
noted with ``one_sided=False``."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from core.tracking import flags_post
from core.tracking.flags_gaps import ONE_SIDED_FLAG
from core.tracking.flags_post import (
    FLAG,
    UNCHECKED,
    apply_trajectory_flags,
    trajectory_flags,
    trajectory_review,
)
from core.tracking.results import FrameResult, TrackingResult
from tests.core.tracking.track_helpers import C, walking_track

#: Frames off by ±0.6 degrees about z in turn (12x the noise): each flagged by its own fit, and a frame
#: among them (20; 0 beside the trial's first four) left without a fit through good neighbours.
INSIDE = {16: 0.6, 17: -0.6, 18: 0.6, 19: -0.6, 21: 0.6, 22: -0.6, 23: 0.6, 24: -0.6}
START = {1: 0.6, 2: -0.6, 3: 0.6, 4: -0.6}


def _spiked(spikes, off=None, n=60, seed=6):
    """The tests' walking track with ``spikes`` (frame: degrees about z) and ``off`` (frame, degrees)."""
    def shift(k, p):
        p[5] += np.radians(spikes.get(k, 0.0) + (off[1] if off is not None and k == off[0] else 0.0))

    return walking_track(n, (0.01, 0.05), seed, shift)


def test_a_frame_among_flagged_neighbours_is_judged_from_frames_further_away():
    fr = np.arange(60)
    good = _spiked(INSIDE)
    got = trajectory_flags(fr, good, C)
    assert sorted(got) == sorted(INSIDE)  # frame 20 judged, not flagged
    # spike 19 too was left without a fit once 16-18 and 21-24 were flagged: the check before missed it
    assert "line through its nearest frames judged good 14, 15, 25, 26" in got[19]
    assert sorted(trajectory_flags(fr, good, C, reach=None)) == [16, 17, 18, 21, 22, 23, 24]
    _, unjudged = trajectory_review(fr, good, C, reach=0)  # no frame within reach: both noted
    assert sorted(unjudged) == [19, 20] and all(m.startswith(UNCHECKED) for m in unjudged.values())
    assert "fewer than 2 frames judged good on a side within 0 tracked frames" in unjudged[20]
    bad = _spiked(INSIDE, off=(20, 0.5))  # 10x the noise, its neighbours all flagged
    got = trajectory_flags(fr, bad, C)
    assert sorted(got) == sorted([*INSIDE, 20])
    assert got[20].startswith(FLAG) and got[21].startswith(FLAG)
    assert "line through its nearest frames judged good 14, 15, 25, 26" in got[20]
    assert 20 not in trajectory_flags(fr, bad, C, reach=None)  # the check before: no fit, never judged
    assert trajectory_review(fr, bad, C)[1] == {}  # judged frames carry no note


@pytest.mark.parametrize("off", [0.0, 1.0])
def test_a_frame_at_the_trials_end_among_flagged_ones_is_noted_unchecked(off):
    """The trial's ends fitted through the window cut at them (``ends=False``, the check before
    flags_ends): frames 0 and 2 left without a fit once 1, 3 and 4 are flagged (2 is a spike the check
    before missed): the frames judged good are all after them, so they are noted, not judged (a line
    extrapolated from 5-8 follows the motion's acceleration; on the acceptance trial's first frames
    more than the error: module docs) — whatever frame 0's error."""
    fr = np.arange(60)
    P = _spiked(START, off=(0, off), seed=2)
    assert sorted(trajectory_flags(fr, P, C, reach=None, ends=False)) == [1, 3, 4]
    got, unchecked = trajectory_review(fr, P, C, one_sided=False, ends=False)
    assert sorted(got) == [1, 3, 4] and sorted(unchecked) == [0, 2]
    assert all("5, 6, 7, 8, on one side only" in m for m in unchecked.values())
    # by default (flags_gaps.ONE_SIDED) they are flagged for review instead, with the same reason
    got, unchecked = trajectory_review(fr, P, C, ends=False)
    assert sorted(got) == [0, 1, 2, 3, 4] and unchecked == {}
    assert all(got[f].startswith(f"{ONE_SIDED_FLAG} ({UNCHECKED}: its neighbours flagged; the nearest frames "
                                 "judged good, 5, 6, 7, 8, on one side only") for f in (0, 2))
    # with the trial's ends fitted through the window shifted inside it (the default, flags_ends) frames 0
    # and 2 have fits: every frame 0-4 is flagged, by its fit or, beside three flagged frames or more, for
    # review (flags_ends.CROWD; without it, frames 0 and 1 are silent when frame 0 is 1 deg off)
    got, unchecked = trajectory_review(fr, P, C)
    assert sorted(got) == [0, 1, 2, 3, 4] and unchecked == {}
    assert any("near it flagged at the trial's end" in m for m in got.values())
    if off:
        assert sorted(trajectory_review(fr, P, C, crowd=None)[0]) == [2, 3, 4]


def test_a_frame_it_cannot_judge_is_noted_unchecked_not_flagged():
    P = walking_track(60, (0.01, 0.05), 3)
    lost = {f: ("lost (test)",) for f in [*range(8, 20), *range(21, 33)]}  # per-frame flags: no neighbours
    res = {("tibia", k): FrameResult("tibia", k, P[k], 0.8, 10, 0.0, True, lost.get(k, ()))
           for k in range(len(P))}
    out, changed = apply_trajectory_flags(TrackingResult(("tibia",), tuple(range(60)), res, "complete", 1.0),
                                          {"tibia": C})
    fr20 = out.results[("tibia", 20)]
    assert [r.frame for r in changed] == [20] and not fr20.flags
    assert len(fr20.notes) == 1 and fr20.notes[0].startswith(UNCHECKED)
    assert f"fewer than 2 frames judged good on a side within {flags_post.REACH} tracked" in fr20.notes[0]
    again, changed2 = apply_trajectory_flags(out, {"tibia": C})  # idempotent: the note not doubled
    assert changed2 == [] and again.results[("tibia", 20)].notes == fr20.notes
    off, changed3 = apply_trajectory_flags(out, {"tibia": C}, reach=None)  # the check as before: note off
    assert [r.frame for r in changed3] == [20] and off.results[("tibia", 20)].notes == ()
    # a note added after it (another step's) keeps its place: run again, nothing changes
    later = dict(out.results)
    later[("tibia", 20)] = replace(fr20, notes=(*fr20.notes, "a later note"))
    out2 = TrackingResult(out.bones, out.frames, later, "complete", 1.0)
    again2, changed4 = apply_trajectory_flags(out2, {"tibia": C})
    assert changed4 == [] and again2.results[("tibia", 20)].notes == (*fr20.notes, "a later note")


@pytest.mark.parametrize("seed", range(8))
def test_a_note_never_changes_a_flag(seed):
    """Spikes as :data:`START` at the trial's start and as :data:`INSIDE` about a random frame, which
    is good or 0.5 deg off (frames at the start noted in every draw; the frame among the spikes
    judged, flagged in some): the frames noted are never flagged, every flag of the check without
    the rule (reach=None) stays, and the rule adds flags only to frames it judged (left without a
    fit, not noted). The trial's ends fitted through the window cut at them (``ends=False``: with the
    shifted window the frames at the start have fits, flags_ends)."""
    g = np.random.default_rng(seed)
    c, s0 = int(g.integers(14, 46)), int(g.integers(0, 3))
    spikes = {**{c + d: 0.6 * (-1) ** d for d in (-4, -3, -2, -1, 1, 2, 3, 4)},
              **{s0 + 1 + k: 0.6 * (-1) ** k for k in range(4)}}
    fr = np.arange(60)
    P = _spiked(spikes, off=(c, float(g.choice([0.0, 0.5]))), seed=seed)
    before = trajectory_flags(fr, P, C, reach=None, ends=False)
    unfitted = trajectory_review(fr, P, C, reach=0, ends=False)[1]
    got, notes = trajectory_review(fr, P, C, one_sided=False, ends=False)
    assert not set(notes) & set(got)
    assert set(before) <= set(got) and set(got) - set(before) <= set(unfitted) - set(notes)
    assert notes and all(m.startswith(UNCHECKED) for m in notes.values())
    # by default the frames noted from one side only are flagged instead; the others as they were
    got1, notes1 = trajectory_review(fr, P, C, ends=False)
    one = {f for f, m in notes.items() if "on one side only" in m}
    assert one and set(got1) == set(got) | one and set(notes1) == set(notes) - one
    assert all(got1[f].startswith(ONE_SIDED_FLAG) for f in one) and all(got1[f] == got[f] for f in got)


def test_too_few_frames_fitted_alike_leave_it_unchecked():
    """A line through frames 1, 2, 3, 5 to frame 0 of a 12-frame track: fewer than GAP_SCALE frames
    have good frames at those offsets to scale it by."""
    P = _spiked({1: 0.0}, n=12)
    ok = np.ones(12, dtype=bool)
    from core.tracking.flags_gaps import _gap_residuals, _Table

    t = _Table(np.arange(12), P, ok, C, flags_post.HALF_WINDOW, flags_post.DEGREE)
    own, S = _gap_residuals(t, P, C, ok, 0, np.array([1, 2, 3, 5]))
    assert own.shape == (2,) and 0 < len(S) < flags_post.GAP_SCALE


def test_the_batch_pass_names_an_unchecked_frame_by_its_note():
    from core.tracking.batch_pass import pass_messages

    note = f"{UNCHECKED} (its neighbours flagged; test)"
    entry = {"key": "k", "ranges": ["a", "b"], "judged": 10, "flagged": 1, "review_flagged": {"tibia": 1},
             "changes": [{"bone": "tibia", "frame": 0, "flags": [], "notes": [note]},
                         {"bone": "tibia", "frame": 3, "flags": [], "notes": []},
                         {"bone": "tibia", "frame": 99, "flags": [], "notes": [note], "was_flagged": True}]}
    lines = pass_messages(entry)
    assert lines[1] == f"k: tibia frame 0: not flagged, {note}"
    assert lines[2] == "k: tibia frame 3: no longer flagged"
    # flagged by its range's own check, noted now: the flag came off (an entry without was_flagged,
    # written before it, reads as not flagged before)
    assert lines[3] == f"k: tibia frame 99: no longer flagged, {note}"


def test_a_trials_end_flagged_for_review_is_judged_afresh_when_run_again():
    """apply_trajectory_flags: frames 0 and 2 (START's spikes 1, 3, 4 flagged) get the one-sided flag
    in their flags, not a note; run again nothing changes; with ``one_sided=False`` the flag gives way to
    the note (the trial's ends fitted through the window cut at them, ``ends=False``, as before
    flags_ends)."""
    P = _spiked(START, off=(0, 0.0), seed=2)
    res = {("tibia", k): FrameResult("tibia", k, P[k], 0.8, 10, 0.0, True) for k in range(len(P))}
    out, changed = apply_trajectory_flags(TrackingResult(("tibia",), tuple(range(60)), res, "complete", 1.0),
                                          {"tibia": C}, ends=False)
    assert sorted(r.frame for r in changed) == [0, 1, 2, 3, 4]
    for f in (0, 2):
        fr = out.results[("tibia", f)]
        assert len(fr.flags) == 1 and fr.flags[0].startswith(ONE_SIDED_FLAG) and fr.notes == ()
    again, changed2 = apply_trajectory_flags(out, {"tibia": C}, ends=False)
    assert changed2 == [] and all(again.results[k].flags == out.results[k].flags for k in out.results)
    noted, changed3 = apply_trajectory_flags(out, {"tibia": C}, one_sided=False, ends=False)
    assert sorted(r.frame for r in changed3) == [0, 2]
    for f in (0, 2):
        fr = noted.results[("tibia", f)]
        assert fr.flags == () and fr.notes[0].startswith(UNCHECKED)
