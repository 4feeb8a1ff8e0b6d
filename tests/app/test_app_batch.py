"""Tracking in batch from the window (Tracking → Track in batch…): the dialog driven by clicks hands
a bone of two trials to a Dask scheduler, the Batch dock follows each task's frames, the window
shows the journal's poses when the batch is done, and Cancel stops a batch and gives the window its
bones back. The scheduler is an in-process Dask cluster of one thread worker (no process start-up).

Set ``TALUS_SCREENSHOTS=DIR`` to keep screenshots of the dialog and of the batch in progress."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from PySide6 import QtCore

from app.main_window import MainWindow
from core.study import Study
from tests.app._helpers import FAST_TRACKING, copy_study, main_window, pause_after_first_frame
from tests.core.tracking.batch_helpers import save_flat_calibration

pytestmark = pytest.mark.gui
distributed = pytest.importorskip("distributed")

# the ceiling for a batch that never ends, not a time the work is expected to take
HUNG_MS = 20 * 60_000
BONE = "talus"
LEFT = QtCore.Qt.MouseButton.LeftButton


def _shot(widget, name: str) -> None:
    folder = os.environ.get("TALUS_SCREENSHOTS")
    if folder:
        Path(folder).mkdir(parents=True, exist_ok=True)
        assert widget.grab().save(str(Path(folder) / name))


@pytest.fixture(scope="module")
def demo_folder(tmp_path_factory):
    """A 2-frame 48-px demo study with a second trial (walk2) on the same frames and keyframes."""
    from core.synthetic import make_demo_study

    out = tmp_path_factory.mktemp("appbatch") / "study"
    make_demo_study(out, n_frames=2, pixels=48, spacing=3.0, tissue_spacing=6.0, device="cpu",
                    calibration_session=False)
    with Study.open(out, mode="w") as st:
        walk = st.manifest["trials"]["walk"]
        bones = list(st.trial("walk").bones)
        st.add_trial("walk2", [st.path(v["path"]) for v in walk["views"]], calibration=walk["calibration"],
                     bones=bones, bit_depth=walk["views"][0]["bit_depth"])
        for b in bones:
            st.trial("walk2").record_pose(b, 0, st.trial("walk").poses(b)[0])
    return out


@pytest.fixture(scope="module")
def scheduler():
    """An in-process Dask cluster: one worker thread running one task at a time."""
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                  dashboard_address=":0") as cluster:
        yield cluster.scheduler_address


@pytest.fixture
def window(qtbot, demo_folder, tmp_path):
    with main_window(qtbot, size=(1100, 760)) as win:
        win.open_study(copy_study(demo_folder, tmp_path))
        win.tracking.options = FAST_TRACKING  # the batch's plumbing is tested, not the tracker
        yield win


def _click_box(qtbot, box) -> None:
    """Click a check box or radio button on its indicator (its centre may lie past its text)."""
    qtbot.mouseClick(box, LEFT, pos=QtCore.QPoint(8, box.height() // 2))


def _fill_dialog(window, qtbot, scheduler):
    window.model.select(BONE)
    window.tracking.batch_action.trigger()
    dlg = window.tracking.batch.dialog
    qtbot.waitExposed(dlg)
    assert dlg.trial_boxes["walk"].isChecked() and not dlg.trial_boxes["walk2"].isChecked()
    assert [b for b, box in dlg.bone_boxes.items() if box.isChecked()] == [BONE]
    _click_box(qtbot, dlg.trial_boxes["walk2"])
    _click_box(qtbot, dlg.scheduler_radio)
    assert not dlg.start_button.isEnabled() and "address" in dlg.note.text()  # no address yet
    qtbot.keyClicks(dlg.scheduler_edit, scheduler)
    assert dlg.start_button.isEnabled()
    # the mode of the window's tracking options (FAST_TRACKING's: one bone after another)
    assert dlg.choice() == {"trials": ["walk", "walk2"], "bones": [BONE], "mode": "sequential",
                            "split_bones": False, "ranges": False, "workers": None, "scheduler": scheduler}
    return dlg


def test_track_in_batch_from_the_window(window, qtbot, scheduler):
    dlg = _fill_dialog(window, qtbot, scheduler)
    _shot(dlg, "batch_dialog_scheduler.png")
    panel = window.tracking.batch
    frames = []
    panel.event.connect(lambda e: e["kind"] == "frame" and frames.append(e))
    with qtbot.waitSignal(panel.finished, timeout=HUNG_MS) as done:
        qtbot.mouseClick(dlg.start_button, LEFT)
        assert panel.running and window.model.layers[window.model.index(BONE)].locked
        assert not window.session.study.journal_locked("walk", BONE)  # handed to the workers
        with pytest.raises(ValueError, match="batch"):
            window.tracking.start([BONE])  # no second tracker on the study meanwhile
        qtbot.waitUntil(lambda: bool(frames) or not panel.running, timeout=HUNG_MS)
        if panel.running:
            _shot(window, "batch_progress.png")
    s = done.args[0]
    assert s.get("status") == "complete", s
    assert [r["key"] for r in s["task_records"]] == ["study/walk/talus", "study/walk2/talus"]
    assert s["frames_tracked"] == 4
    assert {(e["key"], e["done"]) for e in frames} >= {("study/walk/talus", 2), ("study/walk2/talus", 2)}
    state, shown = panel.task_state("study/walk2/talus")
    assert state.startswith("complete") and shown == "2/2"
    assert "2/2 tasks complete" in panel.where.text()
    _shot(window, "batch_done.png")
    # the window has its bone back (its journal free: taken per edit) and shows the journal's poses
    assert not window.session.study.journal_locked("walk", BONE)
    assert not window.model.layers[window.model.index(BONE)].locked
    with Study.open(window.session.folder) as st:
        for t in ("walk", "walk2"):
            assert st.read_report("tracking", f"{t}.{BONE}")["summary"]["status"] == "complete"
        poses = st.trial("walk").poses(BONE)
    assert np.isfinite(poses).all()
    np.testing.assert_allclose(window.model.pose(BONE, 1), poses[1])
    texts = [window.messages.item(i).text() for i in range(window.messages.count())]
    assert any("study/walk2/talus complete" in t for t in texts)


def test_a_batch_can_be_cancelled(window, qtbot, scheduler, monkeypatch):
    # the first task waits after its first frame until the cancel has reached it (the batch's
    # Dask stop event), so the cancel always comes while walk is tracking and before walk2 starts
    pause_after_first_frame(monkeypatch, until_cancelled=True)
    dlg = _fill_dialog(window, qtbot, scheduler)
    _click_box(qtbot, dlg.ranges_box)  # one task per range between keyframes: here frame 0 on
    panel = window.tracking.batch
    started = []
    panel.event.connect(lambda e: e["kind"] == "start" and started.append(e))
    box = window.layers.locked  # the Layers dock's Locked box of the selected bone (the talus)
    with qtbot.waitSignal(panel.finished, timeout=HUNG_MS) as done:
        qtbot.mouseClick(dlg.start_button, LEFT)
        qtbot.waitUntil(lambda: bool(started) or not panel.running, timeout=HUNG_MS)
        # the batch has the talus: its lock cannot be lifted (a fix could be overwritten by a range
        # task that has not reached that frame); it let the user untick it
        assert box.isChecked() and not box.isEnabled()
        assert "tracked by the batch (Batch dock) until it ends or is cancelled" in box.toolTip()
        _click_box(qtbot, box)
        assert box.isChecked() and window.model.layers[window.model.index(BONE)].locked
        _shot(window.layers_dock, "layers_locked_by_batch.png")
        qtbot.mouseClick(panel.cancel_button, LEFT)
    s = done.args[0]
    assert s.get("status") == "cancelled", s
    assert [r["key"] for r in s["task_records"]] == ["study/walk/talus:0-1", "study/walk2/talus:0-1"]
    assert [r["status"] for r in s["task_records"]][1] == "cancelled"  # walk2 never started
    assert not panel.running and not window.session.study.journal_locked("walk", BONE)
    assert not window.model.layers[window.model.index(BONE)].locked
    assert box.isEnabled() and not box.isChecked() and "batch" not in box.toolTip()  # given back
    _click_box(qtbot, box)  # and lockable by hand again
    assert window.model.layers[window.model.index(BONE)].locked
    texts = [window.messages.item(i).text() for i in range(window.messages.count())]
    assert any("Batch cancelled" in t for t in texts)


@pytest.fixture
def calibrated_window(qtbot, demo_folder, tmp_path, monkeypatch):
    """A window on the demo whose walk has a saved flatfield calibration (walk2 not), with the
    window's default tracking options; the batch's tasks are recorded, not run."""
    import core.tracking.batch as core_batch

    folder = shutil.copytree(demo_folder, tmp_path / "study")
    save_flat_calibration(folder, ["walk"])
    win = MainWindow(device="cpu", create_scene_on_show=False)
    qtbot.addWidget(win)
    win.resize(1100, 760)
    win.show()
    win.open_study(folder)
    win.planned = []

    def run_batch(tasks, settings=None, *, on_event=None, **kw):
        win.planned.append([t.key for t in tasks])
        recs = [dict(key=t.key, study=t.study, trial=t.trial, bones=list(t.bones), status="complete",
                     seconds=0.0) for t in tasks]
        return core_batch.summarize(tasks, recs, [], wall_s=0.1, workers=1)

    monkeypatch.setattr(core_batch, "run_batch", run_batch)
    yield win
    win.close()


def _open_dialog(window, qtbot):
    window.model.select(BONE)
    window.tracking.batch_action.trigger()
    dlg = window.tracking.batch.dialog
    qtbot.waitExposed(dlg)
    return dlg


def _pick(qtbot, combo, value) -> None:
    """Choose ``value`` in a combo box from the keyboard, as a user does (arrow keys)."""
    target = combo.findData(value)
    assert target >= 0, value
    while combo.currentIndex() != target:
        key = QtCore.Qt.Key.Key_Down if combo.currentIndex() < target else QtCore.Qt.Key.Key_Up
        qtbot.keyClick(combo, key)


def _start(window, qtbot, dlg) -> list[str]:
    panel = window.tracking.batch
    with qtbot.waitSignal(panel.finished, timeout=HUNG_MS) as done:
        qtbot.mouseClick(dlg.start_button, LEFT)
    assert done.args[0]["status"] == "complete", done.args[0]
    return window.planned[-1]


def test_batch_mode_tracks_as_talus_track_by_default(calibrated_window, qtbot):
    win = calibrated_window
    dlg = _open_dialog(win, qtbot)
    # the default, as talus track and the window's own tracking: jointly where the frames are
    # flatfield-corrected (walk), one task per bone elsewhere (walk2)
    assert dlg.mode_combo.currentData() == "auto"
    _click_box(qtbot, dlg.bone_boxes["calcaneus"])
    _click_box(qtbot, dlg.trial_boxes["walk2"])
    assert dlg.choice()["mode"] == "auto" and dlg.choice()["bones"] == [BONE, "calcaneus"]
    _shot(dlg, "batch_dialog.png")  # resources/screenshots/batch_dialog.png
    assert _start(win, qtbot, dlg) == ["study/walk/talus+calcaneus", "study/walk2/talus",
                                       "study/walk2/calcaneus"]
    texts = [win.messages.item(i).text() for i in range(win.messages.count())]
    assert any("bones tracked jointly in walk; one task per bone in walk2" in t for t in texts)
    # sequential, picked from the list: the trial's bones one after another in one task, as talus
    # track --mode sequential; one task per bone (--split-bones) the entry after it
    dlg = _open_dialog(win, qtbot)
    _click_box(qtbot, dlg.bone_boxes["calcaneus"])
    _pick(qtbot, dlg.mode_combo, "sequential")
    assert dlg.choice()["mode"] == "sequential" and not dlg.choice()["split_bones"]
    assert _start(win, qtbot, dlg) == ["study/walk/talus+calcaneus"]
    assert win.tracking.batch.task_neighbours("study/walk/talus+calcaneus")[0] == "sequential"
    dlg = _open_dialog(win, qtbot)
    _click_box(qtbot, dlg.bone_boxes["calcaneus"])
    _pick(qtbot, dlg.mode_combo, "split")
    assert dlg.choice()["mode"] == "sequential" and dlg.choice()["split_bones"]
    assert _start(win, qtbot, dlg) == ["study/walk/talus", "study/walk/calcaneus"]
    assert win.tracking.batch.task_neighbours("study/walk/talus")[0] == "one bone"
    # the dialog starts from the mode of the window's tracking options
    from app.tracking_options import options_from_choices

    win.tracking.options = options_from_choices(mode="joint")
    dlg = _open_dialog(win, qtbot)
    assert dlg.mode_combo.currentData() == "joint"
    qtbot.mouseClick(dlg.cancel_button, LEFT)
    assert not dlg.isVisible() and not win.tracking.batch.running


def test_batch_with_the_final_stage_needs_flatfield_corrected_trials(calibrated_window, qtbot, monkeypatch):
    """The window's Tracking options with the likelihood final stage: a batch over a trial without
    a flatfield correction (walk2) is refused naming it, nothing handed over; over the calibrated
    walk every task's options end with the stage (the tasks are recorded, not run)."""
    import core.tracking.batch as core_batch
    from app.tracking_options import options_from_choices

    win = calibrated_window
    errors = []
    monkeypatch.setattr(win, "show_error", lambda title, text: errors.append(text))
    recorded, settings = core_batch.run_batch, []

    def run_batch(tasks, s=None, **kw):
        settings.append(s)
        return recorded(tasks, s, **kw)

    monkeypatch.setattr(core_batch, "run_batch", run_batch)
    win.tracking.options = options_from_choices(final="likelihood")
    dlg = _open_dialog(win, qtbot)
    _click_box(qtbot, dlg.trial_boxes["walk2"])
    qtbot.mouseClick(dlg.start_button, LEFT)
    assert errors and "trial 'walk2'" in errors[-1] and "not flatfield-corrected" in errors[-1]
    assert "'walk'" not in errors[-1]
    assert not win.tracking.batch.running and not win.model.layers[win.model.index(BONE)].locked
    assert win.planned == []
    dlg = _open_dialog(win, qtbot)
    assert _start(win, qtbot, dlg) == [f"study/walk/{BONE}"]
    opts = settings[-1].tracking_options(joint=False)
    assert opts.refine_likelihood and opts.registration.final == "likelihood"


def test_the_batch_dock_shows_what_each_task_subtracted(qtbot, demo_folder, scheduler, tmp_path):
    """A calibrated study (walk's frames flatfield-corrected), the talus and calcaneus handed to a
    batch by clicks: *Sequential* is one task whose searches subtracted the other bone (auto resolved
    on), which its row's Neighbours cell says once it ends; *One task per bone* says of each task that
    it searched alone, its tooltip why (nothing to subtract in a task of one bone)."""
    folder = copy_study(demo_folder, tmp_path)
    save_flat_calibration(folder, ["walk"])
    with main_window(qtbot, size=(1100, 760)) as win:
        win.open_study(folder)
        win.tracking.options = FAST_TRACKING  # sequential, sequential_subtract auto
        for mode, keys in (("sequential", ["study/walk/talus+calcaneus"]),
                           ("split", ["study/walk/talus", "study/walk/calcaneus"])):
            dlg = _open_dialog(win, qtbot)
            _click_box(qtbot, dlg.bone_boxes["calcaneus"])
            _pick(qtbot, dlg.mode_combo, mode)
            _click_box(qtbot, dlg.scheduler_radio)
            qtbot.keyClicks(dlg.scheduler_edit, scheduler)
            panel = win.tracking.batch
            with qtbot.waitSignal(panel.finished, timeout=HUNG_MS) as done:
                qtbot.mouseClick(dlg.start_button, LEFT)
                planned = "sequential" if mode == "sequential" else "one bone"
                assert [panel.task_neighbours(k)[0] for k in keys] == [planned] * len(keys)
            s = done.args[0]
            assert s.get("status") == "complete", s
            assert [r["key"] for r in s["task_records"]] == keys
            if mode == "sequential":
                (rec,) = s["task_records"]
                assert rec["sequential_subtract"] is True and rec["frames_tracked"] == 4
                assert panel.task_neighbours(keys[0]) == (
                    "sequential, subtracted", "Each bone searched with the other bones' DRRs subtracted")
                _shot(win, "batch_sequential_subtract.png")  # resources/screenshots/
            else:  # the frames are in the journal already (resumed); each task of one bone says why
                for k in keys:
                    assert panel.task_neighbours(k) == (
                        "sequential, not subtracted", "on, but no other bone tracked: nothing to subtract")
        texts = [win.messages.item(i).text() for i in range(win.messages.count())]
        assert any("bones tracked one after another in walk" in t for t in texts)


def test_batch_tasks_get_the_joint_restart(calibrated_window, qtbot, monkeypatch):
    """The window's Tracking options with *Restart joint rounds from the prediction*: the joint task
    of the calibrated walk gets ``joint_restart`` (as talus batch --joint-restart; recorded, not run)."""
    import core.tracking.batch as core_batch
    from app.tracking_options import options_from_choices

    win = calibrated_window
    recorded, settings = core_batch.run_batch, []

    def run_batch(tasks, s=None, **kw):
        settings.append(s)
        return recorded(tasks, s, **kw)

    monkeypatch.setattr(core_batch, "run_batch", run_batch)
    win.tracking.options = options_from_choices(joint_restart=True)
    dlg = _open_dialog(win, qtbot)
    _click_box(qtbot, dlg.bone_boxes["calcaneus"])
    assert _start(win, qtbot, dlg) == ["study/walk/talus+calcaneus"]
    assert settings[-1].tracking_options(joint=True).joint_restart is True
    # the Batch dock's row says so (planned: nothing ran in this recorded batch)
    key = "study/walk/talus+calcaneus"
    text, tip = win.tracking.batch.task_neighbours(key)
    assert text == "joint, 2 rounds, restart" and "from its prediction" in tip and "2 rounds a frame" in tip


def test_the_batch_dock_shows_the_joint_restart(calibrated_window, qtbot, monkeypatch):
    """A joint task's *Neighbours* cell says whether its rounds after the first started from the
    prediction: the task's end event (as run_task's: its joint_restart and note) says what ran as soon
    as the task ends, the note of a task resumed with the other choice in the tooltip; its record (the
    summary's) then says the same; without the option the cell is plain *joint*."""
    import core.tracking.batch as core_batch
    from app.tracking_options import options_from_choices

    win = calibrated_window
    recorded = core_batch.run_batch
    key = "study/walk/talus+calcaneus"
    note = "frames 0-1 resumed from a run without joint_restart"

    def run_batch(tasks, s=None, *, on_event=None, **kw):
        restart = s.tracking_options(joint=True).joint_restart
        on_event({"kind": "end", "key": key, "status": "complete", "seconds": 0.0, "mode": "joint",
                  "sequential_subtract": None, "sequential_subtract_note": None,
                  "joint_rounds": 1 + restart, "joint_restart": restart,
                  "joint_restart_note": note if restart else None})
        summary = recorded(tasks, s, on_event=on_event, **kw)
        for r in summary["task_records"]:
            r.update(mode="joint", joint_rounds=1 + restart, joint_restart=restart,
                     joint_restart_note=note if restart else None)
        return summary

    monkeypatch.setattr(core_batch, "run_batch", run_batch)
    seen = []
    for restart, text in ((True, "joint, subtracted, 2 rounds, restart"), (False, "joint, subtracted")):
        win.tracking.options = options_from_choices(joint_restart=restart)
        dlg = _open_dialog(win, qtbot)
        panel = win.tracking.batch  # made with the first dialog
        if not seen:
            panel.event.connect(lambda e, p=panel: seen.append(p.task_neighbours(key))
                                if e.get("kind") == "end" else None)
            seen.append(None)
        _click_box(qtbot, dlg.bone_boxes["calcaneus"])
        assert _start(win, qtbot, dlg) == [key]
        assert seen[-1][0] == text  # from the end event, its note too (the batch's choice has none)
        assert (note in seen[-1][1]) is restart
        shown, tip = panel.task_neighbours(key)  # from the record
        assert shown == text and (("from its prediction" in tip and note in tip) if restart
                                  else "prediction" not in tip)
