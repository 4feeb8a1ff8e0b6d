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

import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from PySide6 import QtCore, QtGui, QtWidgets

from . import __version__, errors, settings
from .importing import ImportActions
from .panes import FluoroPane
from .scene3d import ScenePane
from .tracking_actions import TrackingActions
from .workers import WorkerPool

if TYPE_CHECKING:
    from .model import ViewerModel

# The window shows before the heavy parts load: the study classes, the overlay renderer (Warp)
# and the posing maths (scipy) are imported when a study is opened, the 3D scene (VTK) once
# the window has been painted.


def load_view_images(folder: Path, *, n_views: int = 2) -> list[tuple[str, np.ndarray]]:
    """``[(label, image), ...]``: the first image of each camera of a folder that is not a
    study (see :func:`core.io.images.camera_images`)."""
    from core.io.images import camera_images, read_image

    return [(label, read_image(path)) for label, path in camera_images(folder, n_views=n_views)]


def _breakable(text: str) -> str:
    """Let a label wrap long paths: a zero-width space after each ``/`` and ``_``."""
    return text.replace("/", "/\u200b").replace("_", "_\u200b")


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
        self._restore_geometry()
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
        self.feedback = QtWidgets.QLabel()  # tracking: frame i/N, frames per second, ETA
        self.feedback.setObjectName("tracking-feedback")
        self.feedback.hide()
        self.statusBar().addPermanentWidget(self.feedback)
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
        self.import_project_action = file_menu.addAction("Import &project (Autoscoper .cfg, XMALab .xma)…")
        self.import_project_action.setShortcut(QtGui.QKeySequence("Ctrl+Shift+I"))
        self.import_project_action.triggered.connect(lambda: self._guard(self.import_project_dialog))
        imp = file_menu.addMenu("&Import")
        for text, fn in (("Calibration (MayaCam files)…", self.importer.import_calibration),
                         ("CT volume as a bone…", self.importer.import_volume),
                         ("Trial (one sequence per camera)…", self.importer.import_trial)):
            imp.addAction(text).triggered.connect(lambda _=False, f=fn: self._guard(f))
        from .calibration.menu import add_file_actions

        add_file_actions(self, file_menu)
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
        self.undo_action.triggered.connect(lambda: self.model and self._guard(self.model.undo))
        self.redo_action.triggered.connect(lambda: self.model and self._guard(self.model.redo))
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
        self.tracking.add_batch_action(track)
        self.tracking.add_options_action(track)
        track.addAction("&Cancel tracking").triggered.connect(self.tracking.cancel)
        help_menu = self.menuBar().addMenu("&Help")
        self.about_action = help_menu.addAction("&About Talus")
        self.about_action.triggered.connect(self._about)
        from .review_actions import ReviewActions

        self.review = ReviewActions(self)
        self.timeline = None
        self.controller = None
        self.layers = self.layers_dock = None
        self.last_error: tuple[str, str] | None = None
        self.last_dialog = None  # the import-project or export dialog last opened (tests drive it)
        self._painted = False
        self._after_paint: list = []

    def after_first_paint(self, fn) -> None:
        """Call ``fn`` once the window has been painted (at once if it has been)."""
        if self._painted:
            QtCore.QTimer.singleShot(0, fn)
        else:
            self._after_paint.append(fn)

    def paintEvent(self, event: QtGui.QPaintEvent) -> None:
        super().paintEvent(event)
        if not self._painted:
            self._painted = True
            for fn in self._after_paint:
                QtCore.QTimer.singleShot(0, fn)
            self._after_paint.clear()

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
        """Show a viewer model: panes per camera, bone layers, timeline, overlays, 3D scene.

        All or nothing: if any part fails, what was added is removed again and the error is
        raised, leaving the window as it was.
        """
        from .controller import Controller
        from .layers import LayerList
        from .timeline import Timeline

        if self.model is not None:
            raise ValueError("study: this window already shows a study; open another window")
        before = [(pane.image, pane.window_level, pane._title.text()) for pane in self.panes]
        self.model = model
        try:
            for pane, cam in zip(self.panes, model.rig, strict=False):
                pane._title.setText(f"Camera {cam.name or ''}".strip())
            self.layers = LayerList(model)
            self.layers_dock = QtWidgets.QDockWidget("Layers", self)
            self.layers_dock.setWidget(self.layers)
            self.addDockWidget(QtCore.Qt.DockWidgetArea.LeftDockWidgetArea, self.layers_dock)
            self.timeline = Timeline(model)
            self._central_layout.addWidget(self.timeline)
            self.controller = Controller(model, self.panes, self.pool, device=self.device,
                                         parent=self)
            self.controller.frame_failed.connect(lambda text: self.notify(text, error=True))
            self.layers.mode_changed.connect(self.controller.set_mode)
            self.layers.markers_changed.connect(self.controller.set_markers)
            self.layers.cameras_changed.connect(self.scene.set_cameras_visible)
            self.scene.set_model(model)
            model.history_changed.connect(self._update_history)
            self.review.attach(model, self.session)
        except BaseException:
            self._unset_model(panes=before)
            raise
        self._update_history()
        if getattr(self, "welcome", None) is not None:  # the welcome page gives the study its room
            self.welcome.study_shown()

    def _unset_model(self, *, panes=None) -> None:
        """Take a (partly) shown model out of the window: layers, timeline, scene; the panes
        go back to ``panes`` (``(image, (window, level), title)`` each) or to placeholders."""
        model, self.model = self.model, None
        self.review.detach()
        if self.controller is not None:
            self.controller.shutdown()
            self.controller.setParent(None)
            self.controller.deleteLater()
            self.controller = None
        self.pool.cancel("overlay")
        if self.timeline is not None:
            self.timeline.set_playing(False)
            self._central_layout.removeWidget(self.timeline)
            self.timeline.deleteLater()
            self.timeline = None
        dock = getattr(self, "layers_dock", None)
        if dock is not None:
            self.removeDockWidget(dock)
            dock.deleteLater()
            self.layers_dock = self.layers = None
        if self.scene.model is model:
            self.scene.model = None
        panes = panes or [(None, None, f"Camera {k}") for k in range(1, len(self.panes) + 1)]
        for pane, (image, window_level, title) in zip(self.panes, panes, strict=True):
            pane._title.setText(title)
            for key in pane.overlay_keys():
                pane.hide_overlay(key)
            if image is None:
                pane.clear()
            elif image is not pane.image:
                pane.set_image(image, window=window_level[0], level=window_level[1])
        self._update_history()

    def _update_history(self) -> None:
        self.undo_action.setEnabled(bool(self.model and self.model.can_undo))
        self.redo_action.setEnabled(bool(self.model and self.model.can_redo))

    def open_study(self, folder: str | Path, *, read_only: bool = False) -> None:
        """Open a study folder (``study.json``); pose edits are journalled as they happen.

        Everything the window shows first (the cameras' first frames, every bone's volume)
        is read before the window changes; if anything fails, the study is closed again and
        the window stays as it was.
        """
        from core.study import LockedError

        from .session import open_study

        if self.model is not None:
            raise ValueError("study: this window already shows a study; open another window")
        notes = []
        try:
            session = open_study(folder, read_only=read_only)
        except LockedError as exc:  # open elsewhere for writing: show it read-only
            session = open_study(folder, read_only=True)
            session.read_only_reason = str(exc)
            notes.append(f"{exc} — opened read-only.")
        self.session = session
        try:
            for view in range(len(session.model.rig)):
                session.model.frame_image(view)  # a damaged first frame fails here
            self.set_model(session.model)
            from .panes import attach_study_correction

            attach_study_correction(self.panes, session.study, session.trial_name)
        except BaseException:
            self.session = None
            session.close()
            raise
        folder = session.folder
        names = ", ".join(layer.name for layer in self.model.layers)
        self.statusBar().showMessage(f"Opened {folder} ({session.trial_name}): {names}")
        for note in notes:
            self.notify(note)
        if session.recovered:
            self.notify(f"{folder} (trial {session.trial_name}) was not closed cleanly last time; "
                        "every pose recorded up to then has been restored.")
        if not session.writable:
            self.notify(f"{folder} is open read-only: pose edits are not saved.")
        settings.add_recent(str(folder))
        self._fill_recent()

    def _fill_recent(self) -> None:
        self.recent_menu.clear()
        for path in settings.recent():
            act = self.recent_menu.addAction(path)
            act.triggered.connect(lambda _=False, p=path: self._open_checked(p))
        self.recent_menu.setEnabled(bool(settings.recent()))

    def show_error(self, title: str, text: str) -> None:
        """A warning dialog whose text wraps (long paths included) instead of being cut off (or,
        where :data:`app.errors.HOOK` is set — the GUI tests — the hook, without a modal box)."""
        self.last_error = (title, text)
        if errors.report_elsewhere(title, text):
            return
        box = QtWidgets.QMessageBox(QtWidgets.QMessageBox.Icon.Warning, "Talus", "", parent=self)
        box.setObjectName("error-dialog")
        box.setTextFormat(QtCore.Qt.TextFormat.PlainText)
        box.setText(_breakable(title))
        box.setInformativeText(_breakable(text))
        screen = (self.screen() or QtWidgets.QApplication.primaryScreen()).availableGeometry()
        width = max(360, min(640, screen.width() - 80))
        for label in box.findChildren(QtWidgets.QLabel):
            if label.text():
                label.setWordWrap(True)
                label.setMinimumWidth(width)
                label.setTextInteractionFlags(
                    QtCore.Qt.TextInteractionFlag.TextSelectableByMouse)
        box.exec()

    def _guard(self, action) -> None:
        """Run a menu action; a failure is shown, never raised into the event loop."""
        try:
            action()
        except Exception as exc:  # shown to the user with its reason
            self.notify(f"{exc}", error=True)
            self.show_error("This did not work:", str(exc))

    def _open_checked(self, folder: str) -> None:
        from .session import MissingFilesError

        try:
            self.open_demo_study(folder)
        except MissingFilesError as exc:
            if self.relocate_missing(exc):
                self._open_checked(folder)
        except Exception as exc:  # any reason the study cannot be shown, shown to the user
            self.notify(f"Cannot open {folder}: {exc}", error=True)
            self.show_error(f"Cannot open {folder}", str(exc))

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
        """Open a study folder (through :mod:`core.study`; ``talus demo`` writes one), or
        show the first image of each camera of a plain folder of images (:mod:`core.io`)."""
        folder = Path(folder)
        if (folder / "study.json").is_file():
            self.open_study(folder)
            return
        summary = folder / "summary.json"
        if summary.is_file() and '"talus-synthetic-study"' in summary.read_text(
                encoding="utf-8", errors="replace"):
            raise ValueError(
                f"{folder}: a 'talus demo' folder without its study manifest (study.json): the "
                f"demo was cancelled or written by an older Talus; run 'talus demo --out "
                f"{folder} --regenerate' to write it again")
        if self.model is not None:
            raise ValueError("study: this window already shows a study; open another window")
        images = load_view_images(folder, n_views=len(self.panes))
        for pane, (name, image) in zip(self.panes, images, strict=False):
            pane.set_image(image)
            pane.setToolTip(name)
        self.statusBar().showMessage(
            f"Opened {folder}: " + ", ".join(name for name, _ in images)
        )

    def import_project_dialog(self):
        """*File → Import project…*: an Autoscoper or XMALab project as a new study, then opened
        (:class:`app.import_project_dialog.ImportProjectDialog`). Returns the dialog (shown)."""
        from .import_project_dialog import ImportProjectDialog

        dlg = ImportProjectDialog(self)
        dlg.setAttribute(QtCore.Qt.WidgetAttribute.WA_DeleteOnClose)
        dlg.open()
        self.last_dialog = dlg
        return dlg

    def _ask_open_demo(self) -> None:
        folder = QtWidgets.QFileDialog.getExistingDirectory(self, "Open study", os.getcwd())
        if folder:
            self._open_checked(folder)

    # ------------------------------------------------------------------ jobs
    def notify(self, text: str, *, error: bool = False, tag: str | None = None) -> None:
        """Log a message in the Messages dock; its last line shows in the status bar for 10 s.
        A ``tag`` equal to the last message's updates that message instead of adding one (a hand
        edit refused again: :mod:`app.hand_edits`).

        The dock is shown on the first message: small, or as a tab beside the plots. It comes to
        the front only for an ``error``: other messages (tracking started or ended, a flagged
        frame) leave the tab in front where it is — the Plots or the Frames the user watches
        while tracking runs — and are seen in the status bar."""
        dock = self.messages_dock
        front = [d for d in self.findChildren(QtWidgets.QDockWidget)  # the tabs in front now
                 if d is not dock and d.isVisible() and not d.visibleRegion().isEmpty()]
        if dock.isHidden():  # shown small (or as a tab beside the plots) until needed
            dock.show()
            if not self.tabifiedDockWidgets(dock):
                self.resizeDocks([dock], [80], QtCore.Qt.Orientation.Vertical)
        if error:
            dock.raise_()
        else:
            for other in self.tabifiedDockWidgets(dock):
                if other in front:
                    other.raise_()
        role = QtCore.Qt.ItemDataRole.UserRole
        last = self.messages.item(self.messages.count() - 1) if self.messages.count() else None
        if tag is None or last is None or last.data(role) != tag:
            self.messages.addItem("")
            last = self.messages.item(self.messages.count() - 1)
        last.setText(text.splitlines()[-1] if text else "")
        last.setToolTip(text)
        last.setData(role, tag)
        self.messages.scrollToBottom()
        self.statusBar().showMessage(text.splitlines()[-1] if text else "", 10000)

    def _on_failed(self, key: str, text: str) -> None:
        self.notify(f"{key} failed:\n{text}", error=True)

    def _on_progress(self, key: str, done: int, total: int) -> None:
        self.progress.setRange(0, max(total, 1))
        self.progress.setValue(done)
        self.progress.setFormat(f"{key} %v/%m")
        self.progress.setVisible(total > 1)
        self.cancel_button.setVisible(total > 1)

    def _on_busy(self, busy: bool) -> None:
        if not busy:  # every job ended: no bar, button or tracking line left behind
            self.set_feedback(None)

    def set_feedback(self, text: str | None) -> None:
        """Show a job's feedback line in the status bar; None takes it away with the progress bar
        and the cancel button."""
        if text is None:
            self.feedback.hide()
            self.feedback.clear()
            self.progress.hide()
            self.progress.reset()
            self.cancel_button.hide()
        else:
            self.feedback.setText(text)
            self.feedback.show()

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

    def _restore_geometry(self) -> None:
        """Open at the size of last time, else at 85 % of the screen's free area (at least 1024 × 700
        where the screen has it), centred."""
        saved = settings.get("window/geometry")
        if saved is not None and self.restoreGeometry(QtCore.QByteArray(saved)):
            return
        screen = QtWidgets.QApplication.primaryScreen()
        avail = screen.availableGeometry() if screen is not None else QtCore.QRect(0, 0, 1280, 800)
        w = min(max(int(avail.width() * 0.85), 1024), avail.width())
        h = min(max(int(avail.height() * 0.85), 700), avail.height())
        self.resize(w, h)
        self.move(avail.x() + (avail.width() - w) // 2, avail.y() + (avail.height() - h) // 2)

    def closeEvent(self, event: QtGui.QCloseEvent) -> None:
        s = self.session
        refused = s.edits.settle() if s is not None and s.writable else []  # hand edits still waiting
        if refused:  # said in Messages, which closing would take away unread: the window stays
            event.ignore()
            self.notify(f"The window stays open: the last edits of {', '.join(refused)} are not saved "
                        "(the message above says why). Close it again to leave without them.", error=True)
            return
        settings.set_value("window/geometry", self.saveGeometry())
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
    """Open the main window and run the Qt event loop; with ``demo`` (a study folder), open it
    once the window is on screen (a failure is shown in a dialog and on stderr)."""
    if sys.platform.startswith("linux") and os.environ.get("DISPLAY"):
        os.environ.setdefault("QT_QPA_PLATFORM", "xcb")  # VTK's interactor needs X11/GLX
    app = QtWidgets.QApplication.instance() or QtWidgets.QApplication(sys.argv[:1])
    app.setApplicationName("Talus")
    from .welcome import app_icon, show_welcome

    app.setWindowIcon(app_icon())
    window = MainWindow()
    if demo is None:  # no study asked for: the welcome page (start actions, CUDA check)
        show_welcome(window)
    window.show()  # first on screen; the study and the heavy modules load after its first paint

    def open_demo() -> None:
        window.statusBar().showMessage(f"Opening {demo} …")
        try:
            window.open_demo_study(demo)
        except Exception as exc:  # shown to the user, the window stays as it was
            print(f"talus gui: cannot open {demo}: {exc}", file=sys.stderr)
            window.statusBar().showMessage(f"Cannot open {demo}")
            window.show_error(f"Cannot open {demo}", str(exc))

    if demo is not None:
        window.after_first_paint(open_demo)
    return app.exec()
