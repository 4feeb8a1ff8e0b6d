"""Background work for the GUI: request -> response, off the GUI thread.

* A request is a plain function with its arguments (snapshots: arrays are copied by the caller),
  submitted under a *key* ("overlay", "track:talus", ...). Submitting again under the same key
  supersedes the previous request: it is cancelled if it has not started and its result is
  dropped if it has, so the GUI only ever sees the newest answer.
* Work runs in a ``concurrent.futures`` thread pool (Warp releases the GIL during launches); by
  default one worker, which also serialises use of the GPU.
* Results, errors and progress come back as Qt signals on the GUI thread. A worker exception is
  reported through ``failed`` (with the traceback text) and never raises into the event loop.
  Worker threads never touch Qt: they put messages in a thread-safe queue that a GUI-thread
  timer drains while jobs are running (emitting Qt signals from Python threads corrupts the
  reference counts of ``True``/``False`` in PySide6 6.12 on Python 3.11 and aborts the process).
* Cancellation is cooperative: the function receives ``cancel`` (a callable returning True once
  cancelled) and ``progress(done, total)`` when it accepts those keyword arguments.
* Every job ends exactly once, whatever way it ends: a result, an error, or ``cancelled`` — also a
  job cancelled (or superseded, or dropped by :meth:`WorkerPool.shutdown`) while it still waited
  for a worker, whose function never runs: its future's done-callback posts the end then. After
  the end of the last job ``busy_changed(False)`` follows, so nothing waits on a job that will
  never come back and no progress bar is left behind.
* Python's garbage collector runs on the GUI thread only while a pool lives (see
  :class:`GuiThreadCollector`): an automatic collection may start in whichever thread allocates,
  and one in a worker thread that finalises a closed window's Qt objects deadlocks with the GUI
  thread (the worker holds a Qt lock and waits for the interpreter lock, the GUI thread holds the
  interpreter lock and waits for that Qt lock).
"""

from __future__ import annotations

import gc
import inspect
import itertools
import queue
import threading
import time
import traceback
import weakref
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field

from PySide6 import QtCore

__all__ = ["CancelToken", "GuiThreadCollector", "Job", "WorkerPool"]


class CancelToken:
    """Thread-safe cancel flag; calling it returns whether cancellation was requested."""

    def __init__(self) -> None:
        self._event = threading.Event()

    def set(self) -> None:
        self._event.set()

    def is_set(self) -> bool:
        return self._event.is_set()

    __call__ = is_set


@dataclass(eq=False)
class Job:
    key: str
    id: int
    token: CancelToken = field(default_factory=CancelToken)
    future: Future | None = None

    def cancel(self) -> None:
        self.token.set()
        if self.future is not None:
            self.future.cancel()


class WorkerPool(QtCore.QObject):
    """Run requests off the GUI thread and deliver the newest result per key on it."""

    finished = QtCore.Signal(str, object)  # key, result
    failed = QtCore.Signal(str, str)  # key, message (with traceback)
    cancelled = QtCore.Signal(str)
    progress = QtCore.Signal(str, int, int)  # key, done, total
    busy_changed = QtCore.Signal(bool)

    POLL_MS = 10  # how often the GUI thread collects worker messages while jobs run

    def __init__(self, parent: QtCore.QObject | None = None, *, max_workers: int = 1) -> None:
        super().__init__(parent)
        self._executor = ThreadPoolExecutor(max_workers=max_workers, thread_name_prefix="talus")
        self._latest: dict[str, Job] = {}
        self._jobs: dict[int, Job] = {}
        self._inbox: queue.SimpleQueue = queue.SimpleQueue()
        self._ids = itertools.count(1)
        self._timer = QtCore.QTimer(self)
        self._timer.setInterval(self.POLL_MS)
        self._timer.timeout.connect(self._drain)
        self._closed = False
        self._busy_shown = False  # the state busy_changed last announced (it fires on changes only)
        GuiThreadCollector.hold(self)  # no automatic collection in a worker thread (module notes)

    # ------------------------------------------------------------------ API
    def submit(self, key: str, fn: Callable, /, *args, **kwargs) -> Job:
        """Run ``fn(*args, **kwargs)`` in the pool; supersedes the previous job of ``key``."""
        if self._closed:
            raise RuntimeError("WorkerPool: already shut down")
        old = self._latest.get(key)
        if old is not None:
            old.cancel()
        job = Job(key, next(self._ids))
        params = _accepted(fn)
        if "cancel" in params:
            kwargs.setdefault("cancel", job.token)
        if "progress" in params:
            kwargs.setdefault("progress", lambda done, total: self._inbox.put(
                ("progress", job.id, (int(done), int(total)))))
        self._latest[key] = job
        self._jobs[job.id] = job
        job.future = self._executor.submit(self._run, job, fn, args, kwargs)
        # a job cancelled before a worker took it never runs ``_run``: report its end from here
        # (called at once by ``Future.cancel`` on the cancelling thread; never for a job that ran)
        job.future.add_done_callback(lambda fut, job=job: self._on_future_done(job, fut))
        if not self._timer.isActive():
            self._timer.start()
        if not self._busy_shown:
            self._busy_shown = True
            self.busy_changed.emit(True)
        return job

    def cancel(self, key: str) -> None:
        job = self._latest.get(key)
        if job is not None:
            job.cancel()

    @property
    def closed(self) -> bool:
        return self._closed

    @property
    def busy(self) -> bool:
        return any(j.future is not None and not j.future.done() for j in self._latest.values())

    def shutdown(self, *, wait: bool = True) -> None:
        """Cancel everything and stop the threads (call when the window closes)."""
        self._closed = True
        self._timer.stop()
        for job in self._latest.values():
            job.cancel()
        self._executor.shutdown(wait=wait, cancel_futures=True)
        GuiThreadCollector.check()  # automatic collection back once no job of any pool runs

    def running(self) -> bool:
        """Whether a worker thread still runs one of this pool's jobs (also after shutdown)."""
        return any(j.future is not None and j.future.running() for j in list(self._jobs.values()))

    # ------------------------------------------------------------------ internals
    def _run(self, job: Job, fn, args, kwargs) -> None:
        if job.token.is_set():
            self._post(job, None, "cancelled")
            return
        try:
            result = fn(*args, **kwargs)
        except BaseException as exc:  # a worker must never take the window down
            text = "".join(traceback.format_exception(exc)).rstrip()
            self._post(job, None, text)
            return
        self._post(job, result, "cancelled" if job.token.is_set() else None)

    def _on_future_done(self, job: Job, fut: Future) -> None:
        if fut.cancelled():  # never started: ``_run`` posts nothing for it
            self._post(job, None, "cancelled")

    def _post(self, job: Job, result, error: str | None) -> None:
        self._inbox.put(("done", job.id, (result, error)))

    def drain(self) -> None:
        """Deliver pending worker messages now (normally done by the timer)."""
        self._drain()

    @QtCore.Slot()
    def _drain(self) -> None:
        while True:
            try:
                kind, job_id, payload = self._inbox.get_nowait()
            except queue.Empty:
                break
            if kind == "progress":
                self._relay_progress(job_id, *payload)
            else:
                self._deliver(job_id, *payload)
        if not self._jobs:
            self._timer.stop()

    def _deliver(self, job_id: int, result, error: str | None) -> None:
        job = self._jobs.pop(job_id, None)
        if job is None:
            return
        latest = self._latest.get(job.key)
        current = latest is job
        if current:
            del self._latest[job.key]
        if self._busy_shown and not self.busy:
            self._busy_shown = False
            self.busy_changed.emit(False)
        if not current or self._closed:
            return  # superseded: drop the stale answer
        if error == "cancelled":
            self.cancelled.emit(job.key)
        elif error is not None:
            self.failed.emit(job.key, error)
        else:
            self.finished.emit(job.key, result)

    def _relay_progress(self, job_id: int, done: int, total: int) -> None:
        job = self._jobs.get(job_id)
        if job is not None and self._latest.get(job.key) is job:
            self.progress.emit(job.key, done, total)


class GuiThreadCollector(QtCore.QObject):
    """Python's garbage collection on the GUI thread, from a timer, while worker pools live.

    CPython collects cyclic garbage in whichever thread happens to allocate past the threshold.
    When that is a worker thread and the garbage holds a closed window's Qt objects, the worker
    destroys them holding a Qt lock and then waits for the interpreter lock, which the GUI thread
    holds while it waits for the same Qt lock: the window hangs for ever (seen in a GUI test, gdb
    stacks of both threads). So, as PyQtGraph does, automatic collection is disabled while any
    :class:`WorkerPool` is alive (or a worker still runs a job of a closed one) and this timer
    collects on the GUI thread instead: generation 0 whenever its count passed the threshold (every
    ``INTERVAL_MS`` at most), generation 1 likewise, a full collection at most every
    ``FULL_MIN_S`` (one of the ~200 000 objects of the imported libraries takes 0.4 s on a 2-core
    machine). When the last pool has gone, one full collection runs here and automatic collection
    is restored as it was. Worker threads never call ``gc.collect``.

    One instance per application, made by the first pool (``WorkerPool.__init__`` calls
    :meth:`hold`), so ``talus gui``, :class:`app.viewer.Viewer` and tests that build a window all
    get it, whoever created the ``QApplication``.
    """

    INTERVAL_MS = 100
    FULL_MIN_S = 30.0

    _instance: GuiThreadCollector | None = None

    def __init__(self, app: QtCore.QCoreApplication) -> None:
        super().__init__(app)
        self._pools: weakref.WeakSet = weakref.WeakSet()
        self._was_enabled: bool | None = None  # gc.isenabled() when armed; None: not armed
        self._last_full = time.monotonic()
        self.collections = [0, 0, 0]  # collections run by this timer, per generation
        self._timer = QtCore.QTimer(self)
        self._timer.setInterval(self.INTERVAL_MS)
        self._timer.timeout.connect(self._tick)

    # ------------------------------------------------------------------ API
    @classmethod
    def instance(cls) -> GuiThreadCollector | None:
        """The application's collector (None before the first pool or without an application)."""
        app = QtCore.QCoreApplication.instance()
        inst = cls._instance
        if app is None:
            return None
        if inst is None or not _valid(inst) or inst.parent() is not app:
            inst = cls._instance = cls(app)
        return inst

    @classmethod
    def hold(cls, pool: WorkerPool) -> None:
        """Keep automatic collection off while ``pool`` lives (call on the GUI thread)."""
        inst = cls.instance()
        if inst is None or threading.current_thread() is not threading.main_thread():
            return
        inst._pools.add(pool)
        if inst._was_enabled is None:
            inst._was_enabled = gc.isenabled()
            gc.disable()
            inst._last_full = time.monotonic()
        inst._timer.start()

    @classmethod
    def check(cls) -> None:
        """Restore automatic collection now if no pool holds it any more (e.g. after a window
        closed; the timer also does this)."""
        inst = cls._instance
        if inst is not None and _valid(inst) and threading.current_thread() is threading.main_thread():
            inst._release_if_unheld()

    @property
    def armed(self) -> bool:
        """Whether automatic collection is held off (and this timer collects)."""
        return self._was_enabled is not None

    def collect_due(self) -> int | None:
        """Collect the generation whose count passed its threshold, as CPython would (a full
        collection at most every ``FULL_MIN_S``); returns the generation collected, or None."""
        counts, thresholds = gc.get_count(), gc.get_threshold()
        if thresholds[0] <= 0 or counts[0] <= thresholds[0]:
            return None
        gen = 0
        if counts[1] > thresholds[1]:
            gen = 1
            if counts[2] > thresholds[2] and time.monotonic() - self._last_full >= self.FULL_MIN_S:
                gen = 2
        gc.collect(gen)
        if gen == 2:
            self._last_full = time.monotonic()
        self.collections[gen] += 1
        return gen

    # ------------------------------------------------------------------ internals
    def _holders(self) -> list:
        return [p for p in list(self._pools) if p.running() or (_valid(p) and not p.closed)]

    def _release_if_unheld(self) -> None:
        if not self.armed or self._holders():
            return
        self._timer.stop()
        gc.collect()  # here, on the GUI thread, before any thread may collect again
        self._last_full = time.monotonic()
        if self._was_enabled:
            gc.enable()
        self._was_enabled = None

    @QtCore.Slot()
    def _tick(self) -> None:
        self._release_if_unheld()
        if self.armed:
            self.collect_due()


def _valid(obj: QtCore.QObject) -> bool:
    """Whether ``obj``'s C++ object still exists."""
    import shiboken6

    return shiboken6.isValid(obj)


def _accepted(fn: Callable) -> set[str]:
    try:
        params = inspect.signature(fn).parameters
    except (TypeError, ValueError):
        return set()
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return {"cancel", "progress"}
    return set(params)
