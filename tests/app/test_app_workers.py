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


def _ends(pool):
    """Every end the pool reports, in order: (signal name, key)."""
    ends = []
    pool.finished.connect(lambda key, result: ends.append(("finished", key)))
    pool.failed.connect(lambda key, text: ends.append(("failed", key)))
    pool.cancelled.connect(lambda key: ends.append(("cancelled", key)))
    return ends


def test_job_cancelled_before_it_starts_ends_once_and_the_pool_goes_idle(qtbot, pool):
    """The one worker is held by a job that waits on an event, so "queued" is cancelled while it
    still waits for a worker: its function never runs, and its end is still reported, once."""
    ends = _ends(pool)
    busy = []
    pool.busy_changed.connect(busy.append)
    release = threading.Event()
    ran = []
    pool.submit("hold", lambda: release.wait(HUNG_MS / 1000) and "held")
    pool.submit("queued", lambda: ran.append(1))
    assert busy == [True]
    with qtbot.waitSignal(pool.cancelled, timeout=HUNG_MS, check_params_cb=lambda key: key == "queued"):
        pool.cancel("queued")
    assert ends == [("cancelled", "queued")] and pool.busy  # "hold" still runs
    with qtbot.waitSignal(pool.finished, timeout=HUNG_MS):
        release.set()
    qtbot.waitUntil(lambda: busy[-1] is False, timeout=HUNG_MS)
    pool.drain()  # nothing more is reported for either job
    assert ends == [("cancelled", "queued"), ("finished", "hold")]
    assert ran == [] and busy == [True, False] and not pool.busy
    assert not pool._jobs and not pool._latest  # no job left waiting for an answer


def test_job_superseded_before_it_starts_gives_only_the_newest_answer(qtbot, pool):
    ends = _ends(pool)
    got = []
    pool.finished.connect(lambda key, result: got.append((key, result)))
    release = threading.Event()
    pool.submit("hold", lambda: release.wait(HUNG_MS / 1000) and "held")
    for x in (1, 2, 3):  # the first two are superseded while they wait: dropped, never reported
        pool.submit("overlay", lambda x=x: x)
    release.set()
    qtbot.waitUntil(lambda: not pool._jobs, timeout=HUNG_MS)
    assert sorted(got) == [("hold", "held"), ("overlay", 3)]
    assert sorted(ends) == [("finished", "hold"), ("finished", "overlay")]
    assert not pool.busy


def test_cancel_every_job_while_one_runs_and_others_wait(qtbot, pool):
    """What the window's Cancel button does: each job ends once, running or waiting, and the
    busy state (which clears the progress bar) falls back to False."""
    ends = _ends(pool)
    busy = []
    pool.busy_changed.connect(busy.append)
    started = threading.Event()

    def running(cancel):
        started.set()
        while not cancel():
            time.sleep(0.001)
        return "stopped"

    pool.submit("run", running)
    pool.submit("wait1", lambda: 1)
    pool.submit("wait2", lambda: 2)
    qtbot.waitUntil(started.is_set, timeout=HUNG_MS)
    for key in ("wait2", "run", "wait1"):
        pool.cancel(key)
    qtbot.waitUntil(lambda: len(ends) == 3, timeout=HUNG_MS)
    qtbot.waitUntil(lambda: bool(busy) and busy[-1] is False, timeout=HUNG_MS)
    pool.drain()
    assert sorted(ends) == [("cancelled", "run"), ("cancelled", "wait1"), ("cancelled", "wait2")]
    assert busy == [True, False] and not pool.busy and not pool._jobs
