"""Scripting the window, napari-style::

    from app import Viewer, run
    v = Viewer("demo_out")                 # a study folder written by `talus demo`
    v.set_pose("talus", T)                  # T_lab_from_bone at the current frame
    v.frame = 10
    v.screenshot("talus.png")
    run()                                   # the Qt event loop (not needed in IPython %gui qt)

The window and the script share one :class:`~app.model.ViewerModel`: anything set here shows at
once, and what the user does in the window is visible to the script.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PySide6 import QtWidgets

from .main_window import MainWindow
from .model import ViewerModel

__all__ = ["Viewer", "run"]


def _app() -> QtWidgets.QApplication:
    return QtWidgets.QApplication.instance() or QtWidgets.QApplication(["talus"])


class Viewer:
    """A Talus window driven from Python.

    Parameters
    ----------
    study : str, Path or ViewerModel, optional
        A demo study folder or a ready model.
    device : str, optional
        Warp device for the overlays.
    show : bool
        Show the window now.
    """

    def __init__(self, study: str | Path | ViewerModel | None = None, *,
                 device: str | None = None, show: bool = True) -> None:
        _app()
        self.window = MainWindow(device=device)
        if isinstance(study, ViewerModel):
            self.window.set_model(study)
        elif study is not None:
            self.window.open_demo_study(study)
        if show:
            self.window.show()

    @property
    def model(self) -> ViewerModel:
        if self.window.model is None:
            raise ValueError("study: no study is open in this viewer")
        return self.window.model

    @property
    def bones(self) -> list[str]:
        return [layer.name for layer in self.model.layers]

    @property
    def frame(self) -> int:
        return self.model.current_frame

    @frame.setter
    def frame(self, value: int) -> None:
        self.model.set_frame(value)

    def pose(self, bone: str | int, frame: int | None = None) -> np.ndarray:
        return self.model.pose(bone, frame)

    def set_pose(self, bone: str | int, T, frame: int | None = None) -> None:
        self.model.set_pose(bone, T, frame=frame, label="script")

    def screenshot(self, path: str | Path) -> Path:
        _app().processEvents()
        path = Path(path)
        if not self.window.grab().save(str(path)):
            raise ValueError(f"path: could not write a screenshot to {path}")
        return path

    def close(self) -> None:
        self.window.close()


def run() -> int:
    """Run the Qt event loop until the last window closes."""
    return _app().exec()
