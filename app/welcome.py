"""The welcome page: what the window shows when it starts without a study.

Open a study, open the demo study (written once into the user's data folder), import an
Autoscoper project, or reopen a recent study; below, which device computes DRRs and tracking.
The CUDA check (:func:`app.device_check.probe`, which initialises Warp) runs in a worker thread
after the window is on screen, so it never delays the window. The page gives way to the study
as soon as one is shown (:meth:`WelcomePage.study_shown`).
"""

from __future__ import annotations

import os
from pathlib import Path

from PySide6 import QtCore, QtGui, QtWidgets

from core import __version__

from . import settings
from .device_check import DeviceInfo, describe, probe
from .workers import WorkerPool

__all__ = ["DEMO_DIR_ENV", "WelcomePage", "app_icon", "demo_folder", "show_welcome"]

DEMO_DIR_ENV = "TALUS_DEMO_DIR"
ICON = Path(__file__).resolve().parent / "icons" / "talus.png"


def app_icon() -> QtGui.QIcon:
    """The application icon (``app/icons/talus.png``, drawn by installer/make_icons.py)."""
    return QtGui.QIcon(str(ICON))


def demo_folder() -> Path:
    """Where the welcome page keeps the demo study: ``$TALUS_DEMO_DIR``, else ``demo`` in the
    user's application data folder."""
    env = os.environ.get(DEMO_DIR_ENV)
    if env:
        return Path(env).expanduser()
    base = QtCore.QStandardPaths.writableLocation(
        QtCore.QStandardPaths.StandardLocation.AppLocalDataLocation)
    return Path(base or Path.home() / ".talus") / "demo"


def _demo_complete(folder: Path) -> bool:
    """A complete demo study is in ``folder`` (its calibration session is not needed to open it)."""
    from .demo_cache import complete_demo

    return complete_demo(folder, calibration_session=False) is not None


def _write_demo(folder: str, options: dict, progress=None, cancel=None) -> str:
    from .demo_cache import write_demo

    def report(done, total, *_stage) -> None:  # the calibration session's steps add a stage name
        if progress is not None:
            progress(done, total)

    write_demo(folder, **options, progress=report, cancel=cancel)
    return folder


class WelcomePage(QtWidgets.QFrame):
    """Start actions, recent studies and the compute device, for a window without a study."""

    device_checked = QtCore.Signal(object)  # DeviceInfo

    def __init__(self, window, *, check_device: bool = True) -> None:
        super().__init__()
        self.window = window
        self.setObjectName("welcome")
        self.demo_options: dict = {}  # make_demo_study options (the demo's defaults when empty)
        self.device_info: DeviceInfo | None = None
        self.pool = WorkerPool(self)
        self.pool.finished.connect(self._finished)
        self.pool.failed.connect(self._failed)
        self.pool.progress.connect(self._progress)

        outer = QtWidgets.QVBoxLayout(self)
        outer.addStretch(1)
        column = QtWidgets.QVBoxLayout()
        row = QtWidgets.QHBoxLayout()
        logo = QtWidgets.QLabel()
        logo.setPixmap(app_icon().pixmap(96, 96))
        row.addWidget(logo)
        title = QtWidgets.QLabel(f"<h1>Talus {__version__}</h1>"
                                 "<p>Biplane fluoroscopy bone tracking</p>")
        row.addWidget(title, 1)
        column.addLayout(row)

        buttons = QtWidgets.QHBoxLayout()
        self.open_button = QtWidgets.QPushButton("Open a study…")
        self.demo_button = QtWidgets.QPushButton("Open the demo")
        self.demo_button.setToolTip("A synthetic foot study (three bones, two cameras), written once "
                                    f"to {demo_folder()}")
        self.import_button = QtWidgets.QPushButton("Import a project…")
        self.import_button.setToolTip("Make a study from an Autoscoper (.cfg) or XMALab (.xma) project")
        for b, name in ((self.open_button, "open"), (self.demo_button, "demo"),
                        (self.import_button, "import")):
            b.setObjectName(f"welcome-{name}")
            b.setMinimumHeight(40)
            buttons.addWidget(b)
        column.addLayout(buttons)
        self.open_button.clicked.connect(self.window._ask_open_demo)
        self.demo_button.clicked.connect(self.open_demo)
        self.import_button.clicked.connect(self.import_project)

        column.addWidget(QtWidgets.QLabel("<b>Recent studies</b>"))
        self.recent = QtWidgets.QListWidget()
        self.recent.setObjectName("welcome-recent")
        self.recent.setMaximumHeight(160)
        self.recent.itemActivated.connect(lambda item: self._open(item.text()))
        self.recent.itemClicked.connect(lambda item: self._open(item.text()))
        column.addWidget(self.recent)
        self.fill_recent()

        self.status = QtWidgets.QLabel()  # progress of the demo, errors
        self.status.setObjectName("welcome-status")
        self.status.setWordWrap(True)
        column.addWidget(self.status)
        self.device = QtWidgets.QLabel("Checking for a CUDA GPU…")
        self.device.setObjectName("welcome-device")
        self.device.setWordWrap(True)
        self.device.setFrameShape(QtWidgets.QFrame.Shape.StyledPanel)
        self.device.setMargin(8)
        column.addWidget(self.device)

        holder = QtWidgets.QHBoxLayout()
        holder.addStretch(1)
        box = QtWidgets.QWidget()
        box.setLayout(column)
        box.setMaximumWidth(720)
        box.setMinimumWidth(480)
        holder.addWidget(box, 4)
        holder.addStretch(1)
        outer.addLayout(holder)
        outer.addStretch(2)
        if check_device:
            self.check_device()

    # ------------------------------------------------------------------ device
    def check_device(self) -> None:
        """Ask Warp for CUDA devices in a worker thread; the label changes when it answers."""
        self.device.setText("Checking for a CUDA GPU…")
        self.pool.submit("device", probe)

    def show_device(self, info: DeviceInfo) -> None:
        self.device_info = info
        level, text = describe(info)
        colour = {"gpu": "#1b5e20", "cpu": "#8a4b00", "error": "#b00020"}[level]
        self.device.setProperty("level", level)
        self.device.setStyleSheet(f"color: {colour};")
        self.device.setText(text)
        self.device_checked.emit(info)

    # ------------------------------------------------------------------ actions
    def fill_recent(self) -> None:
        self.recent.clear()
        for path in settings.recent():
            self.recent.addItem(path)
        if not self.recent.count():
            item = QtWidgets.QListWidgetItem("No study opened yet")
            item.setFlags(QtCore.Qt.ItemFlag.NoItemFlags)
            self.recent.addItem(item)

    def _open(self, folder: str) -> None:
        if self.window.model is None and folder in settings.recent():
            self.window._open_checked(folder)

    def open_demo(self) -> None:
        """Open the demo study; write it first (in a worker, with progress) if it is not there."""
        folder = demo_folder()
        if _demo_complete(folder):
            self.window._open_checked(str(folder))
            return
        self.demo_button.setEnabled(False)
        self.status.setText(f"Writing the demo study to {folder} …")
        self.pool.submit("demo", _write_demo, str(folder), dict(self.demo_options))

    def import_project(self) -> None:
        """Autoscoper .cfg or XMALab .xma → a new study folder beside it (asked for), then opened."""
        cfg, _ = QtWidgets.QFileDialog.getOpenFileName(
            self, "Import a project", os.getcwd(),
            "Autoscoper or XMALab project (*.cfg *.xma);;Autoscoper trial (*.cfg);;XMALab project (*.xma)")
        if not cfg:
            return
        default = str(Path(cfg).with_suffix("")) + "_study"
        out, _ = QtWidgets.QFileDialog.getSaveFileName(
            self, "New study folder", default, "Study folder (*)")
        if not out:
            return

        def run() -> None:
            from core.study.import_project import import_project

            if (Path(out) / "study.json").exists():
                raise ValueError(f"{out} already holds a study: choose a new folder")
            with import_project(cfg, out):
                pass
            self.window.open_study(out)

        self.window._guard(run)

    # ------------------------------------------------------------------ workers
    def _finished(self, key: str, result) -> None:
        if key == "device":
            self.show_device(result)
        elif key == "demo":
            self.demo_button.setEnabled(True)
            self.status.setText("")
            self.window._open_checked(result)

    def _failed(self, key: str, text: str) -> None:
        if key == "device":
            self.show_device(DeviceInfo(error=text.strip().splitlines()[-1]))
        else:
            self.demo_button.setEnabled(True)
            self.status.setText(f"The demo study could not be written: {text.strip().splitlines()[-1]}")
            self.window.notify(f"demo failed:\n{text}")

    def _progress(self, key: str, done: int, total: int) -> None:
        if key == "demo":
            self.status.setText(f"Writing the demo study to {demo_folder()}: {done}/{total}")

    def study_shown(self) -> None:
        """A study is in the window: give it the room."""
        self.hide()
        self.window.splitter.show()

    def shutdown(self) -> None:
        self.pool.shutdown(wait=False)


def show_welcome(window, *, check_device: bool = True) -> WelcomePage:
    """Put the welcome page in ``window`` (a :class:`app.main_window.MainWindow` without a study)
    in place of the panes; it is ``window.welcome``."""
    page = WelcomePage(window, check_device=check_device)
    window.welcome = page
    window.splitter.hide()
    window._central_layout.insertWidget(0, page, 1)
    window.destroyed.connect(page.shutdown)
    return page
