"""An error the window shows in a modal box (app.errors) fails a GUI test at once: a failure while a
dialog opens — here Tracking options…, opened with its shortcut, whose dialog cannot be built —
ends the test's wait with :class:`~tests.app._helpers.ErrorShown` instead of leaving the test in
the box's event loop (it waited there for ever) or at its wait's timeout. A test that expects the
error takes ``shown_errors``; users still get the box (``tests/app/test_app_open_errors.py``
clicks it)."""

from __future__ import annotations

import re
import time

import pytest
from PySide6 import QtCore

from app.tracking_options import TrackingOptionsDialog
from tests.app._helpers import ErrorShown, main_window

pytestmark = pytest.mark.gui

HUNG_MS = 120_000  # the ceiling of a wait that nothing ends; these end at once ...
AT_ONCE_S = 30.0  # ... well within this, however loaded the machine
WHY = "the dialog cannot be built (a test's stand-in fault)"


class _Never(QtCore.QObject):
    never = QtCore.Signal()


@pytest.fixture
def broken_dialog(monkeypatch):
    def fail(self, *a, **k):
        raise RuntimeError(WHY)

    monkeypatch.setattr(TrackingOptionsDialog, "__init__", fail)


def _press_options_shortcut(qtbot, win) -> None:
    with qtbot.waitActive(win):
        win.activateWindow()
    qtbot.keyClick(win, QtCore.Qt.Key.Key_T,
                   QtCore.Qt.KeyboardModifier.ControlModifier | QtCore.Qt.KeyboardModifier.AltModifier)


def test_an_error_while_a_dialog_opens_ends_the_next_wait(qtbot, broken_dialog):
    with main_window(qtbot) as win:
        _press_options_shortcut(qtbot, win)
        with pytest.raises(ErrorShown, match=re.escape(f"This did not work: {WHY}")):
            qtbot.waitUntil(lambda: win.findChild(TrackingOptionsDialog) is not None, timeout=HUNG_MS)
        assert win.last_error == ("This did not work:", WHY)


def test_an_error_during_a_wait_ends_it(qtbot, broken_dialog):
    """The shortcut pressed while the test waits for a signal that never comes: the wait ends
    with the error at once, not at its ceiling."""
    never = _Never()
    with main_window(qtbot) as win:
        QtCore.QTimer.singleShot(0, win, lambda: _press_options_shortcut(qtbot, win))
        t0 = time.monotonic()
        with pytest.raises(ErrorShown, match=re.escape(WHY)), qtbot.waitSignal(never.never, timeout=HUNG_MS):
            pass
        assert time.monotonic() - t0 < AT_ONCE_S


def test_an_expected_error_is_recorded(qtbot, broken_dialog, shown_errors):
    with main_window(qtbot) as win:
        _press_options_shortcut(qtbot, win)
        qtbot.waitUntil(lambda: bool(shown_errors))
        assert shown_errors == [("This did not work:", WHY)]
        assert win.messages.item(win.messages.count() - 1).text().endswith(WHY)


def test_the_hook_is_unset_outside_gui_tests():
    """Users' runs show the box: app.errors.HOOK is None unless a pytest-qt test set it (for its
    own duration only: this runs after the tests above, in the same process)."""
    import app.errors

    assert app.errors.HOOK is None and not app.errors.report_elsewhere("title", "text")
