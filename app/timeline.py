"""Timeline: frame slider, play/pause, frame stepping, and a per-frame status strip."""

from __future__ import annotations

import numpy as np
from PySide6 import QtCore, QtGui, QtWidgets

from .model import ViewerModel

__all__ = ["Timeline"]

# status codes of the strip: 0 untracked, 1 keyframe, 2 tracked, 3 flagged for review
_STATUS_COLORS = np.array([[60, 60, 60], [240, 200, 60], [70, 170, 90], [220, 70, 60]], np.uint8)


class Timeline(QtWidgets.QWidget):
    """Bound to ``model.current_frame``; plays at ``fps`` frames per second."""

    def __init__(self, model: ViewerModel, parent: QtWidgets.QWidget | None = None, *,
                 fps: float = 25.0) -> None:
        super().__init__(parent)
        self.model = model
        self.play_button = QtWidgets.QToolButton()
        self.play_button.setText("▶")
        self.play_button.setToolTip("Play / pause (Space)")
        self.play_button.setCheckable(True)
        self.slider = QtWidgets.QSlider(QtCore.Qt.Orientation.Horizontal)
        self.slider.setRange(0, model.n_frames - 1)
        self.label = QtWidgets.QLabel()
        self.label.setMinimumWidth(90)
        self.strip = QtWidgets.QLabel()
        self.strip.setFixedHeight(8)
        self.strip.setScaledContents(True)
        self.status = np.zeros(model.n_frames, np.uint8)
        top = QtWidgets.QHBoxLayout()
        top.addWidget(self.play_button)
        top.addWidget(self.slider, 1)
        top.addWidget(self.label)
        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(4, 2, 4, 2)
        layout.setSpacing(1)
        layout.addLayout(top)
        layout.addWidget(self.strip)
        self._timer = QtCore.QTimer(self)
        self._timer.setInterval(int(1000 / fps))
        self._timer.timeout.connect(self._tick)
        self.play_button.toggled.connect(self.set_playing)
        self.slider.valueChanged.connect(model.set_frame)
        model.current_frame_changed.connect(self._on_frame)
        model.pose_changed.connect(self._on_pose)
        self._on_frame(model.current_frame)
        self.refresh_status()

    @property
    def playing(self) -> bool:
        return self._timer.isActive()

    def set_playing(self, on: bool) -> None:
        if on:
            self._timer.start()
        else:
            self._timer.stop()
        self.play_button.setChecked(on)
        self.play_button.setText("⏸" if on else "▶")

    def toggle(self) -> None:
        self.set_playing(not self.playing)

    def _tick(self) -> None:
        f = self.model.current_frame + 1
        self.model.set_frame(0 if f >= self.model.n_frames else f)

    def _on_frame(self, frame: int) -> None:
        self.slider.blockSignals(True)
        self.slider.setValue(frame)
        self.slider.blockSignals(False)
        self.label.setText(f"frame {frame + 1} / {self.model.n_frames}")

    def _on_pose(self, bone: int, frame: int) -> None:
        if frame in self.model.layers[bone].keyframes and self.status[frame] == 0:
            self.status[frame] = 1
            self.refresh_status()

    def set_status(self, status) -> None:
        """Per-frame codes: 0 untracked, 1 keyframe, 2 tracked, 3 flagged for review."""
        s = np.asarray(status, dtype=np.uint8)
        if s.shape != (self.model.n_frames,) or s.max(initial=0) > 3:
            raise ValueError(f"status: expected {self.model.n_frames} codes in 0..3")
        self.status = s.copy()
        self.refresh_status()

    def refresh_status(self) -> None:
        rgb = np.ascontiguousarray(_STATUS_COLORS[self.status][None, :, :])
        img = QtGui.QImage(rgb.data, rgb.shape[1], 1, 3 * rgb.shape[1],
                           QtGui.QImage.Format.Format_RGB888).copy()
        self.strip.setPixmap(QtGui.QPixmap.fromImage(img))
