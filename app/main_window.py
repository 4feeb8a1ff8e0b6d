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

from . import __version__, settings
from .controller import Controller
from .importing import ImportActions
from .layers import LayerList
from .model import ViewerModel
from .panes import FluoroPane
from .scene3d import ScenePane
from .timeline import Timeline
from .tracking_actions import TrackingActions
from .workers import WorkerPool

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
    """Talus main window: two fluoroscope panes, the 3D scene, bone layers and a timeline.

    Keys (with a study open): ``Left``/``Right`` or ``,``/``.`` step frames, ``Space`` plays;
    ``W``/``S``, ``A``/``D``, ``Q``/``E`` move the selected bone ±x, ±y, ±z by the translation
    step (mm) and, with ``Shift``, rotate it about those lab axes by the rotation step (deg);
    ``Ctrl+Z`` / ``Ctrl+Shift+Z`` undo/redo.
    """

    def __init__(self, *, create_scene_on_show: bool = True, device: str | None = None) -> None:
        super().__init__()
        self.setWindowTitle("Talus")
        self.resize(1280, 760)
        self.device = device
        self.translate_step_mm = 0.5
        self.rotate_step_deg = 0.5
        self.model = None
        self.controller = None
        self.study = None
        self.session = None
        self.pool = WorkerPool(self)
        self.panes = [FluoroPane("Camera 1"), FluoroPane("Camera 2")]
        self.scene = ScenePane(create_on_show=create_scene_on_show)
        self.splitter = QtWidgets.QSplitter(QtCore.Qt.Orientation.Horizontal)
        for widget in (*self.panes, self.scene):
            self.splitter.addWidget(widget)
        self.splitter.setSizes([420, 420, 440])
        central = QtWidgets.QWidget()
        self._central_layout = QtWidgets.QVBoxLayout(central)
        self._central_layout.setContentsMargins(0, 0, 0, 0)
        self._central_layout.addWidget(self.splitter, 1)
        self.setCentralWidget(central)
        self.messages = QtWidgets.QListWidget()
        self.messages.setObjectName("messages")
        self.messages_dock = QtWidgets.QDockWidget("Messages", self)
        self.messages_dock.setWidget(self.messages)
        self.addDockWidget(QtCore.Qt.DockWidgetArea.BottomDockWidgetArea, self.messages_dock)
        self.messages_dock.hide()  # shown by the first message
        self.progress = QtWidgets.QProgressBar()
        self.progress.setMaximumWidth(200)
        self.progress.hide()
        self.cancel_button = QtWidgets.QPushButton("Cancel")
        self.cancel_button.hide()
        self.statusBar().addPermanentWidget(self.progress)
        self.statusBar().addPermanentWidget(self.cancel_button)
        self.pool.failed.connect(self._on_failed)
        self.pool.progress.connect(self._on_progress)
        self.pool.busy_changed.connect(self._on_busy)
        self.cancel_button.clicked.connect(self._cancel_jobs)
        self._build_menus()
        self.statusBar().showMessage("Ready")

    # ------------------------------------------------------------------ menus and keys
    def _build_menus(self) -> None:
        file_menu = self.menuBar().addMenu("&File")
        self.importer = ImportActions(self)
        self.new_action = file_menu.addAction("&New study…")
        self.new_action.setShortcut(QtGui.QKeySequence("Ctrl+N"))
        self.new_action.triggered.connect(lambda: self._guard(self.importer.new_study))
        self.open_demo_action = file_menu.addAction("&Open study…")
        self.open_demo_action.setShortcut(QtGui.QKeySequence("Ctrl+O"))
        self.open_demo_action.triggered.connect(self._ask_open_demo)
        self.recent_menu = file_menu.addMenu("Open &recent")
        self._fill_recent()
        imp = file_menu.addMenu("&Import")
        for text, fn in (("Calibration (MayaCam files)…", self.importer.import_calibration),
                         ("CT volume as a bone…", self.importer.import_volume),
                         ("Trial (one sequence per camera)…", self.importer.import_trial)):
            imp.addAction(text).triggered.connect(lambda _=False, f=fn: self._guard(f))
        file_menu.addSeparator()
        self.quit_action = file_menu.addAction("&Quit")
        self.quit_action.setShortcut(QtGui.QKeySequence("Ctrl+Q"))
        self.quit_action.setShortcutContext(QtCore.Qt.ShortcutContext.ApplicationShortcut)
        self.quit_action.triggered.connect(self.close)
        edit = self.menuBar().addMenu("&Edit")
        self.undo_action = edit.addAction("&Undo")
        self.undo_action.setShortcut(QtGui.QKeySequence.StandardKey.Undo)
        self.redo_action = edit.addAction("&Redo")
        self.redo_action.setShortcut(QtGui.QKeySequence("Ctrl+Shift+Z"))
        self.undo_action.triggered.connect(lambda: self.model and self.model.undo())
        self.redo_action.triggered.connect(lambda: self.model and self.model.redo())
        view = self.menuBar().addMenu("&View")
        for text, keys, slot in (
            ("Next frame", ("Right", "."), lambda: self.model and self.model.step(1)),
            ("Previous frame", ("Left", ","), lambda: self.model and self.model.step(-1)),
            ("Play / pause", ("Space",), lambda: self.timeline and self.timeline.toggle()),
        ):
            act = view.addAction(text)
            act.setShortcuts([QtGui.QKeySequence(k) for k in keys])
            act.triggered.connect(slot)
        pose = self.menuBar().addMenu("&Pose")
        for axis, (minus, plus) in enumerate((("A", "D"), ("S", "W"), ("Q", "E"))):
            for key, sign in ((minus, -1.0), (plus, 1.0)):
                act = pose.addAction(f"Move {'xyz'[axis]}{'+' if sign > 0 else '-'}")
                act.setShortcut(QtGui.QKeySequence(key))
                act.triggered.connect(lambda _=False, a=axis, sg=sign: self._nudge(a, sg, False))
                act = pose.addAction(f"Turn about {'xyz'[axis]}{'+' if sign > 0 else '-'}")
                act.setShortcut(QtGui.QKeySequence(f"Shift+{key}"))
                act.triggered.connect(lambda _=False, a=axis, sg=sign: self._nudge(a, sg, True))
        self.tracking = TrackingActions(self)
        track = self.menuBar().addMenu("&Tracking")
        self.track_action = track.addAction("Track &selected bone")
        self.track_action.setShortcut(QtGui.QKeySequence("Ctrl+T"))
        self.track_action.triggered.connect(lambda: self._guard(self.tracking.track_selected))
        track.addAction("Track &all bones").triggered.connect(
            lambda: self._guard(self.tracking.track_all))
        track.addAction("&Cancel tracking").triggered.connect(self.tracking.cancel)
        help_menu = self.menuBar().addMenu("&Help")
        self.about_action = help_menu.addAction("&About Talus")
        self.about_action.triggered.connect(self._about)
        self.timeline = None

    def _nudge(self, axis: int, sign: float, rotate: bool) -> None:
        if self.controller is None:
            return
        vec = np.zeros(3)
        if rotate:
            vec[axis] = sign * np.deg2rad(self.rotate_step_deg)
            self.controller.nudge(rotate=vec)
        else:
            vec[axis] = sign * self.translate_step_mm
            self.controller.nudge(translate=vec)

    # ------------------------------------------------------------------ studies
    def set_model(self, model: ViewerModel) -> None:
        """Show a viewer model: panes per camera, bone layers, timeline, overlays, 3D scene."""
        self.model = model
        for pane, cam in zip(self.panes, model.rig, strict=False):
            pane._title.setText(f"Camera {cam.name or ''}".strip())
        self.layers = LayerList(model)
        dock = QtWidgets.QDockWidget("Layers", self)
        dock.setWidget(self.layers)
        self.addDockWidget(QtCore.Qt.DockWidgetArea.LeftDockWidgetArea, dock)
        self.timeline = Timeline(model)
        self._central_layout.addWidget(self.timeline)
        self.controller = Controller(model, self.panes, self.pool, device=self.device,
                                     parent=self)
        self.layers.mode_changed.connect(self.controller.set_mode)
        self.layers.markers_changed.connect(self.controller.set_markers)
        self.layers.cameras_changed.connect(self.scene.set_cameras_visible)
        self.scene.set_model(model)
        model.history_changed.connect(self._update_history)
        self._update_history()

    def _update_history(self) -> None:
        self.undo_action.setEnabled(bool(self.model and self.model.can_undo))
        self.redo_action.setEnabled(bool(self.model and self.model.can_redo))

    def open_study(self, folder: str | Path, *, read_only: bool = False) -> None:
        """Open a study folder (``study.json``); pose edits are journalled as they happen."""
        from core.study import LockedError

        from .session import open_study

        if self.model is not None:
            raise ValueError("study: this window already shows a study; open another window")
        try:
            self.session = open_study(folder, read_only=read_only)
        except LockedError as exc:  # open elsewhere for writing: show it read-only
            self.session = open_study(folder, read_only=True)
            self.notify(f"{exc} — opened read-only.")
        self.set_model(self.session.model)
        folder = self.session.folder
        names = ", ".join(layer.name for layer in self.model.layers)
        self.statusBar().showMessage(f"Opened {folder} ({self.session.trial_name}): {names}")
        if self.session.recovered:
            self.notify(f"{folder} was not closed cleanly last time; every pose recorded up to "
                        "then has been restored.")
        if not self.session.writable:
            self.notify(f"{folder} is open read-only: pose edits are not saved.")
        settings.add_recent(str(folder))
        self._fill_recent()

    def _fill_recent(self) -> None:
        self.recent_menu.clear()
        for path in settings.recent():
            act = self.recent_menu.addAction(path)
            act.triggered.connect(lambda _=False, p=path: self._open_checked(p))
        self.recent_menu.setEnabled(bool(settings.recent()))

    def _guard(self, action) -> None:
        """Run a menu action; a failure is shown, never raised into the event loop."""
        try:
            action()
        except Exception as exc:  # shown to the user with its reason
            self.notify(f"{exc}")
            QtWidgets.QMessageBox.warning(self, "Talus", str(exc))

    def _open_checked(self, folder: str) -> None:
        from .session import MissingFilesError

        try:
            self.open_demo_study(folder)
        except MissingFilesError as exc:
            if self.relocate_missing(exc):
                self._open_checked(folder)
        except Exception as exc:  # any reason the study cannot be shown, shown to the user
            QtWidgets.QMessageBox.warning(self, "Talus", f"Cannot open {folder}:\n{exc}")

    def relocate_missing(self, exc) -> bool:
        """Show what is missing and let the user point at each file's new place; True when
        every missing file was relocated (the study can be opened again)."""
        from core.study import Study

        answer = QtWidgets.QMessageBox.question(
            self, "Talus", f"{exc}\n\nLocate the missing files now?")
        if answer != QtWidgets.QMessageBox.StandardButton.Yes:
            return False
        with Study.open(exc.folder, mode="w", check_files=False) as st:
            for what, path in exc.missing:
                if path.suffix:
                    new, _ = QtWidgets.QFileDialog.getOpenFileName(
                        self, f"Where is {path.name}? ({what})", str(path.parent))
                else:
                    new = QtWidgets.QFileDialog.getExistingDirectory(
                        self, f"Where is {path.name}? ({what})", str(path.parent))
                if not new:
                    return False
                st.relocate(path, new)
                self.notify(f"{what}: now {new}")
        return True

    def open_demo_study(self, folder: str | Path) -> None:
        """Open a study folder, a ``talus demo`` folder without a manifest, or (a plain folder of
        camera images) show the first image of each camera."""
        folder = Path(folder)
        if (folder / "study.json").is_file():
            self.open_study(folder)
            return
        if (folder / "summary.json").is_file() and '"talus-synthetic-study"' in (
                folder / "summary.json").read_text(encoding="utf-8"):
            from .demo_study import open_demo_study

            self.study = open_demo_study(folder)
            self.set_model(self.study.model)
            names = ", ".join(layer.name for layer in self.study.model.layers)
            self.statusBar().showMessage(f"Opened {folder}: {names}")
            return
        images = load_view_images(folder, n_views=len(self.panes))
        for pane, (name, image) in zip(self.panes, images, strict=False):
            pane.set_image(image)
            pane.setToolTip(name)
        self.statusBar().showMessage(
            f"Opened {folder}: " + ", ".join(name for name, _ in images)
        )

    def _ask_open_demo(self) -> None:
        folder = QtWidgets.QFileDialog.getExistingDirectory(self, "Open study", os.getcwd())
        if folder:
            self._open_checked(folder)

    # ------------------------------------------------------------------ jobs
    def notify(self, text: str) -> None:
        self.messages_dock.show()
        self.messages.addItem(text.splitlines()[-1] if text else "")
        self.messages.item(self.messages.count() - 1).setToolTip(text)
        self.messages.scrollToBottom()
        self.statusBar().showMessage(text.splitlines()[-1] if text else "", 10000)

    def _on_failed(self, key: str, text: str) -> None:
        self.notify(f"{key} failed:\n{text}")

    def _on_progress(self, key: str, done: int, total: int) -> None:
        self.progress.setRange(0, max(total, 1))
        self.progress.setValue(done)
        self.progress.setFormat(f"{key} %v/%m")

    def _on_busy(self, busy: bool) -> None:
        self.progress.setVisible(busy and self.progress.maximum() > 1)
        self.cancel_button.setVisible(busy and self.progress.maximum() > 1)

    def _cancel_jobs(self) -> None:
        for key in list(self.pool._latest):
            self.pool.cancel(key)

    def _about(self) -> None:
        QtWidgets.QMessageBox.about(
            self,
            "About Talus",
            f"<b>Talus {__version__}</b><p>Biplane fluoroscopy bone tracking: image correction, "
            "X-ray camera calibration and DRR-based 2D/3D registration.</p>",
        )

    def closeEvent(self, event: QtGui.QCloseEvent) -> None:
        if self.controller is not None:
            self.controller.shutdown()
        if self.timeline is not None:
            self.timeline.set_playing(False)
        self.pool.shutdown(wait=False)
        if self.session is not None:
            self.session.close()
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
