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


def test_plots_shade_the_flagged_frames_of_their_own_bones(qtbot, demo_study, tmp_path):
    """The tibia's pose plot was shaded at the talus's flagged frame (every bone's flags shaded
    every plot): the technician looked for a problem the tibia did not have."""
    import numpy as np

    from app.review import FLAGGED

    folder = copy_study(demo_study, tmp_path)
    with main_window(qtbot) as win:
        with qtbot.waitSignal(win.pool.finished, timeout=HUNG_JOB_MS):
            win.open_demo_study(folder)
        rv, trial = win.review, win.session.study.trial("walk")
        pose = trial.poses("talus")[0]
        trial.record_pose("talus", 1, pose, score=0.4, tracking={"flags": ["score drop"], "converged": False})
        rv.data.reload_bone(trial, "talus")
        talus = rv.data.bones.index("talus")
        assert rv.data.status[talus, 1] == FLAGGED
        plots = rv.plots
        plots.show_page("Pose")
        shaded = lambda key: np.flatnonzero(np.isfinite(plots._shading[key].series(0))).tolist()  # noqa: E731
        qtbot.keyClicks(plots.bone_combo, "tibia")  # the user picks the bone
        plots.refresh()
        assert plots.bone_combo.currentText() == "tibia" and shaded("translation") == []
        plots.bone_combo.setCurrentIndex(talus)
        plots.refresh()
        assert shaded("translation") == [1] and shaded("rotation") == [1]
        joints = [k for k in plots._shading if k.startswith("jcs:")]  # ankle, subtalar: both hold the talus
        assert joints and all("talus" in [rv.data.bones[i] for i in plots.shaded_bones(k)] for k in joints)
        plots.show_page("Joint angles")
        plots.refresh()
        assert all(shaded(k) == [1] for k in joints)


def test_a_study_another_program_writes_says_who_when_tracking_is_refused(qtbot, demo_study, tmp_path):
    """With 'talus track' writing the talus, the window opened the study read-only and Track
    selected bone said only 'tracking needs a study open for writing': not why, nor what to do."""
    from core.study import Study

    folder = copy_study(demo_study, tmp_path)
    with Study.open(folder, mode="w") as other, main_window(qtbot) as win:  # another writer of the talus
        other.lock_journal("walk", "talus")
        with qtbot.waitSignal(win.pool.finished, timeout=HUNG_JOB_MS):
            win.open_demo_study(folder)
        assert not win.session.writable
        shown = []
        win.show_error = lambda title, text: shown.append(text)  # the dialog _guard shows
        win.track_action.trigger()  # Tracking → Track selected bone
        win.review.keyframe_action.trigger()  # K
        assert len(shown) == 2, shown
        for text in shown:
            assert "needs the study open for writing, but bone 'talus' of trial 'walk'" in text
            assert "locked for writing by process" in text and "open the study again" in text
        assert "tracking needs" in shown[0] and "setting a keyframe needs" in shown[1]


def test_a_calibration_saved_in_another_lab_frame_warns_in_the_window(qtbot, demo_study, tmp_path):
    """The wizard's save moved the trial to a calibration whose sources lie elsewhere (another lab
    frame): the window said only 'trials using it: walk', and the keyframes were then drawn off."""
    from core.study import Study
    from core.study.calibrations import SavedCalibration, use_calibration

    folder = copy_study(demo_study, tmp_path)
    with main_window(qtbot) as win:
        with qtbot.waitSignal(win.pool.finished, timeout=HUNG_JOB_MS):
            win.open_demo_study(folder)
        win.calibrate_action.trigger()  # File → Calibrate…
        w = _wizard()
        win.session.close()  # what the wizard's save does, done here without a session to solve
        with Study.open(folder, mode="w") as st:
            st.add_calibration("session.v1", [folder / "rig" / "cam02.txt", folder / "rig" / "cam01.txt"])
            use_calibration(st, "walk", "session.v1")
        seen = []
        win.notify = lambda text, error=False: seen.append((text, error))
        w.saved_calibration.emit(SavedCalibration("session.v1", "session", 1, folder / "x", ("walk",)))
        assert seen[0] == (f"Calibration session.v1 saved in {folder / 'x'}; trials using it: walk", False)
        assert seen[1][1] and seen[1][0].startswith("Warning: trial 'walk' moved from calibration rig to "
                                                     "session.v1, whose cameras see its recorded poses")
        w.close()


def test_a_frame_that_cannot_be_read_is_said_in_its_pane_and_the_messages(qtbot, demo_study, tmp_path):
    """Stepping onto a damaged TIFF raised out of the frame signal (a traceback on stderr) and the
    pane went on showing the previous frame as if it were this one."""
    folder = copy_study(demo_study, tmp_path)
    (folder / "frames" / "cam01" / "frame_0001.tif").write_bytes(b"garbage")
    with main_window(qtbot, scene=True) as win:
        with qtbot.waitSignal(win.pool.finished, timeout=HUNG_JOB_MS):
            win.open_demo_study(folder)
        seen = []
        win.notify = lambda text, error=False: seen.append((text, error))
        step = {a.text(): a for m in win.menuBar().actions() if m.menu() for a in m.menu().actions()}
        step["Next frame"].trigger()  # View → Next frame
        assert win.model.current_frame == 1
        left, right = win.panes
        assert left.image is None and left._note.text() == "frame 1 cannot be read"
        assert right.image is not None  # the other view's frame 1
        (text, error), = seen
        assert error and text.startswith("frame 1, view 1: ") and "frame_0001.tif" in text
        step["Previous frame"].trigger()
        assert left.image is not None and left._note.text() == ""


def test_a_lone_pose_is_drawn_in_the_pose_plot(qtbot, demo_study, tmp_path):
    """The demo's bones have one pose (the frame-0 keyframe) and the Pose plot of each was empty:
    a curve was drawn only between two consecutive frames with values. (The series are relative to
    the bone's first pose: zero there.)"""
    import numpy as np
    from PySide6 import QtCore

    folder = copy_study(demo_study, tmp_path)
    with main_window(qtbot, size=(1400, 900)) as win:
        with qtbot.waitSignal(win.pool.finished, timeout=HUNG_JOB_MS):
            win.open_demo_study(folder)
        plots = win.review.plots
        win.review.plots_dock.raise_()
        plots.show_page("Pose")
        plots.refresh()
        values = plots.curve_data("translation", 0)
        assert np.isfinite(values[0]) and not np.isfinite(values[1:]).any()  # the keyframe alone
        canvas = plots.canvas_of("translation")
        vb = plots.plots["translation"].getViewBox()
        at = canvas.mapFromScene(vb.mapViewToScene(QtCore.QPointF(0.0, float(values[0]))))
        img = canvas.grab().toImage()
        drawn = 0  # pixels of a curve's pen (x, y, z: reddish, greenish, bluish; z drawn on top)
        for dx in range(-8, 9):
            for dy in range(-3, 4):
                c = img.pixelColor(at.x() + dx, at.y() + dy)
                drawn += max(c.red(), c.green(), c.blue()) - min(c.red(), c.green(), c.blue()) > 60
        assert drawn >= 4, drawn
