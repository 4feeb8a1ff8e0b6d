"""A tracking run's clock frame by frame, with what ran in each frame (:class:`FrameClock`): the tool that
pins the slow frames of :mod:`core.studies.tracking.frame_profile` and ``talus bench track``.

A run's frames after the first are timed from the end of the frame before (its last bone's ``progress``),
as :func:`frame_walls` does; per frame the clock also keeps

* ``reg_ms``: the frame's registrations (the sum of its results' ``time_s``), and ``loop_ms``, the rest of
  its wall (the frame step's set-up, the checks' records, the feed, ``progress``, a pause between frames);
* ``cpu_ms``: the registering thread's CPU time over the frame (:func:`time.thread_time`); a wall far above
  it is time the thread did not run: waits for the device, for the interpreter (another thread holding
  it, up to :func:`sys.getswitchinterval` after each wait), or for a core (the OS);
* ``proc_cpu_ms``: the whole process's CPU time (:func:`time.process_time`): every thread's, the feed's
  worker and the device driver's included;
* ``feed_wait_ms``: the frame's :meth:`core.tracking.feed.FrameFeed.get` (the wait for the worker's
  preparation when it had not finished), ``feed_ready``: whether it had;
* ``worker_ms``: the feed's worker's preparations that ran in the frame (the next frame's, normally), their
  time within the frame's window;
* ``gc_ms`` and ``gc``: the garbage collections in the frame (pause and generations);
* ``after_last`` (the run after its last frame: the backward check, the trajectory post-pass): its wall,
  CPU, feed, worker and collection times as above (the clock stops at the end of :meth:`FrameClock.
  watching`, so the caller ends the block right after the run), and the wall and thread CPU times of
  the backward check (``backward_ms``, ``backward_cpu_ms``; :mod:`core.tracking.backward_check`) and
  of the trajectory post-pass (``post_pass_ms``, ``post_pass_cpu_ms``; :mod:`core.tracking.flags_post`);
* ``evaluations``, ``retried``, ``flagged``, ``stage_steps`` (the final stage's steps), ``other_ms`` (the
  registrations' ``other_s``): what the registrations did.

:meth:`FrameClock.report` gives the frames over :data:`SLOW` × the median (``slow``, each with those
fields; ``slowest_records``: the three slowest frames', whatever their ratio) and ``clusters``, runs of
consecutive slow frames, besides the summary of ``frame_walls``. The clock wraps the feed's two methods,
the backward check and the post-pass, and adds a garbage-collector callback within
:meth:`FrameClock.watching` only (put back after); ``progress`` is its per-frame hook. Timing only: what
the tracker computes is the same (its calls pass on unchanged).
"""

from __future__ import annotations

import gc
import sys
import threading
import time
from contextlib import contextmanager

import numpy as np

__all__ = ["SLOW", "FrameClock", "frame_walls"]

#: A frame whose wall exceeds this many times the run's median frame is reported with its details.
SLOW = 2.0


class FrameClock:
    """Frame-by-frame records of one tracking run (module docs). Use as::

        clock = FrameClock()
        with clock.watching():
            t0 = time.perf_counter()
            track(..., progress=clock.progress)
            wall = time.perf_counter() - t0
        clock.report(order, t0, wall)
    """

    def __init__(self) -> None:
        self.ends: dict = {}  # frame -> (perf_counter, thread_time, process_time) at its last bone's progress
        self.results: dict = {}  # frame -> [FrameResult]
        self.gets: list = []  # (start, end, frame, ready)
        self.worker: list = []  # (start, end) of the feed worker's preparations
        self.gcs: list = []  # (start, end, generation)
        self._gc_t0 = 0.0
        self._lock = threading.Lock()
        self.start = (time.perf_counter(), time.thread_time(), time.process_time())
        self.stop = None  # (the same, at the end of watching())
        self.after: dict = {}  # the backward check's and the post-pass's (seconds, thread CPU seconds)

    def progress(self, done, total, fr) -> None:
        """``track``'s ``progress``: the frame's end (the last of its bones') and its result."""
        self.results.setdefault(fr.frame, []).append(fr)
        self.ends[fr.frame] = (time.perf_counter(), time.thread_time(), time.process_time())

    def _gc(self, phase: str, info: dict) -> None:
        if phase == "start":
            self._gc_t0 = time.perf_counter()
        else:
            self.gcs.append((self._gc_t0, time.perf_counter(), int(info.get("generation", 0))))

    @contextmanager
    def watching(self):
        """Within the block the feed's ``get`` and its worker's preparation are timed and the garbage
        collections recorded (module docs); the clock's start is taken on entry."""
        import core.tracking.backward_check as backward
        import core.tracking.feed as feed
        import core.tracking.trial as trial

        get, prepare = feed.FrameFeed.get, feed.FrameFeed._prepare
        clock = self

        def timed_get(self, f):
            a = self.ahead
            ready = bool(a is not None and a[0] == f and a[2].done())
            t = time.perf_counter()
            try:
                return get(self, f)
            finally:
                clock.gets.append((t, time.perf_counter(), int(f), ready))

        def timed_prepare(self, *a, **k):
            t = time.perf_counter()
            try:
                return prepare(self, *a, **k)
            finally:
                with clock._lock:
                    clock.worker.append((t, time.perf_counter()))

        def timed_after(fn, name):
            def w(*a, **k):
                t, c = time.perf_counter(), time.thread_time()
                try:
                    return fn(*a, **k)
                finally:
                    clock.after[name] = (time.perf_counter() - t, time.thread_time() - c)
            return w

        feed.FrameFeed.get, feed.FrameFeed._prepare = timed_get, timed_prepare
        kept = [(backward, "backward_check", backward.backward_check),
                (trial, "apply_trajectory_flags", trial.apply_trajectory_flags)]
        for mod, name, fn in kept:
            setattr(mod, name, timed_after(fn, name))
        gc.callbacks.append(self._gc)
        self.start = (time.perf_counter(), time.thread_time(), time.process_time())
        try:
            yield self
        finally:
            self.stop = (time.perf_counter(), time.thread_time(), time.process_time())
            feed.FrameFeed.get, feed.FrameFeed._prepare = get, prepare
            for mod, name, fn in kept:
                setattr(mod, name, fn)
            if self._gc in gc.callbacks:
                gc.callbacks.remove(self._gc)

    def rows(self, order) -> list[dict]:
        """One record per frame of ``order`` that ended (module docs); the first frame's window starts
        at the clock's start."""
        out = []
        prev = self.start
        for f in order:
            if f not in self.ends:
                continue
            end = self.ends[f]
            a, b = prev[0], end[0]
            rs = self.results.get(f, [])
            reg = sum(float(r.time_s) for r in rs)
            tim = [r.timing or {} for r in rs]
            gets = [g for g in self.gets if g[2] == f and a <= g[0] <= b]
            gcs = [g for g in self.gcs if a <= g[0] < b]
            work = sum(max(0.0, min(e, b) - max(s, a)) for s, e in self.worker)
            out.append({
                "frame": int(f), "ms": 1e3 * (b - a), "reg_ms": 1e3 * reg, "loop_ms": 1e3 * (b - a - reg),
                "cpu_ms": 1e3 * (end[1] - prev[1]), "proc_cpu_ms": 1e3 * (end[2] - prev[2]),
                "feed_wait_ms": 1e3 * sum(e - s for s, e, _, _ in gets),
                "feed_ready": all(g[3] for g in gets) if gets else None,
                "worker_ms": 1e3 * work,
                "gc_ms": 1e3 * sum(e - s for s, e, _ in gcs), "gc": [g for _, _, g in gcs],
                "evaluations": int(sum(r.evaluations for r in rs)), "retried": any(r.retried for r in rs),
                "flagged": any(bool(r.flags) for r in rs),
                "stage_steps": int(sum(t.get("likelihood_steps", 0) for t in tim)),
                "other_ms": 1e3 * float(sum(t.get("other_s", 0.0) for t in tim))})
            prev = end
        return out

    def report(self, order, t0: float, wall: float, slow: float = SLOW) -> dict:
        """``frame_walls``' summary of the run (``t0`` its start, ``wall`` its length) with ``slow``:
        the frames after the first over ``slow`` × their median, each with its record (module docs),
        ``slowest_records`` the three slowest frames' records,
        ``clusters``: runs of consecutive slow frames (``[first, last]`` frame numbers), and the medians
        of the records' fields over the frames after the first (``typical``)."""
        out = frame_walls({f: e[0] for f, e in self.ends.items()}, order, t0, wall)
        rows = self.rows(order)[1:]
        if not rows:
            return out
        med = float(np.median([r["ms"] for r in rows]))
        hot = [r for r in rows if r["ms"] > slow * med]
        clusters, run = [], []
        pos = {r["frame"]: k for k, r in enumerate(rows)}
        for r in hot:
            if run and pos[r["frame"]] == pos[run[-1]] + 1:
                run.append(r["frame"])
            else:
                if run:
                    clusters.append([run[0], run[-1]])
                run = [r["frame"]]
        if run:
            clusters.append([run[0], run[-1]])
        keys = ("ms", "reg_ms", "loop_ms", "cpu_ms", "proc_cpu_ms", "feed_wait_ms", "worker_ms", "gc_ms",
                "other_ms", "evaluations", "stage_steps")
        out["typical"] = {k: float(np.median([r[k] for r in rows])) for k in keys}
        out["slow_over_median"] = slow
        out["slow"] = hot
        # the three slowest frames' records whatever their ratio to the median (frame_walls' "slowest")
        out["slowest_records"] = sorted(rows, key=lambda r: -r["ms"])[:3]
        out["clusters"] = clusters
        out["switch_interval_s"] = sys.getswitchinterval()
        last = max((e for e in self.ends.values()), default=None, key=lambda e: e[0])
        if last is not None and self.stop is not None:  # the backward check and the post-pass
            a, b = last[0], self.stop[0]
            out["after_last"] = {
                "ms": 1e3 * (b - a), "cpu_ms": 1e3 * (self.stop[1] - last[1]),
                "proc_cpu_ms": 1e3 * (self.stop[2] - last[2]),
                "feed_wait_ms": 1e3 * sum(e - s for s, e, _, _ in self.gets if s >= a),
                "worker_ms": 1e3 * sum(max(0.0, min(e, b) - max(s, a)) for s, e in self.worker),
                "gc_ms": 1e3 * sum(e - s for s, e, _ in self.gcs if s >= a)}
            for name, key in (("backward_check", "backward"), ("apply_trajectory_flags", "post_pass")):
                if name in self.after:
                    out["after_last"][f"{key}_ms"] = 1e3 * self.after[name][0]
                    out["after_last"][f"{key}_cpu_ms"] = 1e3 * self.after[name][1]
        return out


def frame_walls(ends: dict, order, t0: float, wall: float) -> dict:
    """A run's clock frame by frame: ``ends`` the time each frame of ``order`` finished (its last bone's
    ``progress``), ``t0`` the run's start and ``wall`` its length. The frames after the first, each from
    the end of the one before (``median_ms``, ``mean_ms``, ``max_ms``, ``slowest``: the three slowest
    ``[frame, ms]``), and ``after_last_frame_ms``: the run after its last frame's end (the backward check,
    the trajectory post-pass). A pause of the host (a full garbage collection) shows in ``max_ms`` and the
    mean, not in the median."""
    t = [ends[f] for f in order if f in ends]
    if not t:
        return {}
    d = np.diff(t) * 1e3
    fr = [f for f in order if f in ends][1:]
    slow = sorted(zip(fr, d.tolist(), strict=True), key=lambda x: -x[1])[:3]
    got = {k: (float(fn(d)) if len(d) else None) for k, fn in (("median_ms", np.median), ("mean_ms", np.mean),
                                                               ("max_ms", np.max))}
    return {**got, "slowest": [[int(f), ms] for f, ms in slow],
            "after_last_frame_ms": 1e3 * (t0 + wall - t[-1])}
