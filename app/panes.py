"""Fluoroscope panes: an image through a window/level, DRR overlays, and mouse interaction.

Image display follows radiology viewers: an image is shown through a *window/level* mapping,
grey value ``0`` at ``level - window / 2`` and ``255`` at ``level + window / 2``. Image arrays are
indexed ``[row, col]``; pixel ``(u, v) = (col, row)`` is drawn centred at scene coordinates
``(u + 0.5, v + 0.5)``, so scene ``(x, y)`` is image ``(u, v) = (x - 0.5, y - 0.5)``.

Mouse: right-drag changes window/level (double click resets it), the wheel zooms about the
cursor, middle-drag pans; left-drag moves the selected bone in this view's plane and
Ctrl+left-drag turns it about the ray through its centre (signals ``pose_drag_*``, in image
coordinates; the window turns them into pose edits).

Correction: with a correction set (:meth:`FluoroPane.set_correction`: the study's saved
pipeline, raw counts → fluence), the pane's *Corrected* button shows the corrected frame instead
of the raw one, and *Usable* tints red the pixels outside the usable fluence range of tracking
(:data:`USABLE`: black outside the field or collimated, saturated), computed on the corrected
frame or on the raw frame divided by its full scale (``2**bits - 1``).
"""

from __future__ import annotations

import numpy as np
from PySide6 import QtCore, QtGui, QtWidgets

_PLACEHOLDER_SHAPE = (512, 512)
USABLE = (0.02, 0.999)  # relative fluence of usable pixels (core.tracking.cost.prepare_frame)
_MASK_KEY = "__usable__"
_DRAG_PIXELS = 200.0  # mouse travel that changes the window by a factor e / the level by a window


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
    """Graphics view of one image: fitted on resize until the user zooms; mouse handling."""

    drag_window_level = QtCore.Signal(float, float)  # (dx, dy) in screen pixels
    reset_window_level = QtCore.Signal()
    pose_drag_started = QtCore.Signal(str, float, float)  # kind ("move"|"rotate"), u, v
    pose_drag_moved = QtCore.Signal(str, float, float)
    pose_drag_finished = QtCore.Signal()

    def __init__(self, parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        self.setBackgroundBrush(QtGui.QColor(20, 20, 20))
        self.setRenderHint(QtGui.QPainter.RenderHint.SmoothPixmapTransform, False)
        self.setHorizontalScrollBarPolicy(QtCore.Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        self.setVerticalScrollBarPolicy(QtCore.Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        self.setTransformationAnchor(QtWidgets.QGraphicsView.ViewportAnchor.AnchorUnderMouse)
        self._last: QtCore.QPointF | None = None
        self._pan: QtCore.QPointF | None = None
        self._pose_kind: str | None = None
        self._zoomed = False

    def fit(self) -> None:
        if self.scene() is not None:
            self.fitInView(self.scene().sceneRect(), QtCore.Qt.AspectRatioMode.KeepAspectRatio)
            self._zoomed = False

    def resizeEvent(self, event: QtGui.QResizeEvent) -> None:
        super().resizeEvent(event)
        if not self._zoomed:
            self.fit()

    def image_uv(self, pos: QtCore.QPointF) -> tuple[float, float]:
        """Image ``(u, v)`` under a viewport position."""
        p = self.mapToScene(pos.toPoint())
        return p.x() - 0.5, p.y() - 0.5

    def wheelEvent(self, event: QtGui.QWheelEvent) -> None:
        factor = 1.25 ** (event.angleDelta().y() / 120.0)
        self.scale(factor, factor)
        self._zoomed = True
        event.accept()

    def mousePressEvent(self, event: QtGui.QMouseEvent) -> None:
        button = event.button()
        if button == QtCore.Qt.MouseButton.RightButton:
            self._last = event.position()
        elif button == QtCore.Qt.MouseButton.MiddleButton:
            self._pan = event.position()
        elif button == QtCore.Qt.MouseButton.LeftButton:
            ctrl = event.modifiers() & QtCore.Qt.KeyboardModifier.ControlModifier
            self._pose_kind = "rotate" if ctrl else "move"
            self.pose_drag_started.emit(self._pose_kind, *self.image_uv(event.position()))
        else:
            super().mousePressEvent(event)
            return
        event.accept()

    def mouseMoveEvent(self, event: QtGui.QMouseEvent) -> None:
        if self._last is not None:
            delta = event.position() - self._last
            self._last = event.position()
            self.drag_window_level.emit(delta.x(), delta.y())
        elif self._pan is not None:
            delta = event.position() - self._pan
            self._pan = event.position()
            h, v = self.horizontalScrollBar(), self.verticalScrollBar()
            h.setValue(h.value() - int(delta.x()))
            v.setValue(v.value() - int(delta.y()))
            self._zoomed = True
        elif self._pose_kind is not None:
            self.pose_drag_moved.emit(self._pose_kind, *self.image_uv(event.position()))
        else:
            super().mouseMoveEvent(event)
            return
        event.accept()

    def mouseReleaseEvent(self, event: QtGui.QMouseEvent) -> None:
        button = event.button()
        if button == QtCore.Qt.MouseButton.RightButton:
            self._last = None
        elif button == QtCore.Qt.MouseButton.MiddleButton:
            self._pan = None
        elif button == QtCore.Qt.MouseButton.LeftButton and self._pose_kind is not None:
            self._pose_kind = None
            self.pose_drag_finished.emit()
        super().mouseReleaseEvent(event)

    def mouseDoubleClickEvent(self, event: QtGui.QMouseEvent) -> None:
        if event.button() == QtCore.Qt.MouseButton.RightButton:
            self.reset_window_level.emit()
        else:
            self.fit()
        super().mouseDoubleClickEvent(event)


class FluoroPane(QtWidgets.QWidget):
    """One fluoroscope view: a title and an image shown through a window/level."""

    window_level_changed = QtCore.Signal(float, float)
    display_changed = QtCore.Signal()  # raw/corrected switched or the correction replaced

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
        self.corrected_button = QtWidgets.QToolButton()
        self.corrected_button.setText("Corrected")
        self.corrected_button.setCheckable(True)
        self.corrected_button.setToolTip("show the frame corrected by the study's saved correction "
                                         "(dark, flatfield, distortion) instead of the raw frame")
        self.corrected_button.setVisible(False)
        self.corrected_button.toggled.connect(lambda _: self._redisplay())
        self.usable_button = QtWidgets.QToolButton()
        self.usable_button.setText("Usable")
        self.usable_button.setCheckable(True)
        self.usable_button.setToolTip("tint red the pixels tracking cannot use (outside the usable fluence "
                                      "range: outside the field, collimated or saturated)")
        self.usable_button.toggled.connect(lambda _: self._draw_mask())
        head = QtWidgets.QHBoxLayout()
        head.setContentsMargins(0, 0, 0, 0)
        head.addWidget(self._title, 1)
        head.addWidget(self.corrected_button)
        head.addWidget(self.usable_button)
        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(2, 2, 2, 2)
        layout.addLayout(head)
        layout.addWidget(self.view, 1)
        self._raw: np.ndarray | None = None
        self._correct = None
        self._full_scale: float | None = None
        self._image: np.ndarray | None = None
        self._window, self._level = 1.0, 0.5
        self._overlays: dict = {}
        self._markers: list = []
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
        self, image: np.ndarray, *, window: float | None = None, level: float | None = None,
        keep_view: bool = False,
    ) -> None:
        """Show a 2-D array ``[row, col]`` (or ``[row, col, 3|4]`` colour, shown as grey).

        ``keep_view`` keeps the zoom and window/level (stepping through frames)."""
        arr = np.asarray(image)
        if arr.ndim == 3 and arr.shape[2] in (3, 4):
            arr = arr[..., :3].mean(axis=2)
        if arr.ndim != 2 or arr.size == 0:
            raise ValueError(f"image: expected a 2-D array [row, col], got shape {arr.shape}")
        if not (np.issubdtype(arr.dtype, np.number) and not np.iscomplexobj(arr)):
            raise ValueError(f"image: expected a real numeric array, got dtype {arr.dtype}")
        self._raw = arr
        if self._correct is not None and self.corrected_button.isChecked():
            arr = np.asarray(self._correct(arr), dtype=np.float32)
        self._show(arr, window=window, level=level, keep_view=keep_view)

    def _show(self, arr: np.ndarray, *, window=None, level=None, keep_view=False) -> None:
        same_shape = self._image is not None and self._image.shape == arr.shape
        self._image = arr
        self._note.setText("")
        if keep_view and same_shape and window is None and level is None:
            self.set_window_level(self._window, self._level)
            self._draw_mask()
            return
        auto_w, auto_l = auto_window_level(arr)
        self._scene.setSceneRect(0, 0, arr.shape[1], arr.shape[0])
        self.set_window_level(
            auto_w if window is None else window, auto_l if level is None else level
        )
        self.view.fit()
        self._draw_mask()

    # -- correction and usable pixels
    @property
    def raw_image(self) -> np.ndarray | None:
        """The frame as given to :meth:`set_image` (before any correction)."""
        return self._raw

    @property
    def showing_corrected(self) -> bool:
        return self._correct is not None and self.corrected_button.isChecked()

    def set_correction(self, correct, *, full_scale: float | None = None, corrected: bool = True) -> None:
        """``correct(raw) -> fluence`` (None: none saved; the button hides), ``full_scale`` of the
        raw counts (``2**bits - 1``) for the usable mask of raw frames; ``corrected`` toggles it on."""
        self._correct = correct
        self._full_scale = None if full_scale is None else float(full_scale)
        self.corrected_button.setVisible(correct is not None)
        self.corrected_button.blockSignals(True)
        self.corrected_button.setChecked(bool(corrected) and correct is not None)
        self.corrected_button.blockSignals(False)
        self._redisplay()

    def set_corrected(self, on: bool) -> None:
        """Show the corrected (True) or the raw frame."""
        self.corrected_button.setChecked(bool(on))

    def _redisplay(self) -> None:
        if self._raw is not None:
            arr = self._raw
            if self.showing_corrected:
                arr = np.asarray(self._correct(arr), dtype=np.float32)
            self._show(arr)
        self.display_changed.emit()

    def marker_input(self) -> tuple[np.ndarray, np.ndarray | None] | None:
        """What the markers layer looks for beads in: ``(image, mask)`` of the frame shown — the
        corrected frame (its usable, finite pixels as the mask: beads are found where tracking can
        see) when the pane shows corrected, else the raw frame (no mask) — so the circles drawn land
        on the image under them. None while no frame is shown."""
        if self._image is None:
            return None
        img = np.asarray(self._image, np.float32)
        if not self.showing_corrected:
            return img, None
        mask = np.isfinite(img) & (img > USABLE[0]) & (img < USABLE[1])
        return img, mask

    def usable_mask(self) -> np.ndarray | None:
        """True where tracking can use the pixel (the shown corrected frame, or the raw frame over its
        full scale); None without a frame or, for a raw frame, without a full scale."""
        if self._image is None:
            return None
        if self.showing_corrected:
            x = np.asarray(self._image, np.float32)
        elif self._full_scale:
            x = np.asarray(self._raw, np.float32) / np.float32(self._full_scale)
        else:
            return None
        return (x > USABLE[0]) & (x < USABLE[1])

    def _draw_mask(self) -> None:
        m = self.usable_mask() if self.usable_button.isChecked() else None
        if m is None:
            self.hide_overlay(_MASK_KEY)
            return
        rgba = np.zeros((*m.shape, 4), np.uint8)
        rgba[~m] = (255, 0, 0, 110)
        self.set_overlay(_MASK_KEY, rgba, (0, 0, m.shape[1], m.shape[0]), 1.0)

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
        self._image = self._raw = None
        self.hide_overlay(_MASK_KEY)
        self._scene.setSceneRect(0, 0, _PLACEHOLDER_SHAPE[1], _PLACEHOLDER_SHAPE[0])
        self.set_window_level(1.0, 0.5)
        self._note.setText("No image loaded")
        self._note.setScale(3.0)
        self._note.setPos(20, 20)
        self.view.fit()

    def show_unreadable(self, text: str) -> None:
        """The placeholder with ``text`` (a frame whose file cannot be read), not the last frame."""
        self.clear()
        self._note.setText(text)
        self._note.setScale(2.0)

    # -- overlays
    def set_overlay(self, key, rgba: np.ndarray, roi: tuple[int, int, int, int],
                    scale: float) -> None:
        """Show an RGBA (H, W, 4) uint8 overlay whose pixel ``[r, c]`` covers the full-resolution
        block starting at ``(u0 + c * scale, v0 + r * scale)`` of ``roi = (u0, v0, w, h)``."""
        rgba = np.ascontiguousarray(rgba, dtype=np.uint8)
        if rgba.ndim != 3 or rgba.shape[2] != 4:
            raise ValueError(f"rgba: expected (H, W, 4) uint8, got {rgba.shape}")
        h, w = rgba.shape[:2]
        qimg = QtGui.QImage(rgba.data, w, h, 4 * w, QtGui.QImage.Format.Format_RGBA8888).copy()
        item = self._overlays.get(key)
        if item is None:
            item = self._scene.addPixmap(QtGui.QPixmap())
            item.setZValue(10)
            self._overlays[key] = item
        item.setPixmap(QtGui.QPixmap.fromImage(qimg))
        item.setScale(float(scale))
        item.setPos(float(roi[0]), float(roi[1]))
        item.setVisible(True)

    def hide_overlay(self, key) -> None:
        item = self._overlays.get(key)
        if item is not None:
            item.setVisible(False)

    def overlay_keys(self) -> list:
        return [k for k, item in self._overlays.items() if item.isVisible() and k != _MASK_KEY]

    def overlay_image(self, key) -> QtGui.QImage | None:
        item = self._overlays.get(key)
        return None if item is None else item.pixmap().toImage()

    def overlay_geometry(self, key) -> tuple[float, float, float] | None:
        """``(x, y, scale)`` of an overlay in scene coordinates."""
        item = self._overlays.get(key)
        return None if item is None else (item.pos().x(), item.pos().y(), item.scale())

    # -- markers
    def set_markers(self, uv, radius) -> None:
        """Draw bead markers: circles of ``radius`` px centred at image ``(u, v)``."""
        for item in self._markers:
            self._scene.removeItem(item)
        self._markers = []
        pen = QtGui.QPen(QtGui.QColor(0, 255, 255))
        pen.setCosmetic(True)
        pen.setWidthF(1.5)
        for (u, v), r in zip(np.asarray(uv, float).reshape(-1, 2), np.ravel(radius), strict=True):
            item = self._scene.addEllipse(u + 0.5 - r, v + 0.5 - r, 2 * r, 2 * r, pen)
            item.setZValue(20)
            self._markers.append(item)

    @property
    def marker_count(self) -> int:
        return len(self._markers)

    @property
    def markers_uv(self) -> np.ndarray:
        """Image ``(u, v)`` of the bead markers drawn, ``(N, 2)``."""
        c = [item.rect().center() for item in self._markers]
        return np.array([[p.x() - 0.5, p.y() - 0.5] for p in c]).reshape(-1, 2)

    def _on_drag(self, dx: float, dy: float) -> None:
        if self._image is not None:
            window = self._window * float(np.exp(dx / _DRAG_PIXELS))
            self.set_window_level(window, self._level - dy * self._window / _DRAG_PIXELS)


def attach_study_correction(panes, study, trial_name: str) -> str:
    """Give each pane the correction saved with the calibration the trial uses
    (:func:`core.study.calibrations.trial_correction`) and the raw full scale of its view's bit
    depth; the panes then show corrected frames. Returns how the frames are shown."""
    from core.study.calibrations import trial_correction

    views = study.manifest["trials"][trial_name]["views"]
    scales = [float(2 ** int(v.get("bit_depth") or 16) - 1) for v in views]
    try:
        fns = trial_correction(study, trial_name)
    except (ValueError, OSError):
        fns = None
    for k, pane in enumerate(panes):
        fn = None if fns is None or k >= len(fns) else fns[k]
        pane.set_correction(fn, full_scale=scales[k] if k < len(scales) else None)
    if fns is None:
        return "raw frames (no saved correction)"
    return f"corrected with calibration {study.manifest['trials'][trial_name]['calibration']}"
