"""The 3D lab scene (pyvistaqt): lab axes, X-ray sources, detector planes, bone meshes."""

from __future__ import annotations

import numpy as np
from PySide6 import QtCore, QtGui, QtWidgets


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
