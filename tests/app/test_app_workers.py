"""Worker pool: results on the GUI thread, stale results dropped, errors reported, cancel."""

import gc
import threading
import time
import weakref

import pytest
from PySide6 import QtCore

from app.workers import GuiThreadCollector, WorkerPool

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


class _Node:
    pass


def test_garbage_is_collected_on_the_gui_thread_never_in_a_worker(qtbot):
    """While a pool lives, automatic collection is off and a GUI-thread timer collects (a worker
    thread that collected a closed window's Qt objects could deadlock with the GUI thread)."""
    threads = []

    def on_gc(phase, info):
        if phase == "start":
            threads.append(threading.current_thread())

    def churn():  # cyclic garbage made in the worker, past every threshold many times
        for _ in range(50_000):
            a = []
            a.append(a)
        return "done"

    pool = WorkerPool()
    collector = GuiThreadCollector.instance()
    gc.callbacks.append(on_gc)
    try:
        assert collector.armed and not gc.isenabled()
        with qtbot.waitSignal(pool.finished, timeout=HUNG_MS):
            pool.submit("churn", churn)
        node = _Node()
        node.me = node
        ref = weakref.ref(node)
        del node
        before = sum(collector.collections)
        for _ in range(2 * gc.get_threshold()[0]):  # past the generation-0 threshold
            b = []
            b.append(b)
        qtbot.waitUntil(lambda: ref() is None, timeout=HUNG_MS)  # collected by the timer
        assert sum(collector.collections) > before
    finally:
        gc.callbacks.remove(on_gc)
        pool.shutdown()
    assert threads and set(threads) == {threading.main_thread()}
    assert pool not in collector._holders()
    if not collector._holders():  # no other pool alive: automatic collection is back
        assert not collector.armed and gc.isenabled()


def test_a_closed_pool_holds_automatic_collection_off_until_its_job_ends(qtbot):
    pool = WorkerPool()
    collector = GuiThreadCollector.instance()
    release, started = threading.Event(), threading.Event()
    pool.submit("hold", lambda: started.set() or release.wait(HUNG_MS / 1000))
    try:
        qtbot.waitUntil(started.is_set, timeout=HUNG_MS)
        pool.shutdown(wait=False)  # as a window's close does: the running job goes on
        assert pool.running() and pool in collector._holders()
        assert collector.armed and not gc.isenabled()
    finally:
        release.set()
    qtbot.waitUntil(lambda: not pool.running(), timeout=HUNG_MS)
    qtbot.waitUntil(lambda: pool not in collector._holders(), timeout=HUNG_MS)
    GuiThreadCollector.check()
    if not collector._holders():
        assert not collector.armed and gc.isenabled()
