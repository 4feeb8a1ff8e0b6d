"""A trial moved to a new calibration while its old calibration's camera files are gone: the
lab-frame check must say it could not compare, not crash after the calibration was saved."""

from types import SimpleNamespace

import numpy as np

from core.study.calibrations import lab_frame_note
from core.study.errors import StudyError


class _Study:
    def __init__(self):
        rec = SimpleNamespace(pose=np.eye(4))
        state = SimpleNamespace(records={0: rec}, keyframes={0: rec})
        self._trial = SimpleNamespace(bones=["talus"], results=lambda bone: state)

    def trial(self, name):
        return self._trial

    def rig(self, calibration):
        if calibration == "old":
            raise StudyError("rig/cam01.txt: no such file (a MayaCam camera file expected)")
        return []


def test_unreadable_old_cameras_give_a_note_not_a_crash():
    note = lab_frame_note(_Study(), "walk", "old", "new")
    assert note.startswith("trial 'walk' moved from calibration old to new with 1 recorded poses")
    assert "old's cameras cannot be read" in note and "rig/cam01.txt" in note


def test_nothing_recorded_needs_no_cameras():
    st = _Study()
    st._trial = SimpleNamespace(bones=["talus"], results=lambda b: SimpleNamespace(records={}, keyframes={}))
    assert lab_frame_note(st, "walk", "old", "new") is None
