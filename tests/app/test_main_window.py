"""The main window under a real X server (xvfb-run): menus, image panes, the 3D scene."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("PySide6", reason="the GUI extra (PySide6) is not installed")

from PySide6 import QtCore, QtGui

from app.panes import auto_window_level, to_qimage
from tests.app._helpers import main_window

# Waits end on the event itself (a signal, a state); the timeout is only the ceiling for an event
# that never comes, not a time the work is expected to take on a loaded machine.
HUNG_MS = 30 * 60_000


def _grey(qimage: QtGui.QImage, u: int, v: int) -> int:
    """Grey value of pixel (u, v) = (column, row)."""
    return QtGui.QColor(qimage.pixel(u, v)).red()


def _phantom_radiograph(rows: int, cols: int, shift: float) -> np.ndarray:
    """A float image in [0, 1] (1 = full fluence) with two dark 'bones'."""
    v, u = np.mgrid[0:rows, 0:cols].astype(np.float64)
    img = np.full((rows, cols), 0.9)
    img -= 0.5 * np.exp(-(((u - cols * (0.4 + shift)) / 40) ** 2 + ((v - rows * 0.5) / 120) ** 2))
    img -= 0.4 * np.exp(-(((u - cols * 0.65) / 30) ** 2 + ((v - rows * (0.45 + shift)) / 90) ** 2))
    return img.astype(np.float32)


@pytest.fixture
def window(qtbot):
    """A shown window with its 3-D scene, on the default device; closed (interactor too) after."""
    with main_window(qtbot, scene=True, device=None) as win:
        yield win


def test_to_qimage_window_level_mapping():
    img = np.array([[0.0, 0.25, 0.5], [0.75, 1.0, np.nan]])
    q = to_qimage(img, window=0.5, level=0.5)  # 0.25 -> 0, 0.5 -> 128, 0.75 -> 255
    assert (q.width(), q.height()) == (3, 2)
    assert [_grey(q, u, 0) for u in range(3)] == [0, 0, 128]
    assert [_grey(q, u, 1) for u in range(3)] == [255, 255, 0]
    assert auto_window_level(np.array([[2.0, 2.0]])) == (1.0, 2.0)  # flat image: unit window
    with pytest.raises(ValueError, match="window"):
        to_qimage(img, window=0.0, level=0.5)


@pytest.mark.gui
def test_window_opens_with_menus_shortcuts_and_status(window):
    assert window.windowTitle() == "Talus"
    menus = [a.text() for a in window.menuBar().actions()]
    assert menus == ["&File", "&Edit", "&View", "&Pose", "&Tracking", "&Review", "&Help"]
    assert window.quit_action.shortcut() == QtGui.QKeySequence("Ctrl+Q")
    assert window.open_demo_action.shortcut() == QtGui.QKeySequence("Ctrl+O")
    assert window.open_demo_action.text().startswith("&Open study")
    assert window.about_action in window.menuBar().actions()[-1].menu().actions()
    assert window.statusBar().currentMessage() == "Ready"
    # placeholders until a study is loaded: mid grey
    for pane in window.panes:
        assert pane.image is None
        assert _grey(pane.qimage(), 10, 10) == 128


@pytest.mark.gui
def test_ctrl_q_closes_the_window(window, qtbot):
    with qtbot.waitActive(window):  # shortcuts go to the active window
        window.activateWindow()
    qtbot.keyClick(window, QtCore.Qt.Key.Key_Q, QtCore.Qt.KeyboardModifier.ControlModifier)
    qtbot.waitUntil(lambda: not window.isVisible(), timeout=HUNG_MS)
    assert window.scene.plotter is None


@pytest.mark.gui
def test_image_roundtrips_window_level(window):
    pane = window.panes[0]
    img = np.zeros((40, 60), np.float32)  # [row, col]
    img[7, 23] = 1.0  # pixel (u, v) = (23, 7)
    img[8, 23] = 0.5
    pane.set_image(img, window=0.5, level=0.5)
    assert pane.image is img
    assert pane.window_level == (0.5, 0.5)
    q = pane.qimage()
    assert (q.width(), q.height()) == (60, 40)
    assert _grey(q, 23, 7) == 255 and _grey(q, 23, 8) == 128 and _grey(q, 0, 0) == 0

    seen = []
    pane.window_level_changed.connect(lambda w, lv: seen.append((w, lv)))
    pane.set_window_level(2.0, 1.0)
    assert pane.window_level == (2.0, 1.0) and seen == [(2.0, 1.0)]
    assert _grey(pane.qimage(), 23, 7) == 128
    pane.auto_window_level()
    assert pane.window_level == pytest.approx(auto_window_level(img))
    with pytest.raises(ValueError, match="2-D"):
        pane.set_image(np.zeros((2, 3, 5)))
    assert pane.image is img  # a rejected image leaves the pane as it was


@pytest.mark.gui
def test_scene_shows_lab_axes(window):
    actors = window.scene.plotter.renderer.actors
    assert {"lab-axis-red", "lab-axis-green", "lab-axis-blue"} <= set(actors)


@pytest.mark.gui
def test_open_demo_study_folder(window, tmp_path):
    for cam, shift in ((1, 0.0), (2, 0.05)):
        (tmp_path / f"cam{cam:02d}").mkdir()
        np.save(tmp_path / f"cam{cam:02d}" / "frame0000.npy", _phantom_radiograph(64, 80, shift))
        np.save(tmp_path / f"cam{cam:02d}" / "drr0000.npy", np.zeros((64, 80)))  # not fluoro
    window.open_demo_study(tmp_path)
    for cam, pane in enumerate(window.panes, start=1):
        assert pane.image.shape == (64, 80)
        assert pane.image.max() > 0
        assert f"cam{cam:02d}" in window.statusBar().currentMessage()
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ValueError, match="no camera images"):
        window.open_demo_study(empty)


@pytest.mark.gui
def test_open_study_listed_in_summary(window, tmp_path):
    tifffile = pytest.importorskip("tifffile")
    frames = {}
    for cam in ("cam01", "cam02"):
        (tmp_path / "frames" / cam).mkdir(parents=True)
        paths = []
        for i in range(2):
            img = (4095 * _phantom_radiograph(32, 48, 0.02 * i)).astype(np.uint16)  # 12-bit
            tifffile.imwrite(tmp_path / "frames" / cam / f"frame_{i:04d}.tif", img)
            paths.append(f"frames/{cam}/frame_{i:04d}.tif")
        frames[cam] = paths
    tifffile.imwrite(tmp_path / "flatfield_cam01.tif", np.zeros((32, 48), np.float32))
    (tmp_path / "summary.json").write_text(json.dumps({"files": {"frames": frames}}))
    window.open_demo_study(tmp_path)
    expected = tifffile.imread(tmp_path / "frames" / "cam02" / "frame_0000.tif")
    np.testing.assert_array_equal(window.panes[1].image, expected)
    assert "cam01: frames/cam01/frame_0000.tif" in window.statusBar().currentMessage()
    (tmp_path / "summary.json").write_text(json.dumps({"files": {"frames": {"cam01": []}}}))
    with pytest.raises(ValueError, match="no frames written"):
        window.open_demo_study(tmp_path)


@pytest.mark.gui
def test_screenshot(window, qtbot, tmp_path):
    window.resize(1280, 600)
    for k, pane in enumerate(window.panes):
        pane.set_image(_phantom_radiograph(480, 480, 0.05 * k))
    window.statusBar().showMessage("Screenshot test")
    window.scene.plotter.render()
    qtbot.wait(200)
    shot = window.screen().grabWindow(window.winId())  # includes the OpenGL scene
    assert not shot.isNull() and shot.width() >= 600
    targets = [tmp_path]
    if os.environ.get("TALUS_SCREENSHOT_DIR"):
        targets.append(Path(os.environ["TALUS_SCREENSHOT_DIR"]))
    for folder in targets:
        folder.mkdir(parents=True, exist_ok=True)
        assert shot.save(str(folder / "main_window.png"))
    assert QtGui.QImage(str(tmp_path / "main_window.png")).width() == shot.width()
