"""Tracking from the window: background job, responsive GUI, progress, results, cancel."""

from __future__ import annotations

import numpy as np
import pytest
from PySide6 import QtCore

from core.study import Study
from tests.app._helpers import (
    FAST_TRACKING,
    HUNG_JOB_MS,
    copy_study,
    job_ends,
    main_window,
    pause_after_first_frame,
)

pytestmark = pytest.mark.gui


@pytest.fixture
def window(qtbot, demo_study, tmp_path):
    with main_window(qtbot) as win:
        with job_ends(qtbot, win.pool, "overlay"):
            win.open_study(copy_study(demo_study, tmp_path))
        win.tracking.options = FAST_TRACKING
        yield win


def test_tracking_runs_in_the_background_and_lands_in_model_journal_and_timeline(
        window, qtbot, monkeypatch):
    m = window.model
    m.select("calcaneus")
    start = m.pose("calcaneus", 2).copy()
    go_on = pause_after_first_frame(monkeypatch)
    ticks, progress = [], []

    def tick():  # a timer of the GUI thread, firing while the tracker is mid-job
        if progress and window.tracking.running:
            ticks.append(progress[-1][1])
            go_on.set()

    timer = QtCore.QTimer()
    timer.timeout.connect(tick)
    timer.start(20)
    window.pool.progress.connect(lambda key, done, total: progress.append((key, done, total)))
    try:
        with job_ends(qtbot, window.pool, "tracking"):
            window.track_action.trigger()
            assert window.tracking.running and m.layers[2].locked
    finally:
        timer.stop()
        go_on.set()
    assert ticks and ticks[0] == 1  # the event loop ran while the tracker worked (after frame 1 of 3)
    assert progress and progress[-1][1:] == (3, 3)
    assert not window.tracking.running and not m.layers[2].locked
    tracked = m.pose("calcaneus", 2)
    assert not np.allclose(tracked, start)  # frame 2 was registered, not just copied
    with Study.open(window.session.folder) as st:  # already in the journal
        np.testing.assert_allclose(st.trial("walk").poses("calcaneus")[2], tracked)
    assert set(np.flatnonzero(window.timeline.status >= 2)) == {0, 1, 2}


def test_tracking_can_be_cancelled(window, qtbot, monkeypatch):
    cancelled = pause_after_first_frame(monkeypatch)
    window.model.select("tibia")
    seen = []
    window.pool.progress.connect(lambda key, done, total: seen.append(done))
    try:
        with job_ends(qtbot, window.pool, "tracking", expect="cancelled") as ends:
            window.tracking.track_all()  # 4 bones x 3 frames
            qtbot.waitUntil(lambda: bool(seen or ends), timeout=HUNG_JOB_MS)  # a first frame done
            window.tracking.cancel()
            cancelled.set()
    finally:
        cancelled.set()
    assert seen and seen[-1] < 12  # stopped part-way
    assert not window.tracking.running
    assert not any(layer.locked for layer in window.model.layers)
    texts = [window.messages.item(i).text() for i in range(window.messages.count())]
    assert any("cancelled" in t for t in texts)
