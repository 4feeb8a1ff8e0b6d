"""The Talus main window: two fluoroscope panes and a 3D scene of the lab.

Image display follows radiology viewers: an image is shown through a *window/level* mapping,
grey value ``0`` at ``level - window / 2`` and ``255`` at ``level + window / 2``; dragging with
the right mouse button changes it (horizontal: window, vertical: level), a double click resets it
to the image's own range. Image arrays are indexed ``[row, col]``; pixel ``(u, v) = (col, row)``
is drawn centred at scene coordinates ``(u + 0.5, v + 0.5)``.

The 3D scene (a pyvistaqt ``QtInteractor``, lab frame in mm) is created lazily, the first time
the pane is shown, so the window can be built without an OpenGL context; closing the window
closes it.
"""

from __future__ import annotations

import json
import os
import re
import sys
from pathlib import Path

import numpy as np
from PySide6 import QtCore, QtGui, QtWidgets

from . import __version__

_PLACEHOLDER_SHAPE = (512, 512)
_DRAG_PIXELS = 200.0  # mouse travel that changes the window by a factor e / the level by a window
_IMAGE_SUFFIXES = {".tif", ".tiff", ".png", ".npy"}
_VIEW_KEY = re.compile(r"(?:cam(?:era)?|view)[_\-]?0*(\d+)", re.IGNORECASE)
_NOT_FLUORO = re.compile(r"drr|mask|label|truth|flatfield", re.IGNORECASE)


def _read_image(path: Path) -> np.ndarray:
    """First frame of an image file as an array ``[row, col]`` (.npy, .tif/.tiff, .png)."""
    suffix = path.suffix.lower()
    if suffix == ".npy":
        image = np.load(path, allow_pickle=False)
    elif suffix in (".tif", ".tiff"):
        import tifffile

        image = tifffile.imread(path, key=0)
    else:
        import cv2

        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise ValueError(f"{path}: not a readable image")
    while image.ndim > 2 and image.shape[-1] not in (3, 4):
        image = image[0]  # a stack: [frame, row, col]
    return image


def _summary_frames(folder: Path) -> dict[str, list[Path]] | None:
    """Frames per camera listed by a study's ``summary.json`` (``files.frames``), if any."""
    path = folder / "summary.json"
    if not path.is_file():
        return None
    try:
        frames = json.loads(path.read_text(encoding="utf-8")).get("files", {}).get("frames")
    except (OSError, ValueError, AttributeError) as exc:
        raise ValueError(f"{path}: not a study summary ({exc})") from exc
    if not isinstance(frames, dict):
        raise ValueError(f"{path}: expected 'files': {{'frames': {{camera: [paths]}}}}")
    return {cam: [folder / p for p in paths] for cam, paths in sorted(frames.items()) if paths}


def load_view_images(folder: Path, *, n_views: int = 2) -> list[tuple[str, np.ndarray]]:
    """``[(label, image), ...]``: the first frame of each camera of a study folder.

    The frames are those listed in ``summary.json`` (written by ``talus demo``); without one,
    cameras are recognised by ``cam01``/``camera1``/``view0``-style names of files or folders,
    skipping images whose names mention a DRR, mask, label, ground truth or flatfield.
    """
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: not a folder")
    listed = _summary_frames(folder)
    if listed is not None:
        if not listed:
            raise ValueError(f"{folder / 'summary.json'}: no camera images (no frames written)")
        return [
            (f"{cam}: {paths[0].relative_to(folder)}", _read_image(paths[0]))
            for cam, paths in list(listed.items())[:n_views]
        ]
    groups: dict[int, list[Path]] = {}
    for path in sorted(folder.rglob("*")):
        rel = path.relative_to(folder)
        if (path.suffix.lower() not in _IMAGE_SUFFIXES or len(rel.parts) > 3
                or _NOT_FLUORO.search(str(rel)) or not path.is_file()):
            continue
        keys = _VIEW_KEY.findall(str(rel))
        if keys:
            groups.setdefault(int(keys[-1]), []).append(path)
    if not groups:
        raise ValueError(
            f"{folder}: no camera images found (expected .tif/.png/.npy images in files or "
            "folders named like cam01, cam02)"
        )
    return [
        (f"cam{key:02d}: {groups[key][0].relative_to(folder)}", _read_image(groups[key][0]))
        for key in sorted(groups)[:n_views]
    ]


def auto_window_level(image: np.ndarray) -> tuple[float, float]:
    """(window, level) spanning the 0.5-99.5 % range of the finite values of ``image``."""
    finite = image[np.isfinite(image)]
    if finite.size == 0:
        return 1.0, 0.5
    lo, hi = np.percentile(finite, [0.5, 99.5])
    if hi <= lo:
        lo, hi = float(finite.min()), float(finite.max())
    if hi <= lo:
        return 1.0, float(lo)
    return float(hi - lo), float(0.5 * (hi + lo))


def to_qimage(image: np.ndarray, window: float, level: float) -> QtGui.QImage:
    """An 8-bit grey ``QImage`` of a 2-D array through ``(window, level)``; NaN shows black."""
    if image.ndim != 2:
        raise ValueError(f"image: expected a 2-D array [row, col], got shape {image.shape}")
    if not window > 0:
        raise ValueError(f"window: expected a positive number, got {window}")
    scaled = (image.astype(np.float32) - (level - 0.5 * window)) * np.float32(255.0 / window)
    grey = np.clip(np.nan_to_num(scaled, nan=0.0) + 0.5, 0, 255).astype(np.uint8)
    grey = np.ascontiguousarray(grey)
    h, w = grey.shape
    return QtGui.QImage(grey.data, w, h, w, QtGui.QImage.Format.Format_Grayscale8).copy()


class _ImageView(QtWidgets.QGraphicsView):
    """Graphics view keeping the image fitted; right-drag adjusts window/level."""

    drag_window_level = QtCore.Signal(float, float)  # (dx, dy) in screen pixels
    reset_window_level = QtCore.Signal()

    def __init__(self, parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        self.setBackgroundBrush(QtGui.QColor(20, 20, 20))
        self.setRenderHint(QtGui.QPainter.RenderHint.SmoothPixmapTransform, False)
        self.setHorizontalScrollBarPolicy(QtCore.Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        self.setVerticalScrollBarPolicy(QtCore.Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        self._last: QtCore.QPointF | None = None

    def fit(self) -> None:
        if self.scene() is not None:
            self.fitInView(self.scene().sceneRect(), QtCore.Qt.AspectRatioMode.KeepAspectRatio)

    def resizeEvent(self, event: QtGui.QResizeEvent) -> None:
        super().resizeEvent(event)
        self.fit()

    def mousePressEvent(self, event: QtGui.QMouseEvent) -> None:
        if event.button() == QtCore.Qt.MouseButton.RightButton:
            self._last = event.position()
            event.accept()
            return
        super().mousePressEvent(event)

    def mouseMoveEvent(self, event: QtGui.QMouseEvent) -> None:
        if self._last is not None:
            delta = event.position() - self._last
            self._last = event.position()
            self.drag_window_level.emit(delta.x(), delta.y())
            event.accept()
            return
        super().mouseMoveEvent(event)

    def mouseReleaseEvent(self, event: QtGui.QMouseEvent) -> None:
        if event.button() == QtCore.Qt.MouseButton.RightButton:
            self._last = None
        super().mouseReleaseEvent(event)

    def mouseDoubleClickEvent(self, event: QtGui.QMouseEvent) -> None:
        self.reset_window_level.emit()
        super().mouseDoubleClickEvent(event)


class FluoroPane(QtWidgets.QWidget):
    """One fluoroscope view: a title and an image shown through a window/level."""

    window_level_changed = QtCore.Signal(float, float)

    def __init__(self, title: str, parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        self.setObjectName(title)
        self._title = QtWidgets.QLabel(title)
        self._title.setStyleSheet("font-weight: bold; padding: 2px;")
        self._scene = QtWidgets.QGraphicsScene(self)
        self._pixmap = self._scene.addPixmap(QtGui.QPixmap())
        self._note = self._scene.addSimpleText("")
        self._note.setBrush(QtGui.QColor(230, 230, 230))
        self.view = _ImageView(self)
        self.view.setScene(self._scene)
        self.view.drag_window_level.connect(self._on_drag)
        self.view.reset_window_level.connect(self.auto_window_level)
        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(2, 2, 2, 2)
        layout.addWidget(self._title)
        layout.addWidget(self.view, 1)
        self._image: np.ndarray | None = None
        self._window, self._level = 1.0, 0.5
        self.clear()

    # -- state
    @property
    def image(self) -> np.ndarray | None:
        """The array shown (``[row, col]``), or ``None`` while the placeholder is shown."""
        return self._image

    @property
    def window_level(self) -> tuple[float, float]:
        return self._window, self._level

    def qimage(self) -> QtGui.QImage:
        """The 8-bit image currently displayed."""
        return self._pixmap.pixmap().toImage()

    # -- intents
    def set_image(
        self, image: np.ndarray, *, window: float | None = None, level: float | None = None
    ) -> None:
        """Show a 2-D array ``[row, col]`` (or ``[row, col, 3|4]`` colour, shown as grey)."""
        arr = np.asarray(image)
        if arr.ndim == 3 and arr.shape[2] in (3, 4):
            arr = arr[..., :3].mean(axis=2)
        if arr.ndim != 2 or arr.size == 0:
            raise ValueError(f"image: expected a 2-D array [row, col], got shape {arr.shape}")
        if not (np.issubdtype(arr.dtype, np.number) and not np.iscomplexobj(arr)):
            raise ValueError(f"image: expected a real numeric array, got dtype {arr.dtype}")
        self._image = arr
        self._note.setText("")
        auto_w, auto_l = auto_window_level(arr)
        self._scene.setSceneRect(0, 0, arr.shape[1], arr.shape[0])
        self.set_window_level(
            auto_w if window is None else window, auto_l if level is None else level
        )
        self.view.fit()

    def set_window_level(self, window: float, level: float) -> None:
        window, level = float(window), float(level)
        if not (np.isfinite(window) and window > 0 and np.isfinite(level)):
            raise ValueError(
                f"window/level: expected window > 0 and a finite level, got {window}, {level}"
            )
        self._window, self._level = window, level
        shown = self._image if self._image is not None else np.full(_PLACEHOLDER_SHAPE, 0.5)
        self._pixmap.setPixmap(QtGui.QPixmap.fromImage(to_qimage(shown, window, level)))
        self.window_level_changed.emit(window, level)

    def auto_window_level(self) -> None:
        if self._image is not None:
            self.set_window_level(*auto_window_level(self._image))

    def clear(self) -> None:
        """Show the grey placeholder."""
        self._image = None
        self._scene.setSceneRect(0, 0, _PLACEHOLDER_SHAPE[1], _PLACEHOLDER_SHAPE[0])
        self.set_window_level(1.0, 0.5)
        self._note.setText("No image loaded")
        self._note.setScale(3.0)
        self._note.setPos(20, 20)
        self.view.fit()

    def _on_drag(self, dx: float, dy: float) -> None:
        if self._image is not None:
            window = self._window * float(np.exp(dx / _DRAG_PIXELS))
            self.set_window_level(window, self._level - dy * self._window / _DRAG_PIXELS)


class ScenePane(QtWidgets.QWidget):
    """The 3D lab scene (pyvistaqt); the interactor is created on first show."""

    AXIS_LENGTH_MM = 100.0

    def __init__(self, parent: QtWidgets.QWidget | None = None, *, create_on_show: bool = True):
        super().__init__(parent)
        self.plotter = None
        self._create_on_show = create_on_show
        self._placeholder = QtWidgets.QLabel("3D scene")
        self._placeholder.setAlignment(QtCore.Qt.AlignmentFlag.AlignCenter)
        self._layout = QtWidgets.QVBoxLayout(self)
        self._layout.setContentsMargins(0, 0, 0, 0)
        self._layout.addWidget(self._placeholder)

    def showEvent(self, event: QtGui.QShowEvent) -> None:
        super().showEvent(event)
        if self._create_on_show and self.plotter is None:
            QtCore.QTimer.singleShot(0, self.ensure_interactor)

    def ensure_interactor(self):
        """Create the ``QtInteractor`` with the lab axes (once); returns it."""
        if self.plotter is None:
            import pyvista as pv
            from pyvistaqt import QtInteractor

            plotter = QtInteractor(self, auto_update=False)
            plotter.set_background("#1e1e1e")
            length = self.AXIS_LENGTH_MM
            for axis, colour in zip(np.eye(3), ("red", "green", "blue"), strict=True):
                arrow = pv.Arrow(start=(0, 0, 0), direction=axis, scale=length)
                plotter.add_mesh(arrow, color=colour, name=f"lab-axis-{colour}")
            plotter.add_point_labels(
                1.1 * length * np.eye(3), ["X", "Y", "Z"], font_size=14, text_color="white",
                shape=None, show_points=False, name="lab-axis-labels",
            )
            plotter.add_axes()
            plotter.view_isometric()
            plotter.camera.zoom(0.8)  # room for the axis labels
            self._layout.removeWidget(self._placeholder)
            self._placeholder.hide()
            self._layout.addWidget(plotter.interactor)
            self.plotter = plotter
        return self.plotter

    def close_interactor(self) -> None:
        if self.plotter is not None:
            plotter, self.plotter = self.plotter, None
            plotter.close()


class MainWindow(QtWidgets.QMainWindow):
    """Talus main window: File/Help menus, status bar, two fluoro panes and the 3D scene."""

    def __init__(self, *, create_scene_on_show: bool = True) -> None:
        super().__init__()
        self.setWindowTitle("Talus")
        self.resize(1280, 720)
        self.panes = [FluoroPane("Camera 1"), FluoroPane("Camera 2")]
        self.scene = ScenePane(create_on_show=create_scene_on_show)
        self.splitter = QtWidgets.QSplitter(QtCore.Qt.Orientation.Horizontal)
        for widget in (*self.panes, self.scene):
            self.splitter.addWidget(widget)
        self.splitter.setSizes([420, 420, 440])
        self.setCentralWidget(self.splitter)
        self._build_menus()
        self.statusBar().showMessage("Ready")

    def _build_menus(self) -> None:
        file_menu = self.menuBar().addMenu("&File")
        self.open_demo_action = file_menu.addAction("&Open demo study…")
        self.open_demo_action.setShortcut(QtGui.QKeySequence("Ctrl+O"))
        self.open_demo_action.triggered.connect(self._ask_open_demo)
        file_menu.addSeparator()
        self.quit_action = file_menu.addAction("&Quit")
        self.quit_action.setShortcut(QtGui.QKeySequence("Ctrl+Q"))
        self.quit_action.setShortcutContext(QtCore.Qt.ShortcutContext.ApplicationShortcut)
        self.quit_action.triggered.connect(self.close)
        help_menu = self.menuBar().addMenu("&Help")
        self.about_action = help_menu.addAction("&About Talus")
        self.about_action.triggered.connect(self._about)

    def open_demo_study(self, folder: str | Path) -> None:
        """Show the first frame of each camera of a study folder (e.g. from ``talus demo``)."""
        folder = Path(folder)
        images = load_view_images(folder, n_views=len(self.panes))
        for pane, (name, image) in zip(self.panes, images, strict=False):
            pane.set_image(image)
            pane.setToolTip(name)
        self.statusBar().showMessage(
            f"Opened {folder}: " + ", ".join(name for name, _ in images)
        )

    def _ask_open_demo(self) -> None:
        folder = QtWidgets.QFileDialog.getExistingDirectory(self, "Open demo study", os.getcwd())
        if folder:
            try:
                self.open_demo_study(folder)
            except (OSError, ValueError) as exc:
                QtWidgets.QMessageBox.warning(self, "Talus", f"Cannot open {folder}:\n{exc}")

    def _about(self) -> None:
        QtWidgets.QMessageBox.about(
            self,
            "About Talus",
            f"<b>Talus {__version__}</b><p>Biplane fluoroscopy bone tracking: image correction, "
            "X-ray camera calibration and DRR-based 2D/3D registration.</p>",
        )

    def closeEvent(self, event: QtGui.QCloseEvent) -> None:
        self.scene.close_interactor()
        super().closeEvent(event)


def run_gui(*, demo: Path | None = None) -> int:
    """Open the main window (optionally with a demo study) and run the Qt event loop."""
    if sys.platform.startswith("linux") and os.environ.get("DISPLAY"):
        os.environ.setdefault("QT_QPA_PLATFORM", "xcb")  # VTK's interactor needs X11/GLX
    app = QtWidgets.QApplication.instance() or QtWidgets.QApplication(sys.argv[:1])
    app.setApplicationName("Talus")
    window = MainWindow()
    if demo is not None:
        try:
            window.open_demo_study(demo)
        except (OSError, ValueError) as exc:
            print(f"talus gui: cannot open {demo}: {exc}", file=sys.stderr)
            window.statusBar().showMessage(f"Cannot open {demo}: {exc}")
    window.show()
    return app.exec()
