"""The review state shows a frame the trajectory check could not judge (its ``trajectory unchecked``
note, core.tracking.flags_post.UNCHECKED) as tracked with that reason; a flag's reason comes first."""

from __future__ import annotations

import numpy as np

from app.review import FLAGGED, TRACKED, ReviewData
from core.tracking.flags_post import UNCHECKED


def test_an_unchecked_frame_is_tracked_with_the_note_as_its_reason():
    d = ReviewData(["tibia"], 4)
    note = f"{UNCHECKED} (its neighbours flagged; test)"
    base = {"bone": "tibia", "score": 0.8, "confidence": None}
    d.apply_result({**base, "frame": 0, "flags": [], "notes": ["contact: resolved", note]}, pose=np.eye(4))
    d.apply_result({**base, "frame": 1, "flags": [], "notes": ["contact: resolved"]}, pose=np.eye(4))
    flag = "off the trajectory (test)"
    d.apply_result({**base, "frame": 2, "flags": [flag], "notes": [note]}, pose=np.eye(4))
    assert d.status[0, 0] == TRACKED and d.reasons[(0, 0)] == note and "unchecked" in d.frame_reason(0)
    assert (0, 1) not in d.reasons  # other notes are not reasons
    assert d.status[0, 2] == FLAGGED and d.reasons[(0, 2)] == flag
    assert d.flagged() == [(0, 2)]


def test_the_note_read_from_the_journal_is_the_reason():
    """As the window reads a trial's journals (ReviewData.load_journal): the note journaled with the
    frame (FrameResult.journal_fields) is its reason, the frame tracked, not flagged."""
    from core.study.results import PoseRecord
    from core.tracking.results import FrameResult

    note = f"{UNCHECKED} (its neighbours flagged; test)"
    frames = [FrameResult("tibia", 0, np.eye(4), 0.8, 10, 0.0, True, notes=(note,)),
              FrameResult("tibia", 1, np.eye(4), 0.8, 10, 0.0, True)]
    records = {fr.frame: PoseRecord(fr.frame, fr.pose, fr.score, tracking=fr.journal_fields())
               for fr in frames}

    class _State:  # a journal's state (core.study.results): its records, what is done
        done = records

    _State.records = records

    class _Trial:
        def results(self, bone):
            return _State()
    d = ReviewData(["tibia"], 2)
    d.load_journal(_Trial())
    assert d.status[0, 0] == TRACKED and d.reasons[(0, 0)] == note and d.flagged() == []
    assert (0, 1) not in d.reasons
