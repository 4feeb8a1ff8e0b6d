"""Range tasks of ``talus batch`` sharing one bone's journal (:mod:`core.tracking.batch`).

The ranges of one bone (:func:`core.tracking.batch.keyframe_ranges`) are tracked side by side by
different worker processes into the bone's one pose journal. :class:`SharedJournals` is the study
as :func:`~core.tracking.from_study.track_study` sees it in such a task: locking a journal only
checks that no other writer (``talus track``, the window) holds it for good, and each record takes
the journal's lock — the study layout's ``results/<trial>/poses/.<bone>.lock``, the one
:meth:`core.study.Study.lock_journal` holds — for its append only, after cutting off a record torn
by a writer that was killed mid-append.

:meth:`SharedJournals.holding` holds the locks of a trial's bones across a read-modify-write — the
trajectory pass over a trial's ranges (:mod:`core.tracking.batch_pass`) reads the journals, judges
the frames and journals the flags it changed under them — so a hand fix (a pose recorded by the
window or another process, which takes the same lock) cannot land between the read and the write
and be overtaken: it waits for the pass, or the pass for it, and the pass then reads it.

The locks' holder lines say which of these holds them (``by``: :data:`TRAJECTORY_CHECK`,
:data:`RANGE_APPEND`, :data:`RANGE_START`), so a refused hand fix names the holder — also in the
window's own process, where its batch's trajectory check runs.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

__all__ = ["BATCH_TASK", "JOURNAL_START_WAIT_S", "JOURNAL_WAIT_S", "RANGE_APPEND", "RANGE_START",
           "TRAJECTORY_CHECK", "SharedJournals"]

JOURNAL_WAIT_S = 60.0  # how long a range task's record waits for another range's append
JOURNAL_START_WAIT_S = 5.0  # how long a range task's start waits for a bone another writer holds
#: what holds a journal's lock, in its holder line (``by``; module notes)
TRAJECTORY_CHECK = "talus batch's trajectory check"
RANGE_APPEND = "a talus batch range task's append"
RANGE_START = "a talus batch range task's start"
BATCH_TASK = "a talus batch task tracking the bone"


def _journal_lock(folder: Path, trial: str, bone: str, wait_s: float, by: str):
    """The lock of a bone's journal (the study layout's ``results/<trial>/poses/.<bone>.lock``,
    the one :meth:`core.study.Study.lock_journal` holds), taken within ``wait_s`` seconds by
    ``by``."""
    from ..io.atomic import FileLock

    path = folder / "results" / trial / "poses" / f".{bone}.lock"
    path.parent.mkdir(parents=True, exist_ok=True)
    lock = FileLock(path, purpose=f"bone {bone!r} of trial {trial!r} in study {folder}", by=by)
    return lock.acquire(timeout=wait_s)


class _SharedTrial:
    """A trial whose :meth:`record_pose` takes the bone journal's lock for one append."""

    def __init__(self, trial, folder: Path, wait_s: float, held: frozenset | set = frozenset()) -> None:
        self._trial, self._folder, self._wait_s, self._held = trial, folder, wait_s, held

    def __getattr__(self, name):
        return getattr(self._trial, name)

    def record_pose(self, bone: str, frame: int, pose, *, score=None, tracking=None) -> None:
        from ..study.results import append_pose, repair_tail

        path = self._folder / "results" / self._trial.name / "poses" / f"{bone}.jsonl"
        held = (self._trial.name, bone) in self._held  # SharedJournals.holding: the lock is ours already
        lock = None if held else _journal_lock(self._folder, self._trial.name, bone, self._wait_s,
                                                RANGE_APPEND)
        try:
            if path.exists() and path.stat().st_size:  # a torn last record (a writer killed
                with open(path, "rb") as fh:  # mid-append) is cut off first, as Trial does
                    fh.seek(-1, os.SEEK_END)
                    if fh.read(1) != b"\n":
                        repair_tail(path)
            append_pose(path, int(frame), pose, score=score, tracking=tracking)
        finally:
            if lock is not None:
                lock.release()


class SharedJournals:
    """The study ``study`` (open for writing) as a range task's ``track_study`` sees it (module
    notes)."""

    def __init__(self, study, wait_s: float = JOURNAL_WAIT_S) -> None:
        self._study, self._wait_s = study, wait_s
        self._held: set[tuple[str, str]] = set()  # (trial, bone) whose lock holding() holds

    def __getattr__(self, name):
        return getattr(self._study, name)

    def lock_journal(self, trial: str, bone: str, *, by: str = "") -> None:
        """Taken and released as a range task's start (``by`` is :data:`RANGE_START`)."""
        self._study.trial(trial).bones  # noqa: B018 (an unknown trial raises here)
        _journal_lock(self._study.folder, trial, bone, JOURNAL_START_WAIT_S, RANGE_START).release()

    def trial(self, name: str) -> _SharedTrial:
        return _SharedTrial(self._study.trial(name), self._study.folder, self._wait_s, self._held)

    @contextmanager
    def holding(self, trial: str, bones: Sequence[str],
                wait_s: float = JOURNAL_START_WAIT_S) -> Iterator[None]:
        """Hold the journal locks of ``bones`` of ``trial`` (taken in name order, each within
        ``wait_s`` seconds: another writer's append is waited for, a writer that holds the bone
        for good refuses with :class:`~core.io.atomic.LockedError`) for a read-modify-write: reads
        in the block see every record appended before it, and this object's
        :meth:`_SharedTrial.record_pose` appends without taking them again (module notes)."""
        self._study.trial(trial).bones  # noqa: B018 (an unknown trial raises here)
        locks = []
        try:
            for b in sorted(set(bones)):
                locks.append(_journal_lock(self._study.folder, trial, b, wait_s, TRAJECTORY_CHECK))
                self._held.add((trial, b))
            yield
        finally:
            for b in sorted(set(bones)):
                self._held.discard((trial, b))
            for lock in locks:
                lock.release()
