"""Where the window's error messages go: a modal box for the user, or a hook (the GUI tests).

The window shows a failure of what the user asked for (a menu action, opening a study, a dialog
whose values are refused) in a modal message box (:meth:`app.main_window.MainWindow.show_error`,
the Tracking options' refusal). A modal box runs its own event loop until someone closes it, so
a GUI test in which an action fails unexpectedly would wait there for ever instead of failing.
Where :data:`HOOK` is set — ``tests/app/conftest.py`` sets it for every test that uses pytest-qt
— the message goes to the hook instead and no box opens; users (the hook unset) see the box as
before.
"""

from __future__ import annotations

from collections.abc import Callable

__all__ = ["HOOK", "report_elsewhere"]

#: Called as ``HOOK(title, text)`` instead of opening a modal error box; None (the default): the box.
HOOK: Callable[[str, str], None] | None = None


def report_elsewhere(title: str, text: str) -> bool:
    """Hand an error message to :data:`HOOK` where one is set (True: no box is to be shown)."""
    if HOOK is None:
        return False
    HOOK(title, text)
    return True
