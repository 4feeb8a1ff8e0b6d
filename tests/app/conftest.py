"""Shared set-up of the GUI tests in tests/app.

* ``demo_study``: one small demo study (3 frames, 96 px, four bones, every bone posed at frame 0)
  written once per test run. Tests that write to a study take a private copy
  (:func:`tests.app._helpers.copy_study`); the folder itself is never written to.
* After every test the Qt objects it left behind are deleted on the GUI thread (see
  :func:`_qt_garbage_on_the_gui_thread`).
* An error the window would show in a modal box (:mod:`app.errors`) fails a pytest-qt test at
  once instead (:func:`_errors_fail_the_test`): the box would wait for a click for ever. A test
  that expects such errors takes ``shown_errors`` (the ``(title, text)`` pairs, nothing raised);
  one that looks at the box itself takes ``modal_errors`` (the box, as users see it).
"""

from __future__ import annotations

import gc

import pytest


class _ErrorState:
    def __init__(self) -> None:
        self.expected: list | None = None  # shown_errors' list: recorded, nothing raised
        self.pending: list[Exception] = []  # ErrorShown reported, not yet raised in the test
        self.raised: list[Exception] = []
        self.loops: list = []  # the event loops of pytest-qt's waits now running, innermost last

    def report(self, title: str, text: str) -> None:
        if self.expected is not None:
            self.expected.append((title, text))
            return
        from tests.app._helpers import ErrorShown

        self.pending.append(ErrorShown(f"the window showed an error: {title} {text}"))
        for loop in self.loops:  # end the test's wait now; it raises the error (_exec)
            loop.quit()

    def raise_pending(self) -> None:
        if self.pending:
            exc = self.pending.pop(0)
            self.raised.append(exc)
            raise exc


@pytest.fixture(scope="session")
def demo_study(tmp_path_factory):
    """The shared demo study folder (read it, or copy it before writing)."""
    from core.synthetic import make_demo_study

    out = tmp_path_factory.mktemp("demo_study") / "study"
    make_demo_study(out, n_frames=3, pixels=96, seed=5, device="cpu", spacing=2.0, tissue_spacing=8.0,
                    calibration_session=False)
    return out


@pytest.fixture(autouse=True)
def _qt_garbage_on_the_gui_thread(request):
    """Delete a test's windows and collect its cyclic garbage on the GUI thread, after pytest-qt
    has closed the test's widgets.

    Without this, a closed window's Python wrappers stay as cyclic garbage until the garbage
    collector happens to run, which may be in a worker thread of a later test: that thread then
    destroys Qt objects (taking Qt's locks) while the GUI thread, holding the interpreter lock,
    deletes others in shiboken's main-thread deletion queue, and both wait for ever (seen as a
    hang in the worker's TIFF reading during File > Import project…).

    What survives the collection is frozen (:func:`gc.freeze`): later collections, here and
    automatic ones, scan only what was made since (a full collection of the ~200 000 objects of
    the imported libraries took 0.4 s on the 2-core machine; after the freeze, 2 ms). The app
    itself collects on the GUI thread while a worker pool lives (:class:`app.workers.
    GuiThreadCollector`); once the test's pools are gone, automatic collection is back for the
    tests that follow."""
    yield
    if "qtbot" not in request.fixturenames:
        return
    from PySide6 import QtCore

    QtCore.QCoreApplication.sendPostedEvents(None, QtCore.QEvent.Type.DeferredDelete)
    gc.collect()
    QtCore.QCoreApplication.sendPostedEvents(None, QtCore.QEvent.Type.DeferredDelete)
    gc.freeze()
    from app.workers import GuiThreadCollector

    GuiThreadCollector.check()


@pytest.fixture(autouse=True)
def _errors_fail_the_test(request, monkeypatch):
    """For a test that uses pytest-qt: :data:`app.errors.HOOK` records the window's error messages
    instead of a modal box, and pytest-qt's waits (``waitUntil``, ``waitSignal``, ``wait``… all run
    an event loop through ``qt_api.exec``) end at once and raise
    :class:`tests.app._helpers.ErrorShown` — one running when the error comes, or the next one —
    so a test whose action failed fails then, not at its wait's timeout; an error no wait saw fails
    the test at its end. ``waitExposed``, ``waitActive`` and ``QTest.qWait`` run Qt's own loops,
    which this does not end: an error during one is raised by the next pytest-qt wait. ``shown_errors``
    and ``modal_errors`` change that (module notes)."""
    if "qtbot" not in request.fixturenames or "modal_errors" in request.fixturenames:
        yield
        return
    from pytestqt.qt_compat import qt_api

    import app.errors

    state = _ErrorState()
    exec_ = qt_api.exec

    def _exec(obj, *args, **kwargs):
        __tracebackhide__ = True
        state.raise_pending()
        state.loops.append(obj)
        try:
            result = exec_(obj, *args, **kwargs)
        finally:
            state.loops.remove(obj)
        state.raise_pending()
        return result

    monkeypatch.setattr(app.errors, "HOOK", state.report)
    monkeypatch.setattr(qt_api, "exec", _exec)
    request.node.talus_errors = state
    yield
    if state.pending:
        pytest.fail(f"{state.pending[0]} (not seen by any wait of the test)", pytrace=False)


@pytest.fixture
def shown_errors(request, qtbot, _errors_fail_the_test) -> list[tuple[str, str]]:
    """The ``(title, text)`` of each error the window reported in this test (expected ones:
    nothing is raised)."""
    state = request.node.talus_errors
    state.expected = []
    return state.expected


@pytest.fixture
def modal_errors(monkeypatch):
    """The window's error messages in their modal box, as users see them (the test closes it)."""
    import app.errors

    monkeypatch.setattr(app.errors, "HOOK", None)
