"""Timeline: frame slider, play/pause, frame stepping, and a per-frame status strip.

Frames are numbered from 0, as in the API and the journal. The strip colours each frame by its
status (legend beside it: keyframe, tracked, flagged, edited); hovering it tells the frame's status
and the reasons for review (``reason_for(frame)``, set by the window)."""

from __future__ import annotations

import numpy as np
from PySide6 import QtCore, QtGui, QtWidgets

from .model import ViewerModel

__all__ = ["Timeline"]

# status codes of the strip: 0 untracked, 1 keyframe, 2 tracked, 3 flagged for review, 4 edited
_STATUS_COLORS = np.array([[60, 60, 60], [240, 200, 60], [70, 170, 90], [220, 70, 60], [80, 140, 230]],
                          np.uint8)
_STATUS_NAMES = ("untracked", "keyframe", "tracked", "flagged", "edited")


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
        self.strip.setMouseTracking(True)
        self.strip.installEventFilter(self)
        self.reason_for = None  # callable(frame) -> str: the strip's tooltip text
        self.status = np.zeros(model.n_frames, np.uint8)
        legend = QtWidgets.QHBoxLayout()
        legend.setSpacing(8)
        for code in (1, 2, 3, 4):
            r, g, b = (int(v) for v in _STATUS_COLORS[code])
            lab = QtWidgets.QLabel(f"<span style='color:rgb({r},{g},{b})'>■</span> {_STATUS_NAMES[code]}")
            lab.setObjectName(f"legend-{_STATUS_NAMES[code]}")
            legend.addWidget(lab)
        legend.addStretch(1)
        top = QtWidgets.QHBoxLayout()
        top.addWidget(self.play_button)
        top.addWidget(self.slider, 1)
        top.addWidget(self.label)
        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(4, 2, 4, 2)
        layout.setSpacing(1)
        layout.addLayout(top)
        layout.addWidget(self.strip)
        layout.addLayout(legend)
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
        self.label.setText(f"frame {frame} of 0–{self.model.n_frames - 1}")

    def _on_pose(self, bone: int, frame: int) -> None:
        if frame in self.model.layers[bone].keyframes and self.status[frame] == 0:
            self.status[frame] = 1
            self.refresh_status()

    def set_status(self, status) -> None:
        """Per-frame codes: 0 untracked, 1 keyframe, 2 tracked, 3 flagged for review, 4 edited."""
        s = np.asarray(status, dtype=np.uint8)
        if s.shape != (self.model.n_frames,) or s.max(initial=0) > 4:
            raise ValueError(f"status: expected {self.model.n_frames} codes in 0..4")
        self.status = s.copy()
        self.refresh_status()

    def refresh_status(self) -> None:
        rgb = np.ascontiguousarray(_STATUS_COLORS[self.status][None, :, :])
        img = QtGui.QImage(rgb.data, rgb.shape[1], 1, 3 * rgb.shape[1],
                           QtGui.QImage.Format.Format_RGB888).copy()
        self.strip.setPixmap(QtGui.QPixmap.fromImage(img))

    def frame_at(self, x: float) -> int:
        """The frame under horizontal position ``x`` of the strip."""
        w = max(self.strip.width(), 1)
        return int(np.clip(int(x / w * self.model.n_frames), 0, self.model.n_frames - 1))

    def tooltip(self, frame: int) -> str:
        text = f"frame {frame}: {_STATUS_NAMES[int(self.status[frame])]}"
        if self.reason_for is not None:
            more = self.reason_for(frame)
            if more:
                text += "\n" + more
        return text

    def eventFilter(self, obj, event) -> bool:
        if obj is self.strip and event.type() == QtCore.QEvent.Type.ToolTip:
            f = self.frame_at(event.pos().x())
            QtWidgets.QToolTip.showText(event.globalPos(), self.tooltip(f), self.strip)
            return True
        if obj is self.strip and event.type() == QtCore.QEvent.Type.MouseButtonPress:
            self.model.set_frame(self.frame_at(event.position().x()))
            return True
        return super().eventFilter(obj, event)
