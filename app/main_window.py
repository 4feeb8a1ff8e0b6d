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
from .panes import FluoroPane
from .scene3d import ScenePane

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
