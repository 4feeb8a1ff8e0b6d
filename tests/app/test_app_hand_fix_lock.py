"""A hand fix of a bone the window has handed to a batch (its layer unlocked by hand), while the
batch's trajectory check holds the bone's journal: the fix waits for the check (up to
app.hand_edits.HAND_EDIT_WAIT_S, the window responsive meanwhile) and is journaled under the lock
for that append only, so the batch keeps the bone; a writer that keeps the journal refuses the fix
with a message naming it from the lock's holder line — each refusal said, one message updated —
and nothing reaches the event loop. A bone locked for the batch says so on K and Undo fix.
Through the window's menu actions, on the 96-px demo study."""

from __future__ import annotations

import types

import numpy as np
import pytest
from PySide6 import QtCore

from core.io.atomic import FileLock
from core.tracking.batch_journal import TRAJECTORY_CHECK
from tests.app._helpers import HUNG_JOB_MS, copy_study, main_window
from tests.app._helpers import menu_action as _action

pytestmark = pytest.mark.gui
BONE = "talus"
WAIT_MS = 5000  # for an edit's wait (1 s) to end, on a loaded machine


def _handed(qtbot, win, folder):
    """The window's study with the talus handed to a batch (as BatchPanel.start does: the journal let
    go) and its layer unlocked by hand, selected."""
    with qtbot.waitSignal(win.pool.finished, timeout=HUNG_JOB_MS):
        win.open_demo_study(folder)
    s, m = win.session, win.model
    s.study.unlock_journal(s.trial_name, BONE)
    m.select(BONE)
    return s, m, FileLock(folder / "results" / s.trial_name / "poses" / f".{BONE}.lock", purpose="pass",
                          by=TRAJECTORY_CHECK)


def _journaled(s, frame: int) -> np.ndarray:
    return s.study.trial(s.trial_name).poses(BONE)[frame]


def _refused(qtbot, win, s) -> list[str]:
    """The messages saying an edit is not saved, once the edits' wait is over."""
    qtbot.waitUntil(lambda: not s.edits.waiting(), timeout=WAIT_MS)
    return [t for i in range(win.messages.count()) if "not saved" in (t := win.messages.item(i).text())]


def test_a_hand_fix_waits_for_the_trajectory_check_and_leaves_the_bone_to_the_batch(qtbot, demo_study,
                                                                                   tmp_path):
    folder = copy_study(demo_study, tmp_path)
    with main_window(qtbot) as win:
        s, m, lock = _handed(qtbot, win, folder)
        f = m.current_frame
        lock.acquire()  # the batch's trajectory check reads and rewrites the journal...
        QtCore.QTimer.singleShot(300, lock.release)  # ... for a moment (the event loop lets it go:
        _action(win, "Move x+").trigger()  # D           never before the edit, whatever the load)
        moved = m.pose(BONE)
        assert s.edits.waiting(BONE)
        qtbot.waitUntil(lambda: not s.edits.waiting(), timeout=WAIT_MS)
        np.testing.assert_allclose(_journaled(s, f), moved)  # saved once the check let go
        assert not s.study.journal_locked(s.trial_name, BONE)  # the batch keeps the bone
        assert lock.acquire(timeout=0.0) and lock.release() is None  # nothing else holds it


def test_a_hand_fix_the_batch_keeps_out_is_said_not_saved(qtbot, demo_study, tmp_path):
    folder = copy_study(demo_study, tmp_path)
    with main_window(qtbot) as win:
        s, m, lock = _handed(qtbot, win, folder)
        f = m.current_frame
        before = _journaled(s, f)
        n = win.messages.count()
        lock.acquire()  # held past the wait (here by this process: as the window's own batch)
        try:
            _action(win, "Move x+").trigger()
            _action(win, "Move x+").trigger()  # the same wait: joins it
            said = _refused(qtbot, win, s)
            assert len(said) == 1 and win.messages.count() == n + 1, said
            assert said[0].startswith(f"{BONE}: 2 edits are not saved (the last at ")
            assert said[0].endswith(", after 1 s): its journal is being written by this window's batch (its "
                                    "trajectory check). Edit it again once that is over; a batch gives its "
                                    "bones back to the window when it ends.")
        finally:
            lock.release()
        np.testing.assert_array_equal(_journaled(s, f), before)


def test_k_and_undo_fix_on_a_bone_locked_for_the_batch_say_so(qtbot, demo_study, tmp_path):
    folder = copy_study(demo_study, tmp_path)
    with main_window(qtbot) as win:
        s, m, _ = _handed(qtbot, win, folder)
        m.set_layer_property(BONE, "locked", True)  # as BatchPanel.start locks a handed bone
        shown = []
        win.show_error = lambda title, text: shown.append(text)  # the dialog _guard shows
        win.review.keyframe_action.trigger()  # K, no batch running: locked by hand
        win.tracking.batch = types.SimpleNamespace(running=True, _bones=[BONE])  # the batch has it
        try:
            win.review.keyframe_action.trigger()
            win.review.undo_fix_action.trigger()
        finally:
            win.tracking.batch = None
        assert shown[0] == f"bone: {BONE} is locked (Layers: untick Locked to edit it)"
        for text in shown[1:]:
            assert text.startswith(f"bone: {BONE} is being written by the batch (its tasks track it, then "
                                   "its trajectory check judges the frames); the window takes it back")
        assert len(shown) == 3 and not s.study.journal_locked(s.trial_name, BONE)


def test_a_refused_fix_leaves_the_frame_table_as_the_journal_has_it(qtbot, demo_study, tmp_path):
    """The table showed a refused fix 'edited' (its update ran whatever the journal got); it keeps
    the frame's journal status (tracked) until a fix is saved."""
    from app.review import EDITED, TRACKED
    from core.study import Study

    folder = copy_study(demo_study, tmp_path)
    with Study.open(folder, mode="w") as st:  # frame 1 tracked
        tr = st.trial("walk")
        tr.record_pose(BONE, 1, tr.poses(BONE)[0], score=0.9, tracking={"flags": []})
    with main_window(qtbot) as win:
        s, m, lock = _handed(qtbot, win, folder)
        m.set_frame(1)
        b = win.review.data.bones.index(BONE)
        assert win.review.data.status[b, 1] == TRACKED
        lock.acquire()  # a writer that keeps the journal past the wait
        try:
            _action(win, "Move x+").trigger()
            assert win.review.data.status[b, 1] == TRACKED and s.unsaved(BONE)  # waiting: not edited
            _refused(qtbot, win, s)
        finally:
            lock.release()
        assert win.review.data.status[b, 1] == TRACKED and s.unsaved(BONE)  # not saved: not edited
        assert s.study.trial(s.trial_name).results(BONE).records[1].kind == "tracked"
        s.edits._refused.clear()  # past the burst's quiet time
        _action(win, "Move x+").trigger()  # the journal free: saved, edited
        assert win.review.data.status[b, 1] == EDITED and not s.unsaved(BONE)
        lock.acquire()  # held for a moment: edited once the fix is saved
        QtCore.QTimer.singleShot(300, lock.release)  # a thread's timer could let go before the edit
        _action(win, "Move x+").trigger()
        assert s.edits.waiting(BONE)
        win.review.data.status[b, 1] = TRACKED  # (to see it marked again)
        qtbot.waitUntil(lambda: not s.unsaved(BONE), timeout=WAIT_MS)
        assert win.review.data.status[b, 1] == EDITED


def test_the_window_holds_no_journal_a_batch_beside_it_wants(qtbot, demo_study, tmp_path):
    """A 'talus batch' of range tasks on the window's trial (here a second Study handle, as a task's
    process would open it): the window took every bone's journal at open, between two of the batch's
    writes, and kept it, so the batch's next task waited 60 s and failed. The window now takes a
    journal for its edit only: the batch locks every bone while the window is open, a fix waits for
    it and is refused while the batch keeps it, and once it lets go the fix is saved and the batch can
    lock the bone again. A second window on the trial still opens read-only (the window lock)."""
    from core.study import LockedError, Study

    folder = copy_study(demo_study, tmp_path)
    with main_window(qtbot) as win:
        with qtbot.waitSignal(win.pool.finished, timeout=HUNG_JOB_MS):
            win.open_demo_study(folder)
        s, m = win.session, win.model
        assert s.writable
        bones = list(s.study.trial(s.trial_name).bones)
        assert not any(s.study.journal_locked(s.trial_name, b) for b in bones)
        m.select(BONE)
        f = m.current_frame
        with Study.open(folder, mode="w") as batch:
            for b in bones:
                batch.lock_journal("walk", b)  # the batch's task: not refused
            _action(win, "Move x+").trigger()  # waits HAND_EDIT_WAIT_S, then refused
            said = _refused(qtbot, win, s)  # this process holds it, but not as the window's batch
            assert said and said[-1].startswith(
                f"{BONE}: the edit is not saved (waited 1 s): its journal is being written by another handle "
                "of the study in this program since "), said
            assert " (what holds it is not recorded). Edit it again" in said[-1]
            batch.unlock_journal("walk", BONE)  # the task is done with the talus
            s.edits._refused.clear()
            _action(win, "Move x+").trigger()
            np.testing.assert_allclose(_journaled(s, f), m.pose(BONE))  # saved
            assert not s.study.journal_locked(s.trial_name, BONE)
            batch.lock_journal("walk", BONE)  # the batch's next task takes it at once
        with pytest.raises(LockedError, match="edited in another window"):
            from app.session import open_study

            open_study(folder)


def test_undo_of_an_edit_of_a_bone_locked_for_a_batch_writes_nothing(qtbot, demo_study, tmp_path):
    """Edit > Undo (Ctrl+Z) of an edit made before the bone was locked (handed to a batch, or tracked
    by the window's tracking job) applied it to the locked layer, and the pose signal journaled it
    as a hand pose between the batch's appends (a keyframe a range task could overwrite). The undo
    is refused while the bone is locked (said in the window, nothing written), and done once the
    lock is lifted; Redo likewise."""
    folder = copy_study(demo_study, tmp_path)
    with main_window(qtbot) as win:
        s, m, _ = _handed(qtbot, win, folder)
        f = m.current_frame
        before = m.pose(BONE).copy()
        _action(win, "Move x+").trigger()
        moved = m.pose(BONE).copy()
        journal = folder / "results" / s.trial_name / "poses" / f"{BONE}.jsonl"
        size = journal.stat().st_size
        m.set_layer_property(BONE, "locked", True)  # as BatchPanel.start locks a handed bone
        shown = []
        win.show_error = lambda title, text: shown.append(text)  # the dialog _guard shows
        _action(win, "&Undo").trigger()
        assert shown == [f"bone: {BONE} is locked: its edit at frame {f} is not undone"]
        np.testing.assert_array_equal(m.pose(BONE), moved)  # the model keeps the edit ...
        assert journal.stat().st_size == size  # ... nothing written
        m.set_layer_property(BONE, "locked", False)  # the batch ended
        _action(win, "&Undo").trigger()
        np.testing.assert_allclose(m.pose(BONE), before)
        np.testing.assert_allclose(_journaled(s, f), before)
        m.set_layer_property(BONE, "locked", True)
        _action(win, "&Redo").trigger()
        assert shown[-1] == f"bone: {BONE} is locked: its edit at frame {f} is not redone"
        np.testing.assert_allclose(_journaled(s, f), before)
        assert m.can_redo and not s.study.journal_locked(s.trial_name, BONE)
