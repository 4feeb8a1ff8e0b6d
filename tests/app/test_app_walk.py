"""What a lab technician trips over in the window on the day's walk (File → Calibrate… on a study
that holds its session, …), through the user's actions."""

from __future__ import annotations

import json

import pytest
from PySide6 import QtWidgets

from tests.app._helpers import HUNG_JOB_MS, copy_study, main_window

pytestmark = pytest.mark.gui


def _wizard():
    from app.calibration.wizard import CalibrationWizard

    shown = [w for w in QtWidgets.QApplication.topLevelWidgets()
             if isinstance(w, CalibrationWizard) and w.isVisible()]
    assert len(shown) == 1
    return shown[0]


def test_calibrate_starts_on_the_studys_own_session(qtbot, demo_study, tmp_path):
    """File → Calibrate… on the demo study (which holds calibration_session/) opened on an empty
    session field: the technician had to browse for a folder the study already names."""
    folder = copy_study(demo_study, tmp_path)
    (folder / "calibration_session").mkdir()
    (folder / "calibration_session" / "session.json").write_text("{}")
    with main_window(qtbot) as win:
        with qtbot.waitSignal(win.pool.finished, timeout=HUNG_JOB_MS):
            win.open_demo_study(folder)
        win.calibrate_action.trigger()
        w = _wizard()
        assert w.session_edit.text() == str(folder / "calibration_session")
        assert w.study_edit.text() == str(folder)
        w.close()


def test_calibrate_starts_on_the_session_of_the_newest_saved_calibration(demo_study, tmp_path):
    from app.calibration.menu import default_session

    folder = copy_study(demo_study, tmp_path)
    assert default_session(folder) is None and default_session(None) is None
    for name in ("old", "new"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "session.json").write_text("{}")
    doc = json.loads((folder / "study.json").read_text())
    doc["settings"]["calibration_files"] = {
        "session.v1": {"created": "2026-01-01T00:00:00+00:00", "session": str(tmp_path / "old")},
        "session.v2": {"created": "2026-02-01T00:00:00+00:00", "session": str(tmp_path / "new")}}
    (folder / "study.json").write_text(json.dumps(doc))
    assert default_session(folder) == tmp_path / "new"
    (tmp_path / "new" / "session.json").unlink()  # moved away: the study's own, else nothing
    assert default_session(folder) is None
