"""Hand edits queued while a bone's journal is held by another writer (a batch's trajectory check):
what the user does during the wait, through the window's menu actions, on the 96-px demo study.

* *Undo fix* while the bone's edit waits waits for it (the journal it reads would lack the edit;
  it was refused, to be asked again), the status bar saying so, and undoes the fix of the frame it
  was asked at once the edit is journaled (two asked at two frames: both); *Track all bones*
  likewise starts the tracking job once the edit is journaled. An *Undo fix* that waits, then a
  move of the same frame: the move, journaled after it, stays in the model (the fix's undo put the
  tracked pose back over it: model and journal disagreed).
* Edit → Undo of a waiting move: the journal ends as the model.
* Two bones waiting at once: both journaled once the locks come.
* Closing the window while an edit waits: saved where the lock is free by then; refused, the
  window stays open so that the message is read, and closes the second time; what was asked for
  meanwhile (tracking, *Undo fix*) is not started, and the messages say so.

The locks are let go by a Qt timer (not a thread's clock), so the edit waits whatever the load.
``TALUS_SCREENSHOTS=DIR`` keeps ``undo_fix_waits.png`` (the status bar while Undo fix waits)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from PySide6 import QtCore

from core.io.atomic import FileLock
from core.study import Study
from core.tracking.batch_journal import TRAJECTORY_CHECK
from tests.app._helpers import HUNG_JOB_MS, copy_study, job_ends, main_window
from tests.app._helpers import menu_action as _action

pytestmark = pytest.mark.gui
BONE = "talus"
WAIT_MS = 5000  # for an edit's wait (1 s) to end, on a loaded machine


def _lock(folder, trial: str, bone: str) -> FileLock:
    path = folder / "results" / trial / "poses" / f".{bone}.lock"
    return FileLock(path, purpose="pass", by=TRAJECTORY_CHECK)


def _hold_for_a_moment(folder, s, bone: str = BONE) -> None:
    """Take ``bone``'s journal lock of the open trial as another writer would, let go 300 ms later (on
    the event loop), so that an edit made meanwhile waits."""
    lock = _lock(folder, s.trial_name, bone).acquire()
    QtCore.QTimer.singleShot(300, lambda: lock.release())  # a lambda keeps the lock alive; a bound method not


def _open(qtbot, win, folder, bones=(BONE,)):
    """The study open, ``bones`` handed to a batch (their journals let go), the first selected."""
    with qtbot.waitSignal(win.pool.finished, timeout=HUNG_JOB_MS):
        win.open_demo_study(folder)
    s, m = win.session, win.model
    for b in bones:
        s.study.unlock_journal(s.trial_name, b)
    m.select(bones[0])
    return s, m


def _journal(s, bone: str = BONE):
    return s.study.trial(s.trial_name).poses(bone)


def _fixed_frame_1(folder) -> np.ndarray:
    """Frame 1 of the talus tracked, then fixed by hand; returns the tracked pose."""
    with Study.open(folder, mode="w") as st:
        tr = st.trial("walk")
        tracked = tr.poses(BONE)[0]
        tr.record_pose(BONE, 1, tracked, score=0.9, tracking={"flags": []})
        fix = tracked.copy()
        fix[0, 3] += 2.0
        tr.record_pose(BONE, 1, fix)
    return tracked


def _texts(win) -> list[str]:
    return [win.messages.item(i).text() for i in range(win.messages.count())]


def test_undo_fix_while_an_edit_waits_waits_for_it(qtbot, demo_study, tmp_path, shown_errors):
    folder = copy_study(demo_study, tmp_path)
    tracked = _fixed_frame_1(folder)
    with main_window(qtbot) as win:
        s, m = _open(qtbot, win, folder)
        m.set_frame(1)
        _hold_for_a_moment(folder, s)
        _action(win, "Move x+").trigger()
        assert s.edits.waiting(BONE)
        win.review.undo_fix_action.trigger()
        assert win.statusBar().currentMessage().startswith(
            f"Undo fix of {BONE} at frame 1: waiting for its edit to be saved")
        folder_shots = os.environ.get("TALUS_SCREENSHOTS")
        if folder_shots:  # the status bar while it waits
            Path(folder_shots).mkdir(parents=True, exist_ok=True)
            assert win.statusBar().grab().save(str(Path(folder_shots) / "undo_fix_waits.png"))
        m.set_frame(0)  # moving on meanwhile: the undo is of the frame it was asked at
        done = f"{BONE} frame 1: fix undone (tracking result restored)"
        qtbot.waitUntil(lambda: done in _texts(win), timeout=WAIT_MS)
        assert not shown_errors and not s.edits.waiting()
        recs = s.study.trial(s.trial_name).results(BONE).essential_records()[1]
        assert recs[-1].kind == "tracked"  # the move journaled, then the fix (the move) undone
        np.testing.assert_allclose(_journal(s)[1], tracked)
        np.testing.assert_allclose(m.pose(BONE, 1), tracked)


def test_tracking_started_while_an_edit_waits_starts_once_it_is_saved(qtbot, demo_study, tmp_path,
                                                                       monkeypatch):
    import core.tracking.from_study as from_study

    folder = copy_study(demo_study, tmp_path)
    seen = []

    def fake_track_study(study, trial, bones, frames, **kw):  # the journal as the tracker finds it
        seen.append((list(bones), study.trial(trial).poses(BONE)[f].copy()))
        return None, {"summary": {"status": "complete", "results": 0}, "stopped": {}, "flagged": []}

    monkeypatch.setattr(from_study, "track_study", fake_track_study)
    with main_window(qtbot) as win:
        s, m = _open(qtbot, win, folder)
        f = m.current_frame
        _hold_for_a_moment(folder, s)
        _action(win, "Move x+").trigger()
        moved = m.pose(BONE)
        with job_ends(qtbot, win.pool, "tracking"):
            _action(win, "Track &all bones").trigger()
            assert s.edits.waiting(BONE) and not seen  # not started yet
            assert win.statusBar().currentMessage().startswith(
                "Tracking starts once the hand edits waiting for their journals are saved")
        assert [b for b, _ in seen] == [[layer.name for layer in m.layers]]
        np.testing.assert_allclose(seen[0][1], moved)  # the edit journaled before the tracker started


def test_two_undo_fixes_asked_while_an_edit_waits_both_run(qtbot, demo_study, tmp_path, shown_errors):
    """*Undo fix* at frame 1, then at frame 2, while the bone's edit waits: both wait and both run
    once it is journaled (the second used to replace the first, which never ran though the status
    bar had said it would)."""
    folder = copy_study(demo_study, tmp_path)
    tracked = _fixed_frame_1(folder)
    with Study.open(folder, mode="w") as st:  # frame 2 fixed by hand too
        tr = st.trial("walk")
        tr.record_pose(BONE, 2, tracked, score=0.9, tracking={"flags": []})
        fix = tracked.copy()
        fix[1, 3] += 2.0
        tr.record_pose(BONE, 2, fix)
    with main_window(qtbot) as win:
        s, m = _open(qtbot, win, folder)
        m.set_frame(1)
        _hold_for_a_moment(folder, s)
        _action(win, "Move x+").trigger()
        assert s.edits.waiting(BONE)
        win.review.undo_fix_action.trigger()
        m.set_frame(2)
        win.review.undo_fix_action.trigger()
        assert s.edits.waiting(BONE)
        done = [f"{BONE} frame {f}: fix undone (tracking result restored)" for f in (1, 2)]
        qtbot.waitUntil(lambda: all(d in _texts(win) for d in done), timeout=WAIT_MS)
        assert not shown_errors
        for f in (1, 2):
            assert s.study.trial(s.trial_name).results(BONE).essential_records()[f][-1].kind == "tracked"
            np.testing.assert_allclose(_journal(s)[f], tracked)
            np.testing.assert_allclose(m.pose(BONE, f), tracked)


def test_a_move_made_while_undo_fix_waits_stays(qtbot, demo_study, tmp_path):
    folder = copy_study(demo_study, tmp_path)
    tracked = _fixed_frame_1(folder)
    with main_window(qtbot) as win:
        s, m = _open(qtbot, win, folder)
        m.set_frame(1)
        _hold_for_a_moment(folder, s)
        win.review.undo_fix_action.trigger()  # waits
        assert s.edits.waiting(BONE)
        _action(win, "Move x+").trigger()  # the same frame, behind it
        moved = m.pose(BONE)
        qtbot.waitUntil(lambda: not s.edits.waiting(), timeout=WAIT_MS)
        kinds = [r.kind for r in s.study.trial(s.trial_name).results(BONE).essential_records()[1]]
        assert kinds[-2:] == ["tracked", "hand"]  # the fix undone, then the move
        np.testing.assert_allclose(_journal(s)[1], moved)
        np.testing.assert_allclose(m.pose(BONE, 1), moved)  # not the tracked pose over it
        assert not np.allclose(moved, tracked)
        texts = [win.messages.item(i).text() for i in range(win.messages.count())]
        assert f"{BONE} frame 1: fix undone (tracking result restored), then the edit made while it waited " \
               "saved after it" in texts


def test_edit_undo_of_a_waiting_move_and_two_bones_waiting(qtbot, demo_study, tmp_path):
    folder = copy_study(demo_study, tmp_path)
    with main_window(qtbot) as win:
        s, m = _open(qtbot, win, folder, bones=(BONE, "calcaneus"))
        f = m.current_frame
        before = _journal(s)[f]
        locks = [_lock(folder, s.trial_name, b).acquire() for b in (BONE, "calcaneus")]
        QtCore.QTimer.singleShot(300, locks[0].release)
        QtCore.QTimer.singleShot(400, locks[1].release)
        _action(win, "Move x+").trigger()
        win.undo_action.trigger()  # Edit → Undo of the waiting move
        np.testing.assert_allclose(m.pose(BONE), before)
        m.select("calcaneus")
        _action(win, "Move x+").trigger()
        calcaneus = m.pose("calcaneus")
        assert s.edits.waiting(BONE) and s.edits.waiting("calcaneus")
        qtbot.waitUntil(lambda: not s.edits.waiting(), timeout=WAIT_MS)
        np.testing.assert_allclose(_journal(s)[f], before)  # as the model: the move undone
        np.testing.assert_allclose(_journal(s, "calcaneus")[f], calcaneus)
        assert not s.unsaved(BONE) and not s.unsaved("calcaneus")
        assert not any(s.study.journal_locked(s.trial_name, b) for b in (BONE, "calcaneus"))


def test_closing_while_an_edit_waits(qtbot, demo_study, tmp_path):
    folder = copy_study(demo_study, tmp_path)
    with main_window(qtbot) as win:  # the lock comes within the wait: saved at close
        s, m = _open(qtbot, win, folder)
        lock = _lock(folder, s.trial_name, BONE).acquire()
        _action(win, "Move x+").trigger()
        moved = m.pose(BONE)
        assert s.edits.waiting(BONE)
        lock.release()  # no event loop between this and the close: the edit still waits
        assert s.edits.waiting(BONE)
        win.close()
        assert not win.isVisible() and s._closed
        assert s.edits._timer is None  # no tick after the study is closed
    with Study.open(folder) as st:
        np.testing.assert_allclose(st.trial("walk").poses(BONE)[m.current_frame], moved)

    folder = copy_study(demo_study, tmp_path / "again")
    with main_window(qtbot) as win:  # held past the wait: refused, said, the window stays open
        s, m = _open(qtbot, win, folder)
        before = _journal(s)[m.current_frame]
        lock = _lock(folder, s.trial_name, BONE).acquire()
        try:
            _action(win, "Move x+").trigger()
            assert s.edits.waiting(BONE)
            _action(win, "Track &all bones").trigger()  # waits for the edit; dropped by the close
            win.review.undo_fix_action.trigger()
            win.close()
            assert win.isVisible() and not s._closed and not s.edits.waiting()
            texts = [win.messages.item(i).text() for i in range(win.messages.count())]
            assert texts[-3] == (f"Tracking, Undo fix of {BONE} at frame {m.current_frame}: not started "
                                 "(asked for while hand edits waited for their journals; the window is "
                                 "closing)")
            assert texts[-2].startswith(f"{BONE}: the edit is not saved (waited 1 s): its journal is being "
                                        "written by this window's batch (its trajectory check)")
            assert texts[-1] == (f"The window stays open: the last edits of {BONE} are not saved (the "
                                 "message above says why). Close it again to leave without them.")
            win.close()  # the second time: closed
            assert not win.isVisible() and s._closed
        finally:
            lock.release()
        with Study.open(folder) as st:
            np.testing.assert_array_equal(st.trial("walk").poses(BONE)[m.current_frame], before)


def test_a_new_burst_of_refusals_is_a_new_message(qtbot, demo_study, tmp_path, monkeypatch):
    """Past the quiet time a refusal (after its wait) overwrote the last burst's message when that
    was the last one ('2 edits are not saved' gone from the log); it is a message of its own."""
    import app.hand_edits

    folder = copy_study(demo_study, tmp_path)
    with main_window(qtbot) as win:
        s, _ = _open(qtbot, win, folder)
        lock = _lock(folder, s.trial_name, BONE).acquire()
        try:
            n = win.messages.count()
            _action(win, "Move x+").trigger()
            qtbot.waitUntil(lambda: not s.edits.waiting(), timeout=WAIT_MS)
            _action(win, "Move x+").trigger()  # within the quiet time: the burst's message updated
            assert win.messages.count() == n + 1
            monkeypatch.setattr(app.hand_edits, "REFUSED_QUIET_S", 0.0)  # the quiet time over
            _action(win, "Move x+").trigger()
            assert s.edits.waiting(BONE)
            qtbot.waitUntil(lambda: not s.edits.waiting(), timeout=WAIT_MS)
        finally:
            lock.release()
        texts = [win.messages.item(i).text() for i in range(n, win.messages.count())]
        assert len(texts) == 2, texts
        assert texts[0].startswith(f"{BONE}: 2 edits are not saved (the last at ")
        assert texts[1].startswith(f"{BONE}: the edit is not saved (waited 1 s)")


def test_a_write_that_fails_is_said_not_raised(qtbot, demo_study, tmp_path, monkeypatch):
    """A move journaled at once whose write failed (a full disk) raised into the event loop from the
    model's signal, unseen; it is said in Messages, and the bone's edit is not saved."""
    from core.study.trial import Trial

    folder = copy_study(demo_study, tmp_path)
    with main_window(qtbot) as win:
        s, m = _open(qtbot, win, folder)
        before = _journal(s)[m.current_frame]

        def full(self, *a, **k):
            raise OSError(28, "No space left on device")

        monkeypatch.setattr(Trial, "record_pose", full)
        _action(win, "Move x+").trigger()
        assert win.messages.item(win.messages.count() - 1).text() == (
            f"{BONE}: the edit is not saved: [Errno 28] No space left on device")
        assert s.unsaved(BONE) and not s.study.journal_locked(s.trial_name, BONE)
        monkeypatch.undo()
        np.testing.assert_array_equal(_journal(s)[m.current_frame], before)
        _action(win, "Move x+").trigger()  # the disk free again: saved
        np.testing.assert_allclose(_journal(s)[m.current_frame], m.pose(BONE))
        assert not s.unsaved(BONE)
