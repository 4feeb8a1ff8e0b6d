"""Start-up check of an installed Talus: ``talus gui --smoke [--demo DIR]``.

Used by the bundle's smoke test (installer/smoke_bundle.sh). The window opens as usual; once it
has been painted (and, with ``--demo``, once the study is shown) it is closed through its normal
close path (the study's journal and lock are closed), and one JSON line goes to stderr::

    {"smoke": "ok", "window_s": 3.1, "study_s": 9.8}

Times are seconds from ``$TALUS_SMOKE_T0`` (a ``date +%s.%N`` taken by the caller before it
started the process, so the bundle's unpacking and Python's start count) or from this module's
import. A failure to open the study, or no window (or study) after 600 s, exits 1.
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

from PySide6 import QtCore, QtWidgets

__all__ = ["arm"]

_T0 = float(os.environ.get("TALUS_SMOKE_T0") or time.time())


def _report(**fields) -> None:
    print(json.dumps({"smoke": fields.pop("status"), **fields}), file=sys.stderr, flush=True)


def arm(demo: Path | None, *, timeout_s: float = 600.0) -> QtCore.QTimer:
    """Create the application (if none) and a timer that closes the main window when it is up
    (with ``demo``: when the study is shown); the event loop is :func:`app.main_window.run_gui`'s."""
    if sys.platform.startswith("linux") and os.environ.get("DISPLAY"):
        os.environ.setdefault("QT_QPA_PLATFORM", "xcb")
    app = QtWidgets.QApplication.instance() or QtWidgets.QApplication(sys.argv[:1])
    state: dict = {}

    def finish(code: int, **fields) -> None:
        timer.stop()
        _report(**fields)
        for w in app.topLevelWidgets():
            if isinstance(w, QtWidgets.QDialog) and w.isVisible():
                w.reject()
        window = state.get("window")
        if window is not None:
            window.close()
        QtCore.QTimer.singleShot(0, lambda: app.exit(code))

    def poll() -> None:
        from .main_window import MainWindow

        now = time.time() - _T0
        window = state.get("window")
        if window is None:
            window = next((w for w in app.topLevelWidgets() if isinstance(w, MainWindow)), None)
            state["window"] = window
        if window is not None and window._painted and "window_s" not in state:
            state["window_s"] = round(now, 2)
        if window is not None and window.last_error is not None:
            finish(1, status="failed", error=" ".join(window.last_error), **_times(state))
        elif "window_s" in state and (demo is None or window.model is not None):
            if demo is not None:
                state["study_s"] = round(now, 2)
                state["bones"] = [layer.name for layer in window.model.layers]
            finish(0, status="ok", **_times(state))
        elif now > timeout_s:
            finish(1, status="timeout", after_s=round(now, 2), **_times(state))

    timer = QtCore.QTimer(app)
    timer.setInterval(50)
    timer.timeout.connect(poll)
    timer.start()
    return timer


def _times(state: dict) -> dict:
    return {k: state[k] for k in ("window_s", "study_s", "bones") if k in state}
