"""Hand edits of a bone whose journal the window does not hold, kept off the GUI thread's way.

A hand edit (a drag, a nudge, *K*, *Undo fix*, Edit → Undo) is appended to the bone's journal under
the journal's lock, taken for that append only (:mod:`app.session`). Where another writer holds
the lock — a batch's trajectory check (milliseconds to a fraction of a second), a range task's
append — the edit waits for it up to :data:`HAND_EDIT_WAIT_S`, but not on the GUI thread: the
edit is queued, a ``QTimer`` tries the lock every :data:`POLL_MS`, and the window keeps drawing
and taking input meanwhile (it froze for that second: on this 2-core x86_64 machine, shared, a
*Move x+* on a held journal returned after 1009 ms and a 10-ms timer fired once in that time; now
it returns in 7.5 ms and the timer fires 100 times in the 1 s wait, its longest gap 15 ms). Edits
of the bone made during the wait join the queue (a frame's later pose replaces its earlier one)
and are journaled in order once the lock comes. Where it does not come they are refused, and the
window's messages say why: who holds the journal, named from the lock file's holder line
(:class:`core.io.atomic.FileLock`'s pid, host, since and ``by``: "this window's batch" only where
the holder is this process's batch) — and that they are not saved.

After a refusal the bone's next edits for :data:`REFUSED_QUIET_S` (the rest of a drag) are tried
once without waiting; each one refused says so again, the same message as the first with a count,
updating that one message (and the status bar) rather than adding one per move (a later burst of
refusals has a message of its own). A write that fails (a full disk) is said likewise.

While a bone's edits wait, *Undo fix* of it, a tracking job and a batch wait for them (each would
read or write the journal before them: :meth:`HandEdits.after_waiting`): the status bar says so,
and they go ahead once the edits are journaled or refused — within :data:`HAND_EDIT_WAIT_S`
(they used to be refused, to be asked for again). Edits still waiting when the window closes are journaled
or refused then, blocking for what is left of their wait (what waited for them is dropped, and
said); where refused, the window stays open for the message (:meth:`HandEdits.settle`,
``MainWindow.closeEvent``).

Without a Qt application, or with no one to tell (:attr:`app.session.StudySession.notify` None),
the wait blocks and a refusal raises :class:`core.study.LockedError`.
"""

from __future__ import annotations

import os
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass, field

__all__ = ["HAND_EDIT_WAIT_S", "POLL_MS", "REFUSED_QUIET_S", "WINDOW_EDIT", "HandEdits", "holder_text"]

#: How long a hand edit waits for a bone's journal the window does not hold (handed to a batch):
#: the trajectory check holds a trial's journals for milliseconds to a fraction of a second (the
#: pass itself took 2-25 ms per bone in core.tracking.flags_post's timings).
HAND_EDIT_WAIT_S = 1.0
#: After a refused hand edit, the bone's next edits for this long (the rest of a drag) are refused
#: unless the journal is free at once (no wait); each says so, updating the refusal's message.
REFUSED_QUIET_S = 2.0
#: How often a waiting edit tries the journal's lock (ms).
POLL_MS = 20
#: The window's hand edit in a journal lock's holder line (``by``).
WINDOW_EDIT = "the window's hand edit"


def holder_text(holder: dict) -> str:
    """Who holds a journal, from its lock file's holder line (``pid``, ``host``, ``since``,
    ``by``): this window's batch only where the holder is a batch (its trajectory check, or a
    range task's append) in this very process."""
    from core.tracking.batch_journal import BATCH_TASK, RANGE_APPEND, RANGE_START, TRAJECTORY_CHECK
    from core.tracking.from_study import WINDOW_TRACKING

    if not holder:
        return "another writer"
    by, since = holder.get("by") or "", holder.get("since", "?")
    if holder.get("pid") == os.getpid() and holder.get("host") == socket.gethostname():
        batch = {TRAJECTORY_CHECK: "its trajectory check", RANGE_APPEND: "a range task's append",
                 RANGE_START: "a range task's start", BATCH_TASK: "a task tracking the bone"}
        if by in batch:
            return f"this window's batch ({batch[by]})"
        if by == WINDOW_TRACKING:
            return "this window's tracking job"
        return (f"another handle of the study in this program since {since} "
                f"({by or 'what holds it is not recorded'})")
    # another process: a window there is not this one ("the window's ..." read as this window)
    what = {WINDOW_EDIT: "another window's hand edit", WINDOW_TRACKING: "another window's tracking job"}.get(
        by, by or "a batch's task tracking the bone, or another program")
    return f"process {holder.get('pid', '?')} on {holder.get('host', '?')} since {since} ({what})"


@dataclass
class _Waiting:
    """A bone's edits waiting for its journal."""

    deadline: float
    writes: dict = field(default_factory=dict)  # key -> (write, done), in order
    n: int = 1  # the edits made (a frame's later pose replaces its earlier one in writes)
    exc: Exception | None = None  # the last refusal of the lock


class HandEdits:
    """The hand edits of a :class:`app.session.StudySession` (module notes)."""

    def __init__(self, session) -> None:
        self._s = session
        self._waiting: dict[str, _Waiting] = {}
        #: bone -> (last refusal, edits refused in its burst, the burst's message tag)
        self._refused: dict[str, tuple[float, int, str]] = {}
        self._unsaved: set[str] = set()  # bones whose last edit was refused
        self._timer = None
        self._n = 0  # unique keys and message tags
        self._after: dict[str, tuple[str | None, Callable[[], None]]] = {}  # key -> (bone, action)

    # ------------------------------------------------------------------ queries
    def waiting(self, bone: str | None = None) -> bool:
        """Whether ``bone``'s (any bone's) edits wait for its journal."""
        return bool(self._waiting) if bone is None else bone in self._waiting

    def unsaved(self, bone: str) -> bool:
        """Whether ``bone``'s last edit is not in the journal: refused, or still waiting."""
        return bone in self._unsaved or bone in self._waiting

    def after_waiting(self, key: str, action: Callable[[], None], bone: str | None = None) -> bool:
        """Where edits of ``bone`` (None: of any bone) wait for their journal, run ``action`` once
        they are journaled or refused — at most :data:`HAND_EDIT_WAIT_S` later, from the wait's
        timer — and return True; where none waits, return False (the caller goes on now).
        ``action`` must not raise (the window's actions go through its ``_guard``). A later call
        with the same ``key`` replaces the action waiting; closing the window drops them."""
        if not self.waiting(bone):
            return False
        self._after.pop(key, None)
        self._after[key] = (bone, action)
        return True

    def _run_after(self) -> None:
        for key in [k for k, (bone, _) in self._after.items() if not self.waiting(bone)]:
            _, action = self._after.pop(key)
            action()

    # ------------------------------------------------------------------ edits
    def submit(self, bone: str, write: Callable[[], None], *, key=None,
               done: Callable[[], None] | None = None) -> str:
        """Journal a hand edit of ``bone`` (``write``, its append; ``done`` called once it is
        written, at once or later). ``key``: a later edit with the same key while they wait
        replaces this one (a frame's pose). Returns ``"saved"``, ``"waiting"`` or ``"refused"``
        (refused, or its write failed: said in the window)."""
        from core.study import LockedError

        s = self._s
        st, trial = s.study, s.trial_name
        if key is None:
            self._n += 1
            key = ("edit", self._n)
        if bone in self._waiting:  # behind the edits waiting: in order
            w = self._waiting[bone]
            w.writes.pop(key, None)
            w.writes[key] = (write, done)
            w.n += 1
            return "waiting"
        if st.journal_locked(trial, bone):  # the window's own (its tracking job's)
            return self._write_now(bone, write, done)
        last = self._refused.get(bone, (-1e9,))[0]
        quiet = time.monotonic() - last < REFUSED_QUIET_S
        background = s.notify is not None and _has_app()
        try:
            st.lock_journal(trial, bone, timeout=0.0 if quiet or background else HAND_EDIT_WAIT_S,
                            by=WINDOW_EDIT)
        except LockedError as exc:
            if quiet or not background:
                self._refuse(bone, exc, n=1, waited=0.0 if quiet else HAND_EDIT_WAIT_S, again=quiet)
                return "refused"
            self._waiting[bone] = _Waiting(time.monotonic() + HAND_EDIT_WAIT_S, {key: (write, done)}, exc=exc)
            self._start_timer()
            return "waiting"
        try:
            return self._write_now(bone, write, done)
        finally:
            st.unlock_journal(trial, bone)  # the batch keeps the bone

    def _write_now(self, bone: str, write, done) -> str:
        try:
            write()
        except Exception as exc:  # e.g. a full disk: said (a drag's signal raised into the event loop)
            if self._s.notify is None:
                raise
            self._failed(bone, 1, exc)
            return "refused"
        self._saved(bone)
        if done is not None:
            done()
        return "saved"

    def _saved(self, bone: str) -> None:
        self._refused.pop(bone, None)
        self._unsaved.discard(bone)

    def _failed(self, bone: str, n: int, exc: Exception) -> None:
        """Say that ``n`` edits of ``bone`` are not saved: their write failed (``exc``)."""
        self._unsaved.add(bone)
        head = "the edit is not saved" if n == 1 else f"{n} edits are not saved"
        self._s.notify(f"{bone}: {head}: {exc}", f"failed:{bone}")

    def _refuse(self, bone: str, exc, *, n: int, waited: float, again: bool) -> None:
        """Say that ``n`` edits of ``bone`` are not saved (``again``: within the quiet time of the
        last refusal, whose message is updated), or raise where no one can be told."""
        self._unsaved.add(bone)
        if again and bone in self._refused:  # the burst's message, updated
            _, before, tag = self._refused[bone]
        else:  # a new burst: a message of its own (the last burst's count stays in the log)
            self._n += 1
            before, tag = 0, f"refused:{bone}:{self._n}"
        total = before + n
        self._refused[bone] = (time.monotonic(), total, tag)
        who = holder_text(getattr(exc, "holder", {}) or {})
        if total == 1:
            head, how = "the edit is not saved", f"waited {waited:g} s"
        else:
            head = f"{total} edits are not saved"
            how = (f"the last at {time.strftime('%H:%M:%S')}, "
                   + (f"not waited for: within {REFUSED_QUIET_S:g} s of a refusal" if waited == 0 else
                      f"after {waited:g} s"))
        text = (f"{bone}: {head} ({how}): its journal is being written by {who}. Edit it again once "
                "that is over; a batch gives its bones back to the window when it ends.")
        if self._s.notify is None:
            exc.args = (text,)
            raise exc
        self._s.notify(text, tag)

    # ------------------------------------------------------------------ the wait
    def _start_timer(self) -> None:
        from PySide6 import QtCore

        if self._timer is None:
            self._timer = QtCore.QTimer()
            self._timer.setInterval(POLL_MS)
            self._timer.timeout.connect(self.poll)
        if not self._timer.isActive():
            self._timer.start()

    def poll(self, *, block: bool = False) -> None:
        """Try the journals the waiting edits need: journal a bone's edits whose lock came,
        refuse those whose wait is over (``block``: wait out each one's time now, as at close)."""
        from core.study import LockedError

        s = self._s
        for bone in list(self._waiting):
            w = self._waiting[bone]
            left = w.deadline - time.monotonic()
            held = s.study.journal_locked(s.trial_name, bone)
            if not held:
                try:
                    s.study.lock_journal(s.trial_name, bone, timeout=max(0.0, left) if block else 0.0,
                                         by=WINDOW_EDIT)
                except LockedError as exc:
                    w.exc = exc
                    if block or left <= 0:
                        del self._waiting[bone]
                        self._refuse(bone, exc, n=w.n, waited=HAND_EDIT_WAIT_S, again=False)
                    continue
            del self._waiting[bone]
            written = []
            try:
                for write, done in w.writes.values():
                    write()
                    written.append(done)
                self._saved(bone)
            except Exception as exc:  # e.g. a full disk: said, the rest not written
                if s.notify is None:
                    self._unsaved.add(bone)
                    raise
                self._failed(bone, len(w.writes) - len(written), exc)
            finally:
                if not held:
                    s.study.unlock_journal(s.trial_name, bone)
            for done in written:
                if done is not None:
                    done()
        if not self._waiting and self._timer is not None:
            self._timer.stop()
        if not block:
            self._run_after()

    def settle(self) -> list[str]:
        """Journal or refuse the edits still waiting, blocking for what is left of their wait (the
        window closes; what waited for them is dropped, said through ``notify``); returns the bones
        whose waiting edits were refused (said through ``notify``), so that the window can stay open
        for the message to be read."""
        dropped = [k.capitalize() for k in self._after]
        self._after.clear()
        if dropped and self._s.notify is not None:  # the status bar had said they would go ahead
            self._s.notify(f"{', '.join(dropped)}: not started (asked for while hand edits waited for "
                           "their journals; the window is closing)", None)
        bones = list(self._waiting)
        if bones:
            self.poll(block=True)
        return [b for b in bones if b in self._unsaved]

    def close(self) -> None:
        """Journal or refuse the edits still waiting (:meth:`settle`), and stop the timer (also
        where a refusal is raised: no tick may come after the study is closed)."""
        self._after.clear()
        try:
            if self._waiting:
                self.poll(block=True)
        finally:
            self._waiting.clear()
            if self._timer is not None:
                self._timer.stop()
                self._timer = None


def _has_app() -> bool:
    from PySide6 import QtCore

    return QtCore.QCoreApplication.instance() is not None
