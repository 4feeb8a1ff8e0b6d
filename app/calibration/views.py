"""Widgets of the calibration wizard: an image with points, labels and vectors that reports
clicks in pixel coordinates, and matplotlib figures shown as pixmaps."""

from __future__ import annotations

import numpy as np
from PySide6 import QtCore, QtGui, QtWidgets

__all__ = ["FigureView", "ImageView", "figure_pixmap"]


def _gray(img: np.ndarray, levels=None) -> QtGui.QImage:
    a = np.asarray(img, float)
    fin = np.isfinite(a)
    if levels is not None:
        lo, hi = levels
    else:
        lo, hi = (np.percentile(a[fin], [1, 99]) if fin.any() else (0.0, 1.0))
    g = np.clip((np.where(fin, a, lo) - lo) / max(hi - lo, 1e-12), 0, 1)
    g8 = np.ascontiguousarray((255 * g).astype(np.uint8))
    q = QtGui.QImage(g8.data, g8.shape[1], g8.shape[0], g8.strides[0], QtGui.QImage.Format.Format_Grayscale8)
    return q.copy()


class ImageView(QtWidgets.QWidget):
    """A frame scaled to fit, with ``points`` (u, v) drawn as circles (``colors``, ``labels``),
    optional ``vectors`` from the points, and one ``selected`` point. ``clicked(u, v)`` gives
    the pixel under a left click; :meth:`widget_pos` maps a pixel back (for tests and tools)."""

    clicked = QtCore.Signal(float, float)

    def __init__(self, parent=None) -> None:
        super().__init__(parent)
        self.setMinimumSize(240, 240)
        self._img: QtGui.QImage | None = None
        self._shape = (1, 1)
        self.points = np.zeros((0, 2))
        self.colors: list = []
        self.labels: list = []
        self.vectors: np.ndarray | None = None
        self.vector_scale = 1.0
        self.selected: int | None = None
        self.caption = ""

    def set_image(self, img: np.ndarray | None, levels: tuple[float, float] | None = None) -> None:
        """Show ``img``, grey levels from ``levels`` (black, white) or its 1st-99th percentiles."""
        self._img = None if img is None else _gray(img, levels)
        self._shape = (1, 1) if img is None else np.asarray(img).shape[:2]
        self.update()

    def set_rgb(self, rgb: np.ndarray) -> None:
        """Show an ``(H, W, 3)`` uint8 image as it is."""
        a = np.ascontiguousarray(rgb, dtype=np.uint8)
        q = QtGui.QImage(a.data, a.shape[1], a.shape[0], a.strides[0], QtGui.QImage.Format.Format_RGB888)
        self._img, self._shape = q.copy(), a.shape[:2]
        self.update()

    def set_points(self, uv, *, colors=None, labels=None, vectors=None, vector_scale: float = 1.0) -> None:
        self.points = np.asarray(uv, float).reshape(-1, 2)
        self.colors = list(colors) if colors is not None else ["#00e0ff"] * len(self.points)
        self.labels = list(labels) if labels is not None else []
        self.vectors = None if vectors is None else np.asarray(vectors, float).reshape(-1, 2)
        self.vector_scale = float(vector_scale)
        self.selected = None
        self.update()

    # geometry: the image fills the widget keeping its aspect, centred
    def _fit(self) -> tuple[float, float, float]:
        h, w = self._shape
        s = min(self.width() / w, self.height() / h)
        return s, (self.width() - s * w) / 2, (self.height() - s * h) / 2

    def widget_pos(self, u: float, v: float) -> QtCore.QPoint:
        s, ox, oy = self._fit()
        return QtCore.QPoint(round(ox + s * (u + 0.5)), round(oy + s * (v + 0.5)))

    def pixel_at(self, x: float, y: float) -> tuple[float, float]:
        s, ox, oy = self._fit()
        return (x - ox) / s - 0.5, (y - oy) / s - 0.5

    def nearest(self, u: float, v: float, max_px: float = 12.0) -> int | None:
        if not len(self.points):
            return None
        d = np.hypot(self.points[:, 0] - u, self.points[:, 1] - v)
        k = int(np.argmin(d))
        return k if d[k] * self._fit()[0] <= max_px else None

    def mousePressEvent(self, ev: QtGui.QMouseEvent) -> None:
        if ev.button() == QtCore.Qt.MouseButton.LeftButton:
            u, v = self.pixel_at(ev.position().x(), ev.position().y())
            self.clicked.emit(u, v)
        super().mousePressEvent(ev)

    def paintEvent(self, ev) -> None:
        p = QtGui.QPainter(self)
        p.fillRect(self.rect(), QtGui.QColor("#202020"))
        if self._img is not None:
            s, ox, oy = self._fit()
            h, w = self._shape
            p.drawImage(QtCore.QRectF(ox, oy, s * w, s * h), self._img)
            p.setRenderHint(QtGui.QPainter.RenderHint.Antialiasing)
            r = max(2.0, 3.0 * s)
            for k, (u, v) in enumerate(self.points):
                c = QtGui.QColor(self.colors[k] if k < len(self.colors) else "#00e0ff")
                x, y = ox + s * (u + 0.5), oy + s * (v + 0.5)
                if self.vectors is not None and k < len(self.vectors):
                    d = self.vectors[k] * self.vector_scale * s
                    p.setPen(QtGui.QPen(QtGui.QColor("#ffb000"), 1.2))
                    p.drawLine(QtCore.QPointF(x, y), QtCore.QPointF(x + d[0], y + d[1]))
                p.setPen(QtGui.QPen(c, 3.0 if k == self.selected else 1.2))
                p.drawEllipse(QtCore.QPointF(x, y), r * (1.8 if k == self.selected else 1.0),
                              r * (1.8 if k == self.selected else 1.0))
                if k < len(self.labels) and self.labels[k]:
                    p.drawText(QtCore.QPointF(x + r + 1, y - r - 1), str(self.labels[k]))
        if self.caption:
            flags = QtCore.Qt.AlignmentFlag.AlignTop | QtCore.Qt.AlignmentFlag.AlignLeft
            flags |= QtCore.Qt.TextFlag.TextWordWrap
            box = p.boundingRect(self.rect().adjusted(6, 4, -6, -4), flags, self.caption)
            p.fillRect(box.adjusted(-4, -2, 4, 2), QtGui.QColor(0, 0, 0, 170))
            p.setPen(QtGui.QColor("white"))
            p.drawText(box, flags, self.caption)
        p.end()


def figure_pixmap(fig) -> QtGui.QPixmap:
    """A matplotlib figure (:class:`matplotlib.figure.Figure`, no pyplot) as a pixmap."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    buf = np.asarray(canvas.buffer_rgba())
    fmt = QtGui.QImage.Format.Format_RGBA8888
    q = QtGui.QImage(buf.data, buf.shape[1], buf.shape[0], buf.strides[0], fmt)
    return QtGui.QPixmap.fromImage(q.copy())


class FigureView(QtWidgets.QLabel):
    """A figure drawn off the GUI thread (see :func:`figure_pixmap`), scaled to the label."""

    def __init__(self, parent=None) -> None:
        super().__init__(parent)
        self.setAlignment(QtCore.Qt.AlignmentFlag.AlignCenter)
        self.setMinimumSize(200, 160)
        self._pm: QtGui.QPixmap | None = None

    def set_figure(self, fig) -> None:
        self._pm = figure_pixmap(fig)
        self._rescale()

    def clear_figure(self) -> None:
        """Show nothing (the figure of a result that no longer holds)."""
        self._pm = None
        self.clear()

    def resizeEvent(self, ev) -> None:
        super().resizeEvent(ev)
        self._rescale()

    def _rescale(self) -> None:
        if self._pm is not None:
            self.setPixmap(self._pm.scaled(self.size(), QtCore.Qt.AspectRatioMode.KeepAspectRatio,
                                           QtCore.Qt.TransformationMode.SmoothTransformation))
