"""The trajectory check's 'trajectory unchecked' note (core.tracking.flags_post.UNCHECKED) is kept by
the study's journal with the frame (FrameResult.journal_fields), read back as it was written after
the study is closed and opened again, and the check run again on the frames read back changes
nothing."""

import numpy as np
import pytest

from core.study import Study
from core.tracking.flags_post import UNCHECKED, apply_trajectory_flags
from core.tracking.results import FrameResult, TrackingResult
from tests.core.tracking.track_helpers import C, walking_track


@pytest.fixture
def folder(talus_study):
    return talus_study


def test_the_unchecked_note_survives_the_journal(folder):
    P = walking_track(40, (0.01, 0.05), 3)
    lost = {f: ("lost (test)",) for f in [*range(8, 20), *range(21, 33)]}  # frame 20: no neighbours
    res = {("talus", k): FrameResult("talus", k, P[k], 0.8, 10, 0.0, True, lost.get(k, ()))
           for k in range(40)}
    out, changed = apply_trajectory_flags(TrackingResult(("talus",), tuple(range(40)), res, "complete", 1.0),
                                          {"talus": C})
    fr20 = out.results[("talus", 20)]
    assert [r.frame for r in changed] == [20] and fr20.notes[0].startswith(UNCHECKED) and not fr20.flags
    # the trial has 6 frames: the track's frames 18-23 journaled as its frames 0-5
    with Study.open(folder, mode="w") as st:
        tr = st.trial("walk01")
        for k in range(6):
            fr = out.results[("talus", 18 + k)]
            tr.record_pose("talus", k, fr.pose, score=fr.score, tracking=fr.journal_fields())
    with Study.open(folder) as st:
        recs = st.trial("walk01").results("talus").records
        back = {("talus", 18 + k): FrameResult.from_journal("talus", r) for k, r in recs.items()}
    assert sorted(back) == [("talus", f) for f in range(18, 24)]
    assert back[("talus", 20)].notes == fr20.notes and back[("talus", 20)].flags == ()
    for key, fr in back.items():
        assert fr.flags == out.results[key].flags and fr.notes == out.results[key].notes
        np.testing.assert_allclose(fr.pose, out.results[key].pose)
    read = TrackingResult(("talus",), tuple(range(40)), {**out.results, **back}, "complete", 1.0)
    again, changed2 = apply_trajectory_flags(read, {"talus": C})  # the check again: nothing changes
    assert changed2 == [] and again.results[("talus", 20)].notes == fr20.notes
