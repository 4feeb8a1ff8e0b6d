"""The Plots dock draws a pose that stands alone: the pose of a one-frame trial, and a trial's only
pose at its first or last frame (a dash across the frame; a σ band's bar). On a one-frame trial
nothing was drawn: the curves painted only when two frames or more were exposed.

``TALUS_SCREENSHOTS=DIR`` keeps ``plots_one_frame_trial.png`` (the Pose page of a one-frame
trial)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from PySide6 import QtCore, QtGui, QtWidgets

from tests.app._helpers import copy_study, job_ends, main_window

pytestmark = pytest.mark.gui

Z_PEN = (90, 140, 240)  # the third curve's colour (z, e3, …): drawn last, on top of x and y at 0


def _rgb(image: QtGui.QImage) -> np.ndarray:
    image = image.convertToFormat(QtGui.QImage.Format.Format_RGB32)
    a = np.frombuffer(image.constBits(), np.uint8).reshape(image.height(), image.bytesPerLine() // 4, 4)
    return a[:, :image.width(), 2::-1].astype(int)  # BGRA in memory -> RGB


def _pen_pixels(plots, key: str, color=Z_PEN) -> np.ndarray:
    """(x, y) canvas pixels of plot ``key`` inside its data area painted in ``color``."""
    canvas = plots.canvas_of(key)
    rgb = _rgb(canvas.grab().toImage())
    area = canvas.mapFromScene(plots.plots[key].getViewBox().sceneBoundingRect()).boundingRect()
    hit = np.zeros(rgb.shape[:2], bool)
    hit[area.top():area.bottom(), area.left():area.right()] = True
    hit &= (np.abs(rgb - np.array(color)) <= 12).all(axis=-1)
    ys, xs = np.nonzero(hit)
    return np.stack([xs, ys], axis=1)


def _frame_x(plots, key: str, frame: float) -> float:
    return plots.canvas_of(key).mapFromScene(plots.scene_point(key, frame)).x()


@pytest.fixture(scope="module")
def one_frame_study(tmp_path_factory):
    from core.synthetic import make_demo_study

    out = tmp_path_factory.mktemp("one_frame") / "study"
    make_demo_study(out, n_frames=1, pixels=48, seed=5, device="cpu", spacing=3.0, tissue_spacing=8.0,
                    calibration_session=False)
    return out


def _open(qtbot, win, folder):
    with job_ends(qtbot, win.pool, "overlay"):
        win.open_study(folder)
    rv = win.review
    rv.plots_dock.raise_()  # a tab beside Messages: drawn when shown
    qtbot.waitUntil(rv.plots.isVisible)
    rv.plots.show_page("Pose")
    qtbot.waitUntil(lambda: not rv.plots._dirty["Pose"])
    qtbot.wait(50)  # the paint
    return rv


@pytest.mark.parametrize("study", ["one frame", "first frame of three"])
def test_a_lone_pose_is_drawn(qtbot, tmp_path, monkeypatch, study, one_frame_study, demo_study):
    """Through the window: a study opened, the Plots dock shown; the Pose page's curves (all at 0:
    the pose is its own reference) are painted across the posed frame, as are the JCS angles."""
    monkeypatch.setenv("TALUS_SETTINGS_DIR", str(tmp_path / "settings"))
    folder = copy_study(one_frame_study if study == "one frame" else demo_study, tmp_path)
    with main_window(qtbot, size=(1280, 800)) as win:
        rv = _open(qtbot, win, folder)
        plots = rv.plots
        n = rv.data.n_frames
        assert n == (1 if study == "one frame" else 3)
        assert np.isfinite(rv.data.poses[:, 0]).all() and not np.isfinite(rv.data.poses[:, 1:]).any()
        assert plots.curve_data("translation", 2)[0] == 0.0
        px_per_frame = _frame_x(plots, "translation", 1) - _frame_x(plots, "translation", 0)
        for key in ("translation", "rotation"):
            hit = _pen_pixels(plots, key)
            assert len(hit) > 0.3 * px_per_frame, (key, len(hit))  # a dash 0.6 frames long
            x0 = _frame_x(plots, key, 0)
            assert hit[:, 0].min() < x0 - 0.2 * px_per_frame and hit[:, 0].max() > x0 + 0.2 * px_per_frame
            y0 = plots.canvas_of(key).mapFromScene(plots.plots[key].getViewBox().mapViewToScene(
                QtCore.QPointF(0.0, 0.0))).y()
            assert np.abs(hit[:, 1] - y0).max() <= 2  # at 0
        if study == "one frame":
            folder = os.environ.get("TALUS_SCREENSHOTS")
            if folder:
                Path(folder).mkdir(parents=True, exist_ok=True)
                shot = plots.canvas_of("translation").grab()
                assert shot.save(str(Path(folder) / "plots_one_frame_trial.png"))
        plots.show_page("Joint angles")
        qtbot.waitUntil(lambda: not plots._dirty["Joint angles"])
        qtbot.wait(50)
        key = next(k for k in plots.plots if k.startswith("jcs:"))
        e3 = plots.curve_data(key, 2)
        assert np.isfinite(e3[0]) and not np.isfinite(e3[1:]).any()
        assert len(_pen_pixels(plots, key)) > 0.3 * px_per_frame


def _render(scene, src: QtCore.QRectF, parts: int) -> np.ndarray:
    """The scene's ``src`` rendered in ``parts`` vertical strips, each repainted on its own (its
    exposed rectangle only), as Qt repaints a strip that changed."""
    img = QtGui.QImage(300, 120, QtGui.QImage.Format.Format_ARGB32)
    img.fill(QtGui.QColor("white"))
    painter = QtGui.QPainter(img)
    step = src.width() / parts
    for k in range(parts):
        part = QtCore.QRectF(src.left() + k * step, src.top(), step, src.height())
        target = QtCore.QRectF(k * img.width() / parts, 0, img.width() / parts, img.height())
        scene.render(painter, target, part, QtCore.Qt.AspectRatioMode.IgnoreAspectRatio)
    painter.end()
    return _rgb(img)


@pytest.mark.parametrize("n, frame", [(1, 0), (6, 0), (6, 5)])
def test_live_items_draw_a_lone_value_in_any_repaint(qtbot, n, frame):
    """A lone value at the first or last frame (or the only frame) is a dash across its frame, its
    band a bar, whether the plot is repainted whole or in strips."""
    from app.plots import _Live

    scene = QtWidgets.QGraphicsScene()
    curve = _Live(n, pens=[(200, 0, 0)])
    band = _Live(n, brushes=[(0, 0, 200)])
    for item in (curve, band):
        item.set_bounds(-4.0, 4.0)
        scene.addItem(item)
    y = np.full((1, n), np.nan)
    y[0, frame] = 2.0
    curve.set_data(y)
    band.set_data(np.stack([y - 1.0, y - 0.5], axis=1))  # under the curve: -1 .. 1.5
    src = QtCore.QRectF(-0.5, -4.0, n, 8.0)  # the plot's x range: frames -0.5 .. n - 0.5
    whole = _render(scene, src, 1)
    for parts in (2, 3, 7):
        np.testing.assert_array_equal(_render(scene, src, parts), whole)
    frame_x = (frame + 0.5) / n * whole.shape[1]  # the frame's centre in pixels
    for color in ((200, 0, 0), (0, 0, 200)):
        xs = np.nonzero((whole == color).all(axis=-1))[1]
        assert xs.size, color
        half = 0.3 * whole.shape[1] / n  # the dash: 0.3 frames each side
        assert xs.min() == pytest.approx(frame_x - half, abs=2)
        assert xs.max() == pytest.approx(frame_x + half, abs=2)
