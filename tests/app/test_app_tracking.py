"""Tracking from the window: background job, responsive GUI, progress, results, cancel."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from PySide6 import QtCore

from app.main_window import MainWindow
from core.study import Study
from core.synthetic import make_demo_study
from core.tracking.register import Level, RegistrationOptions
from core.tracking.trial import TrackingOptions
from tests.app._helpers import HUNG_JOB_MS, job_ends

pytestmark = pytest.mark.gui

# The window's plumbing is what is tested here, not the tracker's accuracy: one short CMA-ES level
# and no restarts to verify a result (the default 4 restarts cost most of the tracking time)
FAST = TrackingOptions(registration=RegistrationOptions(
    bounds=(4.0, 4.0), levels=(Level(1.0, "cmaes", (0.7, 0.7), popsize=10, max_generations=40, tol_x=0.02),),
    refine=None), confidence=False, verify_restarts=0)


@pytest.fixture(scope="module")
def demo_folder(tmp_path_factory):
    out = tmp_path_factory.mktemp("trk") / "study"
    make_demo_study(out, n_frames=3, pixels=96, seed=5, device="cpu", spacing=2.0,
                    tissue_spacing=8.0, calibration_session=False)
    return out


@pytest.fixture
def window(qtbot, demo_folder, tmp_path):
    folder = shutil.copytree(demo_folder, tmp_path / "study")
    win = MainWindow(device="cpu", create_scene_on_show=False)
    qtbot.addWidget(win)
    win.show()
    with job_ends(qtbot, win.pool, "overlay"):
        win.open_study(folder)
    win.tracking.options = FAST
    yield win
    win.close()


def test_tracking_runs_in_the_background_and_lands_in_model_journal_and_timeline(window, qtbot):
    m = window.model
    m.select("calcaneus")
    start = m.pose("calcaneus", 2).copy()
    ticks, progress = [], []
    timer = QtCore.QTimer()
    timer.timeout.connect(lambda: ticks.append(1))
    timer.start(20)
    window.pool.progress.connect(lambda key, done, total: progress.append((key, done, total)))
    with job_ends(qtbot, window.pool, "tracking"):
        window.track_action.trigger()
        assert window.tracking.running and m.layers[2].locked
    timer.stop()
    assert len(ticks) > 5  # the event loop ran while the tracker worked
    assert progress and progress[-1][1:] == (3, 3)
    assert not window.tracking.running and not m.layers[2].locked
    tracked = m.pose("calcaneus", 2)
    assert not np.allclose(tracked, start)  # frame 2 was registered, not just copied
    with Study.open(window.session.folder) as st:  # already in the journal
        np.testing.assert_allclose(st.trial("walk").poses("calcaneus")[2], tracked)
    assert set(np.flatnonzero(window.timeline.status >= 2)) == {0, 1, 2}


def test_tracking_can_be_cancelled(window, qtbot):
    window.model.select("tibia")
    seen = []
    window.pool.progress.connect(lambda key, done, total: seen.append(done))
    with job_ends(qtbot, window.pool, "tracking", expect="cancelled") as ends:
        window.tracking.track_all()  # 4 bones x 3 frames
        qtbot.waitUntil(lambda: bool(seen or ends), timeout=HUNG_JOB_MS)  # a first frame done
        window.tracking.cancel()
    assert not window.tracking.running
    assert not any(layer.locked for layer in window.model.layers)
    texts = [window.messages.item(i).text() for i in range(window.messages.count())]
    assert any("cancelled" in t for t in texts)
