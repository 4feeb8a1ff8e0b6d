"""The plots dock's graphics items (:mod:`app.plots`): the live curves, bands and shading that
repaint only the frames that changed (:class:`_Live`), the whole-frame axis, the text-free grid
drawn inside the repainted region, and the pixmap cache of static items."""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from PySide6 import QtCore, QtWidgets

_PENS = ((230, 80, 80), (80, 190, 90), (90, 140, 240))
_DASH = 0.3  # half the width (frames) of the dash drawn for a value without a finite neighbour


def _set(curve, x: np.ndarray, y: np.ndarray) -> None:
    """Set a curve's data, gaps where ``y`` is NaN; an empty curve when nothing is finite."""
    y = np.asarray(y, float)
    ok = np.isfinite(y)
    if not ok.any():
        curve.setData(x[:0], y[:0])
    elif ok.all():
        curve.setData(x, y, connect="all")
    else:
        curve.setData(x, y, connect="finite")


def _finite_runs(ok: np.ndarray) -> list[tuple[int, int]]:
    """``(start, stop)`` (stop exclusive) of each run of True in ``ok``."""
    if ok.all():
        return [(0, len(ok))]
    d = np.diff(np.concatenate(([0], ok.astype(np.int8), [0])))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(), strict=True))


class _Live(QtWidgets.QGraphicsItem):
    """Curves (``pens``: polylines with gaps at NaN), bands (``brushes``: filled between a low
    and a high series) or shading (``shade``: a brush over the whole height of each frame whose
    value is finite) of one plot over frames ``0..n-1``, repainted only where they changed. A value
    without a finite neighbour (a keyframe between untracked frames, the pose of a one-frame trial)
    is a dash across its frame (bands: a bar).

    :meth:`set_data` compares the new values with those drawn and asks Qt to repaint only the span
    of frames that differ (with the segments that reach them); :meth:`paint` draws only the frames
    inside the region being repainted (Qt's exposed rectangle), so a new frame costs a strip a few
    pixels wide. The bounding rectangle spans the frames and the plot's y range
    (:meth:`set_bounds`; the view box clips its children to the plot)."""

    def __init__(self, n_frames: int, *, pens=(), brushes=(), shade=None) -> None:
        super().__init__()
        self.setFlag(QtWidgets.QGraphicsItem.GraphicsItemFlag.ItemUsesExtendedStyleOption)
        self.n = int(n_frames)
        self.pens = [pg.mkPen(p) for p in pens]
        self.brushes = [pg.mkBrush(b) for b in brushes]
        self.shade = None if shade is None else pg.mkBrush(shade)
        self.bands = bool(self.brushes)
        m = 1 if self.shade is not None else len(self.brushes) if self.bands else len(self.pens)
        self.values = np.full((m, 2 if self.bands else 1, self.n), np.nan)  # [series, (lo, hi) | (y,), frame]
        self._x = np.arange(self.n, dtype=float)
        self._rect = QtCore.QRectF(-1.0, -1.0, self.n + 1.0, 2.0)

    def boundingRect(self) -> QtCore.QRectF:  # Qt's name
        return self._rect

    def set_bounds(self, y0: float, y1: float) -> None:
        """The plot's y range (the item's height)."""
        self.prepareGeometryChange()
        self._rect = QtCore.QRectF(-1.0, y0, self.n + 1.0, y1 - y0)

    def set_data(self, values) -> None:
        """New values ``(series, 2 | 1, n)`` (bands: low, high); repaints the frames that differ."""
        v = np.asarray(values, float).reshape(self.values.shape)
        old = self.values
        differ = ~((v == old) | (np.isnan(v) & np.isnan(old)))
        idx = np.flatnonzero(differ.reshape(-1, self.n).any(axis=0))
        if not idx.size:
            return
        self.values = v.copy()
        a, b = int(idx[0]) - 1, int(idx[-1]) + 1  # the segments that reach a changed frame
        r = self._rect
        self.update(QtCore.QRectF(a, r.top(), b - a, r.height()))

    def series(self, k: int = 0) -> np.ndarray:
        """The values drawn of curve ``k`` (bands: the high side)."""
        return self.values[k, -1].copy()

    def paint(self, painter, option, widget=None) -> None:  # Qt's name
        r = option.exposedRect
        a = max(int(np.floor(r.left())) - 1, 0)
        b = min(int(np.ceil(r.right())) + 2, self.n)
        if b <= a:  # one frame is enough: a one-frame trial's pose is a lone value
            return
        x = self._x[a:b]
        if self.shade is not None:
            top, height = self._rect.top(), self._rect.height()
            for s, e in _finite_runs(np.isfinite(self.values[0, 0, a:b])):
                painter.fillRect(QtCore.QRectF(x[s] - 0.5, top, e - s, height), self.shade)
        elif self.bands:
            painter.setPen(QtCore.Qt.PenStyle.NoPen)
            for brush, (lo, hi) in zip(self.brushes, self.values[:, :, a:b], strict=True):
                painter.setBrush(brush)
                for s, e in _finite_runs(np.isfinite(lo) & np.isfinite(hi)):
                    if e - s > 1:
                        painter.drawPolygon(pg.functions.arrayToQPolygonF(
                            np.concatenate([x[s:e], x[s:e][::-1]]), np.concatenate([hi[s:e], lo[s:e][::-1]])))
                    else:  # a lone frame: a bar as wide as a lone value's dash
                        painter.drawRect(QtCore.QRectF(x[s] - _DASH, lo[s], 2 * _DASH, hi[s] - lo[s]))
        else:
            for pen, (y,) in zip(self.pens, self.values[:, :, a:b], strict=True):
                painter.setPen(pen)
                for s, e in _finite_runs(np.isfinite(y)):
                    if e - s > 1:
                        painter.drawPolyline(pg.functions.arrayToQPolygonF(x[s:e], y[s:e]))
                    else:  # a lone value (a keyframe between untracked frames): a dash across its frame
                        painter.drawLine(QtCore.QPointF(x[s] - _DASH, y[s]),
                                         QtCore.QPointF(x[s] + _DASH, y[s]))


class _FrameAxis(pg.AxisItem):
    """The frame axis: ticks at whole frames only (no 0.5 between frames on a short trial)."""

    def tickSpacing(self, minVal, maxVal, size):
        return [(max(1.0, spacing), offset) for spacing, offset in super().tickSpacing(minVal, maxVal, size)
                if spacing >= 1.0] or [(1.0, 0.0)]


class _Grid(QtWidgets.QGraphicsItem):
    """Grid lines of a plot at its axes' major and minor tick values, without text, drawn only
    inside the region being repainted (a new frame's strip: a few short lines). The tick values
    are asked of the axes once per view range."""

    def __init__(self, plot: pg.PlotItem) -> None:
        super().__init__()
        self.setFlag(QtWidgets.QGraphicsItem.GraphicsItemFlag.ItemUsesExtendedStyleOption)
        self.plot = plot
        self.pens = (pg.mkPen((0, 0, 0, 55), width=1), pg.mkPen((0, 0, 0, 22), width=1))
        self._rect = QtCore.QRectF()
        self._ticks: tuple | None = None  # (x levels, y levels) of the view range drawn
        plot.getViewBox().sigRangeChanged.connect(self._on_range)
        self._on_range()

    def _on_range(self, *_) -> None:
        self.prepareGeometryChange()
        self._rect = self.plot.getViewBox().viewRect()
        self._ticks = None

    def boundingRect(self) -> QtCore.QRectF:  # Qt's name
        return self._rect

    def _levels(self) -> tuple:
        if self._ticks is None:
            vb = self.plot.getViewBox()
            (x0, x1), (y0, y1) = vb.viewRange()
            self._ticks = tuple(
                [np.asarray(v, float) for _, v in self.plot.getAxis(name).tickValues(lo, hi, size)[:2]]
                for name, lo, hi, size in (("bottom", x0, x1, vb.width()), ("left", y0, y1, vb.height())))
        return self._ticks

    def paint(self, painter, option, widget=None) -> None:  # Qt's name
        r = option.exposedRect
        xs, ys = self._levels()
        for level, pen in enumerate(self.pens):
            lines = []
            if level < len(xs):
                v = xs[level]
                v = v[(v >= r.left()) & (v <= r.right())]
                lines += [QtCore.QLineF(x, r.top(), x, r.bottom()) for x in v]
            if level < len(ys):
                v = ys[level]
                v = v[(v >= r.top()) & (v <= r.bottom())]
                lines += [QtCore.QLineF(r.left(), y, r.right(), y) for y in v]
            if lines:
                painter.setPen(pen)
                painter.drawLines(lines)


def _cache(item) -> None:
    """Draw a static item (axis, grid, shading) from a pixmap cache on screen: a repaint of the
    curves over it blits it instead of drawing its lines and text again. The cache follows the
    item's own updates (a new range redraws it); exports switch it off (vector output)."""
    item.setCacheMode(QtWidgets.QGraphicsItem.CacheMode.DeviceCoordinateCache)


def _legend_title(title: str, names, styles=None) -> str:
    parts = [f"<span style='color:rgb{_PENS[k % 3]}'>{name}</span>" for k, name in enumerate(names)]
    return f"{title} — {' '.join(parts)}" + (f" <span style='color:#555'>({styles})</span>" if styles else "")
