"""A study that cannot be opened: the window stays as it was and says why in a dialog.

Driven through the events a user makes: Ctrl+O (File → Open study…), the folder chosen in the
file dialog, a click on the dialog's OK button.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest
from PySide6 import QtCore, QtWidgets

from app.main_window import MainWindow

pytestmark = pytest.mark.gui

# Waits end on the event itself; the timeout is only the ceiling for an event that never comes.
HUNG_MS = 30 * 60_000
LONG = "gait_laboratory_2026_subject_07_left_foot_barefoot_walking_trials_session_b"


@pytest.fixture
def demo_folder(demo_study):
    """The shared demo study (tests/app/conftest.py), read only."""
    return demo_study


@pytest.fixture
def damaged_study(demo_folder, tmp_path):
    """A copy of the demo study, deep in long folder names, with its first frame cut short."""
    folder = Path(shutil.copytree(demo_folder, tmp_path / LONG / LONG / "study"))
    frame = folder / "frames" / "cam01" / "frame_0000.tif"
    frame.write_bytes(frame.read_bytes()[:300])
    return folder


@pytest.fixture
def window(qtbot, monkeypatch, modal_errors):  # the error box itself, as users see it
    monkeypatch.setenv("XDG_CONFIG_HOME", os.environ.get("XDG_CACHE_HOME", "/tmp"))
    win = MainWindow(device="cpu", create_scene_on_show=False)
    qtbot.addWidget(win)
    win.resize(1280, 760)
    win.show()
    qtbot.waitExposed(win)
    yield win
    win.close()


def _open_with_ctrl_o(qtbot, window, monkeypatch, folder: Path) -> dict:
    """Press Ctrl+O, choose ``folder``; if an error dialog comes up, record it and click OK."""
    monkeypatch.setattr(QtWidgets.QFileDialog, "getExistingDirectory",
                        staticmethod(lambda *a, **k: str(folder)))
    seen: dict = {}
    polling = [True]

    def handle_dialog():
        if not polling[0]:  # the action has returned: stop looking
            return
        box = QtWidgets.QApplication.activeModalWidget()
        if not isinstance(box, QtWidgets.QMessageBox):
            QtCore.QTimer.singleShot(20, handle_dialog)  # not up yet: look again
            return
        if not box.isVisible():
            QtCore.QTimer.singleShot(20, handle_dialog)
            return
        try:
            record(box)
        finally:
            ok = box.button(QtWidgets.QMessageBox.StandardButton.Ok)
            qtbot.mouseClick(ok, QtCore.Qt.MouseButton.LeftButton)

    def record(box):
        seen["title"], seen["text"] = box.text(), box.informativeText()
        seen["labels"] = [(lb.text(), lb.width(), lb.height(), lb.heightForWidth(lb.width()),
                           lb.minimumSizeHint().width(), lb.isVisible())
                          for lb in box.findChildren(QtWidgets.QLabel) if lb.text()]
        seen["box"] = box.frameGeometry()
        seen["screen"] = box.screen().availableGeometry()
        seen["shot"] = box.grab()

    QtCore.QTimer.singleShot(0, handle_dialog)
    with qtbot.waitActive(window):
        window.activateWindow()
    qtbot.keyClick(window, QtCore.Qt.Key.Key_O, QtCore.Qt.KeyboardModifier.ControlModifier)
    polling[0] = False
    return seen


def _state(window):
    docks = [d.windowTitle() for d in window.findChildren(QtWidgets.QDockWidget)
             if d.isVisible()]
    return {"model": window.model, "session": window.session, "docks": docks,
            "images": [pane.image is None for pane in window.panes],
            "titles": [pane._title.text() for pane in window.panes],
            "timeline": window.timeline, "controller": window.controller}


def _assert_readable(seen):
    assert seen, "no error dialog was shown"
    for text, width, height, needed, minimum, visible in seen["labels"]:
        assert visible and width >= minimum, f"label narrower than its text: {text!r}"
        assert height >= needed, f"label cut off ({height} < {needed} px): {text!r}"
    assert seen["screen"].contains(seen["box"]), (seen["box"], seen["screen"])


def test_a_failed_open_leaves_the_window_as_it_was_and_says_why(
        qtbot, window, monkeypatch, damaged_study, demo_folder, tmp_path):
    before = _state(window)
    seen = _open_with_ctrl_o(qtbot, window, monkeypatch, damaged_study)
    _assert_readable(seen)
    reason = seen["text"].replace("\u200b", "")
    assert "frame_0000.tif" in reason and str(damaged_study) in reason
    after = _state(window)
    after.pop("docks"), before.pop("docks")
    assert after == before  # no bones in Layers, no timeline, panes as they were
    assert not [d for d in window.findChildren(QtWidgets.QDockWidget)
                if d.windowTitle() == "Layers" and d.isVisible()]
    assert "Cannot open" in window.statusBar().currentMessage()
    # the study was closed again: not left locked or marked open
    from core.study import Study

    with Study.open(damaged_study, mode="w"):
        pass
    assert not list((damaged_study / "results").rglob(".session-open"))
    targets = [tmp_path]
    if os.environ.get("TALUS_SCREENSHOT_DIR"):
        targets.append(Path(os.environ["TALUS_SCREENSHOT_DIR"]))
    for folder in targets:
        folder.mkdir(parents=True, exist_ok=True)
        assert seen["shot"].save(str(folder / "open_failed_dialog.png"))
    # and the window still opens a good study afterwards
    good = Path(shutil.copytree(demo_folder, tmp_path / "good"))
    with qtbot.waitSignal(window.pool.finished, timeout=HUNG_MS):
        assert _open_with_ctrl_o(qtbot, window, monkeypatch, good) == {}
    assert [layer.name for layer in window.model.layers] == [
        "tibia", "talus", "calcaneus", "metatarsal2"]
    assert all(pane.image is not None for pane in window.panes)


def test_a_folder_that_is_no_study_is_refused_in_a_dialog(qtbot, window, monkeypatch, tmp_path):
    empty = tmp_path / LONG / "nothing_here"
    empty.mkdir(parents=True)
    before = _state(window)
    seen = _open_with_ctrl_o(qtbot, window, monkeypatch, empty)
    _assert_readable(seen)
    after = _state(window)
    assert after.pop("docks") == ["Messages"] and before.pop("docks") == []  # the reason, logged
    assert "no camera images" in seen["text"] and before == after


def test_a_cancelled_demo_names_the_command_that_rewrites_it(
        qtbot, window, monkeypatch, demo_folder, tmp_path):
    folder = Path(shutil.copytree(demo_folder, tmp_path / "cancelled"))
    (folder / "study.json").unlink()
    seen = _open_with_ctrl_o(qtbot, window, monkeypatch, folder)
    _assert_readable(seen)
    assert "talus demo --out" in seen["text"].replace("\u200b", "") and window.model is None
