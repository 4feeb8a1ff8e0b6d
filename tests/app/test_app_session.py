"""Studies in the window: edits are journalled at once, survive a crash, locks, missing files."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from app.main_window import MainWindow
from app.session import MissingFilesError, open_study
from core.study import Study
from tests.app._helpers import copy_study


@pytest.fixture
def demo_folder(demo_study):
    """The shared demo study (tests/app/conftest.py), read only."""
    return demo_study


@pytest.fixture
def folder(demo_study, tmp_path):
    return copy_study(demo_study, tmp_path)


def _moved(T, dx):
    T = T.copy()
    T[0, 3] += dx
    return T


def test_edits_are_journalled_and_reopen_where_they_were(folder):
    s = open_study(folder)
    m = s.model
    assert 0 in m.layers[1].keyframes  # the demo records frame 0 of every bone
    T = _moved(m.pose("talus"), 3.0)
    m.set_frame(2)
    m.set_pose("talus", T)
    s.close()
    with Study.open(folder) as st:  # on disk, without the window
        np.testing.assert_allclose(st.trial("walk").poses("talus")[2], T)
    s2 = open_study(folder)
    try:
        np.testing.assert_allclose(s2.model.pose("talus", 2), T)
        assert s2.model.layers[1].keyframes == {0, 2}
        assert not s2.recovered
        # frame 1 (never recorded) starts from its nearest recorded neighbour
        assert np.isfinite(s2.model.pose("talus", 1)).all()
    finally:
        s2.close()


def test_a_crash_loses_nothing_and_is_reported(folder):
    s = open_study(folder)
    T = _moved(s.model.pose("calcaneus"), -2.0)
    s.model.set_pose("calcaneus", T)
    s.study.close()  # the process dies: the OS drops the lock, the marker stays
    s2 = open_study(folder)
    try:
        assert s2.recovered
        np.testing.assert_allclose(s2.model.pose("calcaneus", 0), T)
    finally:
        s2.close()


@pytest.mark.gui
def test_second_writer_gets_a_read_only_view(folder, qtbot):
    first = open_study(folder)
    try:
        win = MainWindow(device="cpu", create_scene_on_show=False)
        qtbot.addWidget(win)
        win.open_study(folder)
        assert not win.session.writable
        assert "read-only" in win.messages.item(win.messages.count() - 1).text()
        win.close()
    finally:
        first.close()


def test_missing_files_are_listed(folder):
    shutil.rmtree(folder / "frames" / "cam02")
    with pytest.raises(MissingFilesError, match="missing") as info:
        open_study(folder)
    assert any("cam02" in str(path) for _, path in info.value.missing)


@pytest.mark.gui
def test_new_study_from_imports_opens_in_the_window(demo_folder, tmp_path, qtbot):
    """New study -> calibration -> CT volume -> trial, through the import actions the menus call."""
    win = MainWindow(device="cpu", create_scene_on_show=False)
    qtbot.addWidget(win)
    imp = win.importer
    imp.create(tmp_path / "new")
    with pytest.raises(ValueError, match="calibration"):
        imp.import_trial()
    imp.add_calibration("day1", [demo_folder / "rig" / "cam01.txt", demo_folder / "rig" / "cam02.txt"])
    imp.add_volume("talus", demo_folder / "volumes" / "talus.mha")
    with pytest.raises(ValueError, match="voxel_size_mm"):
        imp.add_volume("tibia", demo_folder / "volumes" / "tibia.tif")  # TIFF without voxel size
    imp.add_trial("walk", [demo_folder / "frames" / "cam01", demo_folder / "frames" / "cam02"])
    assert win.model is not None and [b.name for b in win.model.layers] == ["talus"]
    assert win.model.n_frames == 3 and win.panes[0].image.shape == (96, 96)
    win.close()


@pytest.mark.gui
def test_missing_files_can_be_relocated_from_the_window(folder, tmp_path, qtbot, monkeypatch):
    from PySide6 import QtWidgets

    moved = tmp_path / "moved_cam02"
    shutil.move(folder / "frames" / "cam02", moved)
    monkeypatch.setattr(QtWidgets.QMessageBox, "question",
                        lambda *a, **k: QtWidgets.QMessageBox.StandardButton.Yes)
    monkeypatch.setattr(QtWidgets.QFileDialog, "getExistingDirectory", lambda *a, **k: str(moved))
    win = MainWindow(device="cpu", create_scene_on_show=False)
    qtbot.addWidget(win)
    win._open_checked(str(folder))
    assert win.model is not None and win.panes[1].image is not None
    assert any("now" in win.messages.item(i).text() for i in range(win.messages.count()))
    win.close()


def _two_trials(folder):
    """The demo study with a second trial, walk2 (the same frames), posed at frame 0."""
    with Study.open(folder, mode="w") as st:
        st.add_trial("walk2", [folder / "frames" / "cam01", folder / "frames" / "cam02"],
                     calibration="rig", bones=["talus", "calcaneus"], bit_depth=12)
        walk = st.trial("walk")
        for b in ("talus", "calcaneus"):
            st.trial("walk2").record_pose(b, 0, walk.poses(b)[0])
    return folder


def test_windows_on_two_trials_do_not_warn_a_crash_still_does(folder):
    """The 'not closed cleanly' marker was one per study and the window lock one per trial: a second
    window on another trial found the first one's marker and reported a crash. The marker is per
    trial: neither window warns, each close removes its own, a crash is still reported — for its
    trial only."""
    _two_trials(folder)
    first = open_study(folder, trial="walk")
    second = open_study(folder, trial="walk2")
    assert second.writable and not first.recovered and not second.recovered
    second.close()
    again = open_study(folder, trial="walk2")  # the first window still open: its marker not ours
    assert not again.recovered
    again.close()
    first.study.close()  # the first window's process dies: its marker stays
    walk2 = open_study(folder, trial="walk2")
    try:
        assert not walk2.recovered
    finally:
        walk2.close()
    walk = open_study(folder, trial="walk")
    try:
        assert walk.recovered
    finally:
        walk.close()
    walk = open_study(folder, trial="walk")
    walk.close()
    assert not walk.recovered and not list((folder / "results").rglob(".session-open"))


WINDOW = """
import sys
from PySide6 import QtCore
app = QtCore.QCoreApplication([])
from app.session import open_study
s = open_study(sys.argv[1], trial=sys.argv[2])
print("recovered" if s.recovered else "clean", flush=True)
if sys.stdin.readline().strip() == "close":
    s.close()
print("closed", flush=True)
sys.stdin.readline()
"""


def test_two_processes_on_two_trials_and_a_killed_one(folder):
    """Two processes (as two windows), one per trial: neither warns; the one killed is reported when
    its trial opens again, the other's trial is not."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    _two_trials(folder)
    root = Path(__file__).resolve().parents[2]
    env = dict(os.environ, PYTHONPATH=str(root) + os.pathsep + os.environ.get("PYTHONPATH", ""))

    def window(trial):
        return subprocess.Popen([sys.executable, "-c", WINDOW, str(folder), trial], stdin=subprocess.PIPE,
                                stdout=subprocess.PIPE, text=True, env=env)

    a, b = window("walk"), window("walk2")
    try:
        assert a.stdout.readline().strip() == "clean"
        assert b.stdout.readline().strip() == "clean"
        a.stdin.write("close\n")
        a.stdin.flush()
        assert a.stdout.readline().strip() == "closed"
        b.kill()  # a crash
        b.wait(timeout=30)
    finally:
        for p in (a, b):
            if p.poll() is None:
                p.kill()
            p.wait(timeout=30)
            for stream in (p.stdin, p.stdout):
                stream.close()
    for trial, crashed in (("walk", False), ("walk2", True)):
        s = open_study(folder, trial=trial)
        try:
            assert s.recovered == crashed, trial
        finally:
            s.close()


def test_an_older_versions_study_wide_marker_counts_once(folder):
    """results/.session-open, left by an older version that did not close: reported, then gone."""
    (folder / "results").mkdir(exist_ok=True)
    (folder / "results" / ".session-open").write_text("open\n", encoding="utf-8")
    s = open_study(folder)
    s.close()
    assert s.recovered and not (folder / "results" / ".session-open").exists()
    s = open_study(folder)
    s.close()
    assert not s.recovered


def test_an_older_window_still_open_on_another_trial_keeps_its_marker(folder):
    """The study-wide marker of an older version's window open on another trial (its window lock,
    or an older one's journals, held): not a crash, and not removed under it."""
    from core.io.atomic import FileLock

    _two_trials(folder)
    legacy = folder / "results" / ".session-open"
    legacy.write_text("open\n", encoding="utf-8")
    for held in (folder / "results" / "walk2" / ".window.lock", folder / "results" / "walk2" / "poses" /
                 ".talus.lock"):
        held.parent.mkdir(parents=True, exist_ok=True)
        with FileLock(held, purpose="an older window on walk2"):
            s = open_study(folder, trial="walk")
            s.close()
            assert not s.recovered and legacy.exists(), held
    s = open_study(folder, trial="walk")  # that window gone: its marker says it did not close
    s.close()
    assert s.recovered and not legacy.exists()
