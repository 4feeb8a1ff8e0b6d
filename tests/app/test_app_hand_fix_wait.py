"""A hand fix waiting for a bone's journal (held by a batch beside the window) keeps the window
responsive, each refused edit says why (one message updated, the status bar again), and the holder
is named from the lock's holder line. Through the window's menu actions, on the 96-px demo study.

Set ``TALUS_SCREENSHOTS=DIR`` to keep ``hand_fix_refused.png`` (the window with the refusal)."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from PySide6 import QtCore

from core.io.atomic import FileLock
from core.tracking.batch_journal import RANGE_APPEND, TRAJECTORY_CHECK
from tests.app._helpers import HUNG_JOB_MS, copy_study, main_window
from tests.app._helpers import menu_action as _action

pytestmark = pytest.mark.gui
BONE = "talus"
WAIT_MS = 5000  # for an edit's wait (1 s) to end, on a loaded machine
ROOT = Path(__file__).resolve().parents[2]


def _handed(qtbot, win, folder, by: str = TRAJECTORY_CHECK):
    """The window's study with the talus handed to a batch (its journal let go) and unlocked by
    hand, selected; and a lock of the talus's journal as ``by`` would take it."""
    with qtbot.waitSignal(win.pool.finished, timeout=HUNG_JOB_MS):
        win.open_demo_study(folder)
    s, m = win.session, win.model
    s.study.unlock_journal(s.trial_name, BONE)
    m.select(BONE)
    path = folder / "results" / s.trial_name / "poses" / f".{BONE}.lock"
    return s, m, FileLock(path, purpose="the test", by=by)


def _journaled(s, frame: int) -> np.ndarray:
    return s.study.trial(s.trial_name).poses(BONE)[frame]


def _last(win) -> str:
    return win.messages.item(win.messages.count() - 1).text()


def test_the_window_stays_responsive_while_a_fix_waits_for_the_journal(qtbot, demo_study, tmp_path,
                                                                        monkeypatch):
    """The wait (up to 1 s) ran on the GUI thread: the window froze. The edit now waits off it: the
    trigger returns with the edit waiting, a timer fires during the wait, it is journaled once the lock
    comes; K likewise (the keyframe set once it is journaled). A batch asked for meanwhile starts
    once the edit is journaled (the status bar saying it waits)."""
    import core.tracking.batch as core_batch

    folder = copy_study(demo_study, tmp_path)
    batches = []

    def run_batch(tasks, settings=None, **kw):  # recorded, not run: the journal as the batch finds it
        batches.append((tasks, _journaled(s, f)))
        recs = [dict(key=t.key, study=t.study, trial=t.trial, bones=list(t.bones), status="complete",
                     seconds=0.0) for t in tasks]
        return core_batch.summarize(tasks, recs, [], wall_s=0.0, workers=0)

    monkeypatch.setattr(core_batch, "run_batch", run_batch)
    with main_window(qtbot) as win:
        s, m, lock = _handed(qtbot, win, folder)
        f = m.current_frame
        before = _journaled(s, f)
        fired = []
        lock.acquire()  # the trajectory check, for 0.6 s
        QtCore.QTimer.singleShot(600, lock.release)
        QtCore.QTimer.singleShot(150, lambda: fired.append(s.edits.waiting(BONE)))
        _action(win, "Move x+").trigger()
        # waiting, not refused: a wait on the GUI thread could not have seen the lock go (the event
        # loop lets it go) and would have ended refused after 1 s
        assert s.edits.waiting(BONE) and s.unsaved(BONE)
        np.testing.assert_array_equal(_journaled(s, f), before)  # not yet
        from app.batch_panel import BatchPanel

        panel = BatchPanel(win)
        panel.start(trials=[s.trial_name], bones=[BONE])  # it could overtake the batch: it waits
        assert not batches and win.statusBar().currentMessage().startswith(
            "The batch starts once the hand edits waiting for their journals are saved")
        with qtbot.waitSignal(panel.finished, timeout=WAIT_MS):
            pass
        assert fired == [True]  # the event loop ran while the edit waited
        assert [t.key for t in batches[0][0]] == [f"study/{s.trial_name}/{BONE}"]
        np.testing.assert_allclose(batches[0][1], m.pose(BONE))  # journaled before the batch began
        np.testing.assert_allclose(_journaled(s, f), m.pose(BONE))
        assert not s.unsaved(BONE) and not s.study.journal_locked(s.trial_name, BONE)
        m.set_frame(f + 1)  # K on a frame with no record, while the check holds the journal
        lock.acquire()
        QtCore.QTimer.singleShot(300, lock.release)
        win.review.keyframe_action.trigger()
        assert f + 1 not in m.layers[m.index(BONE)].keyframes  # not journaled yet
        qtbot.waitUntil(lambda: not s.edits.waiting(), timeout=WAIT_MS)
        assert f + 1 in m.layers[m.index(BONE)].keyframes
        assert _last(win) == f"{BONE} frame {f + 1}: keyframe set"
        np.testing.assert_allclose(_journaled(s, f + 1), m.pose(BONE, f + 1))


def test_each_refused_edit_says_why_in_one_message(qtbot, demo_study, tmp_path):
    """A second edit within 2 s of a refused one was refused without a word. Each refusal is said:
    the first's message updated with the count (the status bar shows it again), a new message only
    where another came between."""
    folder = copy_study(demo_study, tmp_path)
    with main_window(qtbot, size=(1280, 720)) as win:
        s, m, lock = _handed(qtbot, win, folder)
        f = m.current_frame
        before = _journaled(s, f)
        lock.acquire()  # held past every wait
        try:
            n = win.messages.count()
            _action(win, "Move x+").trigger()
            qtbot.waitUntil(lambda: win.messages.count() == n + 1, timeout=WAIT_MS)
            first = _last(win)
            assert first == (f"{BONE}: the edit is not saved (waited 1 s): its journal is being written by "
                             "this window's batch (its trajectory check). Edit it again once that is over; a "
                             "batch gives its bones back to the window when it ends.")
            assert win.statusBar().currentMessage() == first
            for k in (2, 3):  # the rest of the drag: refused at once, each said
                win.statusBar().clearMessage()
                _action(win, "Move x+").trigger()
                assert win.messages.count() == n + 1  # the one message, updated
                said = _last(win)
                assert said.startswith(f"{BONE}: {k} edits are not saved (the last at ")
                assert said.endswith(", not waited for: within 2 s of a refusal): its journal is being "
                                     "written by this window's batch (its trajectory check). Edit it again "
                                     "once that is over; a batch gives its bones back to the window when it "
                                     "ends.")
                assert win.statusBar().currentMessage() == said
            folder_shots = os.environ.get("TALUS_SCREENSHOTS")
            if folder_shots:
                Path(folder_shots).mkdir(parents=True, exist_ok=True)
                assert win.grab().save(str(Path(folder_shots) / "hand_fix_refused.png"))
            win.notify("something else")
            _action(win, "Move x+").trigger()  # after another message: a new one
            assert win.messages.count() == n + 3 and _last(win).startswith(f"{BONE}: 4 edits are not saved")
        finally:
            lock.release()
        np.testing.assert_array_equal(_journaled(s, f), before)
        s.edits._refused.clear()  # past the quiet time: the journal free, saved
        _action(win, "Move x+").trigger()
        np.testing.assert_allclose(_journaled(s, f), m.pose(BONE))


HOLD = """
import sys, time
from core.io.atomic import FileLock
lock = FileLock(sys.argv[1], purpose="bone 'talus'", by=sys.argv[2]).acquire()
print("ready", flush=True)
sys.stdin.readline()
"""


def test_the_refusal_names_the_holder_from_its_lock(qtbot, demo_study, tmp_path):
    """It said "this window's batch" for any holder in the window's process: another process's
    holder is named with its pid, host and what holds it (``by``), a handle of this process that is
    not the batch as such."""
    folder = copy_study(demo_study, tmp_path)
    with main_window(qtbot) as win:
        s, _, lock = _handed(qtbot, win, folder, by="")
        env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
        child = subprocess.Popen([sys.executable, "-c", textwrap.dedent(HOLD), str(lock.path), RANGE_APPEND],
                                 stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env)
        try:
            assert child.stdout.readline().strip() == "ready"
            _action(win, "Move x+").trigger()
            qtbot.waitUntil(lambda: not s.edits.waiting(), timeout=WAIT_MS)
            said = _last(win)
            assert said.startswith(f"{BONE}: the edit is not saved (waited 1 s): its journal is being "
                                   f"written by process {child.pid} on {socket.gethostname()} since "), said
            assert said.endswith(f" ({RANGE_APPEND}). Edit it again once that is over; a batch gives its "
                                 "bones back to the window when it ends.")
        finally:
            child.communicate("\n", timeout=30)
        s.edits._refused.clear()
        with lock:  # a holder in this process that says nothing of itself: not "this window's batch"
            _action(win, "Move x+").trigger()
            qtbot.waitUntil(lambda: not s.edits.waiting(), timeout=WAIT_MS)
        assert _last(win).startswith(f"{BONE}: the edit is not saved (waited 1 s): its journal is being "
                                     "written by another handle of the study in this program since ")
        assert " (what holds it is not recorded). Edit it again" in _last(win)
