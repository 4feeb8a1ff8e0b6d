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
