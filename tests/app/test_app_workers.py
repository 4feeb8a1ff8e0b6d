"""Worker pool: results on the GUI thread, stale results dropped, errors reported, cancel."""

import threading
import time

import pytest
from PySide6 import QtCore

from app.workers import WorkerPool

pytestmark = pytest.mark.gui

# Waits end on the event itself (a signal, a state); the timeout is only the ceiling for an event
# that never comes, not a time the work is expected to take on a loaded machine.
HUNG_MS = 30 * 60_000


@pytest.fixture
def pool(qtbot):
    p = WorkerPool()
    yield p
    p.shutdown()


def test_result_arrives_on_the_gui_thread(qtbot, pool):
    got = []
    pool.finished.connect(lambda key, result: got.append((key, result, threading.current_thread())))
    with qtbot.waitSignal(pool.finished, timeout=HUNG_MS):
        pool.submit("sum", lambda a, b: a + b, 2, 3)
    assert got == [("sum", 5, threading.main_thread())]


def test_newer_request_supersedes_the_older(qtbot, pool):
    got = []
    pool.finished.connect(lambda key, result: got.append(result))

    def slow(x, cancel):
        for _ in range(50):
            if cancel():
                return "stale"
            time.sleep(0.002)
        return x

    pool.submit("overlay", slow, 1)
    pool.submit("overlay", slow, 2)
    with qtbot.waitSignal(pool.finished, timeout=HUNG_MS):
        pool.submit("overlay", slow, 3)
    qtbot.wait(50)
    assert got == [3]


def test_worker_exception_is_reported_not_raised(qtbot, pool):
    def boom():
        raise RuntimeError("bad frame 7")

    with qtbot.waitSignal(pool.failed, timeout=HUNG_MS) as sig:
        pool.submit("track", boom)
    key, text = sig.args
    assert key == "track" and "RuntimeError: bad frame 7" in text and "Traceback" in text
    with qtbot.waitSignal(pool.finished, timeout=HUNG_MS):  # the pool still works
        pool.submit("track", lambda: 1)


def test_long_job_keeps_gui_responsive_reports_progress_and_cancels(qtbot, pool):
    ticks = []
    timer = QtCore.QTimer()
    timer.timeout.connect(lambda: ticks.append(time.perf_counter()))
    timer.start(10)
    progress = []
    pool.progress.connect(lambda key, done, total: progress.append(done))

    def long_job(progress, cancel):
        for i in range(1000):
            if cancel():
                return i
            time.sleep(0.005)
            progress(i + 1, 1000)
        return 1000

    pool.submit("job", long_job)
    qtbot.waitUntil(lambda: len(progress) >= 40, timeout=HUNG_MS)  # >= 0.2 s of work
    with qtbot.waitSignal(pool.cancelled, timeout=HUNG_MS):
        pool.cancel("job")
    timer.stop()
    assert len(ticks) >= 8  # the 10 ms timer kept ticking while the job worked
    assert progress == sorted(progress) and progress[-1] < 1000
    assert not pool.busy
