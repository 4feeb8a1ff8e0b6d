"""A batch of frame ranges from the window (Tracking → Track in batch…, one task per range): once
every range of a trial's bone is done the trajectory check judges them together, and the window's
Batch dock and messages give the flags after it — the counts per trial's bone, and the frames it
changed (the first 10 named, the rest counted) — as its own tracking names a run's flagged frames.
The registration is replaced by smooth synthetic poses (no rendering); the scheduler is an
in-process Dask cluster of one thread worker.

Set ``TALUS_SCREENSHOTS=DIR`` to keep a screenshot of the messages after the batch."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from PySide6 import QtCore

from app.tracking_actions import MAX_FLAG_MESSAGES
from core.study import Study
from tests.app._helpers import FAST_TRACKING, copy_study, main_window

pytestmark = pytest.mark.gui
distributed = pytest.importorskip("distributed")

HUNG_MS = 20 * 60_000  # the ceiling for a batch that never ends, not a time it is expected to take
BONE = "talus"
LEFT = QtCore.Qt.MouseButton.LeftButton


@pytest.fixture(scope="module")
def keyed_folder(tmp_path_factory):
    """A 30-frame 48-px demo study whose talus has one hand-set keyframe, frame 12: two ranges (a
    copy of the one the process built, :func:`tests.core.tracking.demo_walk.copy_keyed`)."""
    from tests.core.tracking.demo_walk import copy_keyed

    return copy_keyed(tmp_path_factory, tmp_path_factory.mktemp("batchpass") / "study", BONE)


@pytest.fixture(scope="module")
def scheduler():
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  dashboard_address=":0") as cluster:
        yield cluster.scheduler_address


@pytest.fixture
def window(qtbot, keyed_folder, tmp_path):
    with main_window(qtbot, size=(1100, 760)) as win:
        win.open_study(copy_study(keyed_folder, tmp_path))
        win.tracking.options = FAST_TRACKING
        yield win


def _texts(window) -> list[str]:
    return [window.messages.item(i).text() for i in range(window.messages.count())]


def _click_box(qtbot, box) -> None:
    qtbot.mouseClick(box, LEFT, pos=QtCore.QPoint(8, box.height() // 2))


def test_the_window_gives_the_flags_after_the_trajectory_check_over_the_ranges(window, qtbot, scheduler,
                                                                                monkeypatch):
    from core.tracking import trial
    from core.tracking.results import FrameResult
    from tests.core.tracking.test_flags_post import _track

    # frame 10 0.2 deg off: the range 12-0, run first, does not flag it alone; the trial does
    P = _track(n=30, off=(10, 0.0, 0.2))
    from functools import partial

    from core.tracking import flags_post

    # the trial's ends cut (ends=False): with flags_ends the range flags frame 10 itself
    monkeypatch.setattr(flags_post, "trajectory_review", partial(flags_post.trajectory_review, ends=False))
    monkeypatch.setattr(trial, "track_frame", lambda run, f, imgs, fr, todo, state, skip: {
        0: FrameResult(BONE, f, P[f], 0.8, 10, 0.0, True)})
    window.model.select(BONE)
    window.tracking.batch_action.trigger()
    dlg = window.tracking.batch.dialog
    qtbot.waitExposed(dlg)
    _click_box(qtbot, dlg.ranges_box)
    _click_box(qtbot, dlg.scheduler_radio)
    qtbot.keyClicks(dlg.scheduler_edit, scheduler)
    assert dlg.choice()["ranges"] and dlg.choice()["bones"] == [BONE] and dlg.choice()["trials"] == ["walk"]
    panel = window.tracking.batch
    with qtbot.waitSignal(panel.finished, timeout=HUNG_MS) as done:
        qtbot.mouseClick(dlg.start_button, LEFT)
    s = done.args[0]
    assert s.get("status") == "complete", s
    (entry,) = s["trajectory_pass"]
    assert entry["changed"] == [[BONE, 10]]
    # the dock: each range's count after the check (12-0's own check flagged nothing)
    assert panel.task_state("study/walk/talus:12-0")[0] == "complete, 1 flagged"
    assert panel.task_state("study/walk/talus:12-29")[0] == "complete"
    texts = _texts(window)
    assert ("Batch: study/walk/talus: 1 flagged for review after the trajectory check over its 2 ranges "
            "together (30 bone-frames judged, 1 off the trajectory, 1 changed by the check)") in texts
    assert any(t.startswith("Batch: study/walk/talus: talus frame 10: off the trajectory") for t in texts)
    assert not any("frames flagged for review" in t for t in texts)  # no per-range count: the trial's
    # the review state shown is the journal's after the check
    assert [f for _, f in window.review.data.flagged()] == [10]
    with Study.open(window.session.folder) as st:
        assert [d["frame"] for d in st.read_report("tracking", "walk.talus.12-0")["flagged"]] == [10]
    folder = os.environ.get("TALUS_SCREENSHOTS")
    if folder:
        window.resize(1500, 800)
        window.messages_dock.raise_()
        window.resizeDocks([window.messages_dock], [900], QtCore.Qt.Orientation.Horizontal)
        qtbot.wait(100)
        Path(folder).mkdir(parents=True, exist_ok=True)
        assert window.grab().save(str(Path(folder) / "batch_trajectory_pass.png"))


def _recorded_batch(monkeypatch, entry_of, flagged: int) -> None:
    """``run_batch`` replaced: nothing run, every task complete with ``flagged`` frames flagged, the
    trajectory pass's one entry ``entry_of(tasks)``."""
    import core.tracking.batch as core_batch

    def run_batch(tasks, settings=None, *, on_event=None, **kw):
        recs = [dict(key=t.key, study=t.study, trial=t.trial, bones=list(t.bones), status="complete",
                     seconds=0.0, flagged=flagged) for t in tasks]
        entry = entry_of(tasks)
        return dict(core_batch.summarize(tasks, core_batch.final_records(recs, [entry]), [], wall_s=0.1,
                                         workers=1), trajectory_pass=[entry])

    monkeypatch.setattr(core_batch, "run_batch", run_batch)


def test_the_window_names_ten_changed_frames_and_counts_the_rest(window, qtbot, monkeypatch):
    """A long trial's check changes many frames: the first 10 named, the rest counted; a range
    task the check did not judge keeps its own count (the batch is recorded, not run)."""
    from core.tracking.flags_post import FLAG

    def entry_of(tasks):
        ranges = [t.key for t in tasks if t.bones == (BONE,)]
        return {"key": "study/walk/talus", "ranges": ranges, "judged": 30, "flagged": 13,
                "review_flagged": {BONE: 14},
                "changes": [{"bone": BONE, "frame": f, "flags": [f"{FLAG} (test)"]} for f in range(13)],
                "tasks_flagged": dict.fromkeys(ranges, 7)}

    _recorded_batch(monkeypatch, entry_of, flagged=4)
    window.model.select(BONE)
    window.tracking.batch_action.trigger()
    dlg, panel = window.tracking.batch.dialog, window.tracking.batch
    qtbot.waitExposed(dlg)
    _click_box(qtbot, dlg.ranges_box)
    _click_box(qtbot, dlg.bone_boxes["calcaneus"])
    # one task per bone (the talus's ranges judged together, the calcaneus's range alone)
    dlg.mode_combo.setFocus()
    while dlg.mode_combo.currentData() != "split":
        qtbot.keyClick(dlg.mode_combo, QtCore.Qt.Key.Key_Down)
    assert dlg.choice()["mode"] == "sequential" and dlg.choice()["split_bones"]
    assert dlg.choice()["bones"] == [BONE, "calcaneus"]
    with qtbot.waitSignal(panel.finished, timeout=HUNG_MS):
        qtbot.mouseClick(dlg.start_button, LEFT)
    assert panel.task_state("study/walk/talus:12-0")[0] == "complete, 7 flagged"
    texts = [t for t in _texts(window) if "flagged" in t or "frame" in t or "changed" in t]
    named = [t for t in texts if t.startswith("Batch: study/walk/talus: talus frame ")]
    assert len(named) == MAX_FLAG_MESSAGES and named[0].endswith(f"frame 0: {FLAG} (test)")
    assert ("Batch: study/walk/talus: ... and 3 more frames changed by the check: the review panel "
            "lists the flagged ones") in texts
    assert any(t.startswith("Batch: study/walk/talus: 14 flagged for review after") and "13 changed" in t
               for t in texts)
    assert "Batch: study/walk/calcaneus:0-29: 4 frames flagged for review" in texts  # not judged here
    assert not any(t.startswith("Batch: study/walk/talus:12-") and "flagged for review" in t for t in texts)



def test_a_failed_merge_of_the_shared_keyframe_is_an_error_message(window, qtbot, monkeypatch):
    """The pass's ``shared_error`` (the trajectory check off, the merge of the keyframe the two ranges
    share failed): its lines are error messages, as a failed check's, in the words talus batch prints
    (the batch is recorded, not run)."""
    from core.tracking.batch_pass import pass_messages
    from tests.app.test_cli_batch import SHARED_ERROR

    _recorded_batch(monkeypatch, lambda tasks: dict(SHARED_ERROR, ranges=[t.key for t in tasks]), flagged=0)
    seen, notify = [], window.notify

    def recorded(text, *, error=False, tag=None):
        seen.append((text, error))
        notify(text, error=error, tag=tag)

    monkeypatch.setattr(window, "notify", recorded)
    window.model.select(BONE)
    window.tracking.batch_action.trigger()
    dlg, panel = window.tracking.batch.dialog, window.tracking.batch
    qtbot.waitExposed(dlg)
    _click_box(qtbot, dlg.ranges_box)
    assert dlg.choice()["bones"] == [BONE] and dlg.choice()["ranges"]
    with qtbot.waitSignal(panel.finished, timeout=HUNG_MS) as done:
        qtbot.mouseClick(dlg.start_button, LEFT)
    (entry,) = done.args[0]["trajectory_pass"]
    lines = pass_messages(entry, limit=MAX_FLAG_MESSAGES)
    assert len(lines) == 2 and "not merged (LockedError: walk.talus is being written" in lines[1]
    assert "after journaling 1 of 2 (talus frame 12)" in lines[1]
    for line in lines:  # each line shown, as an error
        assert (f"Batch: {line}", True) in seen
        assert f"Batch: {line}" in _texts(window)
    assert not any(error for text, error in seen if not text.startswith("Batch: study/walk/talus: "))
    assert window.messages_dock.isVisible()
    folder = os.environ.get("TALUS_SCREENSHOTS")
    if folder:
        window.resize(1500, 800)
        window.resizeDocks([window.messages_dock], [900], QtCore.Qt.Orientation.Horizontal)
        qtbot.wait(100)
        Path(folder).mkdir(parents=True, exist_ok=True)
        assert window.grab().save(str(Path(folder) / "batch_shared_error.png"))
