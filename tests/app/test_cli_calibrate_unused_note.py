"""'talus calibrate --trials none' asks that no trial use the new calibration: no hint that none does."""

from pathlib import Path
from types import SimpleNamespace

from app.commands.calibrate import unused_note


def test_trials_none_gets_no_unused_hint():
    saved = SimpleNamespace(name="session.v1", trials=())
    assert unused_note(saved, {"walk": "rig"}, Path("study"), trials="none") is None
    note = unused_note(saved, {"walk": "rig"}, Path("study"), trials="series")
    assert note.startswith("no trial uses session.v1 yet (walk uses rig)")
