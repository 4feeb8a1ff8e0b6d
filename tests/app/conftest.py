"""Shared set-up of the GUI tests in tests/app.

* ``demo_study``: one small demo study (3 frames, 96 px, four bones, every bone posed at frame 0)
  written once per test run. Tests that write to a study take a private copy
  (:func:`tests.app._helpers.copy_study`); the folder itself is never written to.
* After every test the Qt objects it left behind are deleted on the GUI thread (see
  :func:`_qt_garbage_on_the_gui_thread`).
"""

from __future__ import annotations

import gc

import pytest


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
