"""Tracking > Tracking options…: the first frame's backward check (``talus track --backward-limit K|off``,
``TrackingOptions.backward_limit``) in *Advanced checks*, set and turned off with real keys as the
trajectory check is. ``TALUS_SCREENSHOTS=DIR`` keeps ``tracking_options_backward_check.png``."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

pytest.importorskip("PySide6", reason="the GUI extra (PySide6) is not installed")

from PySide6 import QtCore

from app.commands.track import check_choices
from app.tracking_options import OFF_FIELDS, choices_of, options_from_choices
from tests.app._helpers import main_window
from tests.app.test_app_tracking_options import HUNG_MS, _accept, _click, _type


@pytest.fixture
def window(qtbot):
    """The window without its 3-D scene (the dialog is what is tested)."""
    with main_window(qtbot) as win:
        yield win


def _last(window) -> str:
    return window.messages.item(window.messages.count() - 1).text()


def test_the_backward_check_is_set_or_turned_off_in_advanced_checks(qtbot, window, shown_errors):
    assert "backward_limit" in OFF_FIELDS
    dialog = window.tracking.edit_options()
    qtbot.waitUntil(dialog.isVisible, timeout=HUNG_MS)
    box = dialog.backward_limit
    assert box.value() == check_choices(None)["backward_limit"] == 1.25 and box.isEnabled()
    tip = box.toolTip()
    assert "--backward-limit" in tip and "first frame off its backward registration" in tip
    form = dialog.checks_group.layout()
    assert form.labelForField(box).text() == "Back&ward limit:"
    assert form.getWidgetPosition(box)[0] == form.getWidgetPosition(dialog.trajectory_limit)[0] + 1
    dialog.activateWindow()
    qtbot.waitUntil(dialog.isActiveWindow, timeout=HUNG_MS)
    qtbot.keyClick(dialog.search, QtCore.Qt.Key.Key_W, QtCore.Qt.KeyboardModifier.AltModifier)
    assert box.hasFocus()  # its mnemonic
    folder = os.environ.get("TALUS_SCREENSHOTS")
    if folder:  # resources/screenshots/tracking_options_backward_check.png
        assert dialog.grab().save(str(Path(folder) / "tracking_options_backward_check.png"))
    _type(qtbot, box, "2")
    _accept(qtbot, dialog)
    opts = window.tracking.options
    assert opts.backward_limit == 2.0 and opts.trajectory_limit == 2.5
    assert options_from_choices(**choices_of(opts)) == opts
    assert "backward check 2x" in _last(window) and "trajectory check" not in _last(window)

    # a limit under 1 is refused on OK, as the trajectory limit's, naming the option and its range
    dialog = window.tracking.edit_options()
    qtbot.waitUntil(dialog.isVisible, timeout=HUNG_MS)
    box = dialog.backward_limit
    assert box.minimum() == 0.75 and box.specialValueText() == "Off"
    _type(qtbot, box, "0.9")  # between Off and 1: refused, not Off
    _click(qtbot, dialog, "Ok")
    assert dialog.isVisible() and dialog.result() == 0  # not accepted
    assert shown_errors[-1][1].startswith("backward_limit: expected a factor >= 1"), shown_errors
    assert window.tracking.options.backward_limit == 2.0  # unchanged

    # its lowest step is "Off": the tracker's None, the trajectory check untouched
    _type(qtbot, box, "1")
    box.setFocus()
    qtbot.keyClick(box, QtCore.Qt.Key.Key_Down)
    assert box.text() == "Off"
    _accept(qtbot, dialog)
    opts = window.tracking.options
    assert opts.backward_limit is None and opts.trajectory_limit == 2.5
    assert options_from_choices(**choices_of(opts)) == opts
    assert "backward check off" in _last(window)

    # re-opened it shows "Off"; Restore defaults brings back the tracker's limit
    dialog = window.tracking.edit_options()
    qtbot.waitUntil(dialog.isVisible, timeout=HUNG_MS)
    assert dialog.backward_limit.text() == "Off" and dialog.choices() == choices_of(opts)
    _click(qtbot, dialog, "RestoreDefaults")
    assert dialog.backward_limit.value() == 1.25 and dialog.choices() == choices_of(None)
    with qtbot.waitSignal(dialog.rejected, timeout=HUNG_MS):
        qtbot.keyClick(dialog, QtCore.Qt.Key.Key_Escape)
