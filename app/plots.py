"""The plots dock: a bone's pose over frames and the joints' kinematics, linked to the frame.

Rows (pyqtgraph, x = frame number, 0-based as everywhere in Talus):

* the chosen bone's centroid translation (lab x, y, z, mm, relative to its first recorded
  frame) and rotation (rotation vector relative to that frame, lab axes, °): raw as solid lines,
  low-passed (:func:`core.tracking.kinematics.filter_poses`, zero-phase Butterworth at Winter's
  residual cut-off in cycles per frame; shown from 15 recorded frames on) as dashed lines, and a
  band of ± the frame's confidence σ (:mod:`core.tracking.confidence`) around the raw curves;
* per joint (:func:`core.tracking.jcs.default_joints`: ankle and subtalar in the foot) the
  Grood–Suntay angles (°) from principal-axes anatomical frames;
* the helical-axis angle (°) and translation (mm) of each joint from one frame to the next;
* the joint space: smallest surface distance (mm) per joint (:func:`core.tracking.kinematics.min_distance`),
  computed in the background on demand (the bone surfaces take a few seconds to build).

Flagged frames are shaded, a vertical cursor follows the current frame and a click in any plot
moves to the frame under the mouse.

Live updates while tracking stay cheap on the GUI thread (``talus bench review``): a result only
marks its bone and frame changed; a coalescing timer redraws at most every ``refresh_ms`` (100 ms:
≤ 10 Hz), only the page shown, only the curves of the changed bones, and nothing while the dock is
hidden (a tab behind *Messages*, closed) — it catches up when shown. The pose series of the bone
shown are computed again only at the frames that changed (all of them when its first recorded
frame, the reference, changes). The raw curves, the σ bands and the shading of flagged frames of a
plot are one item each (:class:`_Live`) that compares new values with those drawn, asks Qt to
repaint only the span of frames that differ and paints only the frames inside the region
repainted: a new frame repaints a strip a few pixels wide, not the plot. The grid (:class:`_Grid`,
at the axes' tick values, no text) draws only inside that region too. Winter's cut-off and the
low-passed (dashed) curves are computed in the dock's own worker thread when the bone's recorded
frames grew by a fifth (tens of ms each), and drawn, with the axes, from pixmap caches on screen.
The y ranges are set by the dock and widened in steps with a margin (no autorange pass and no
re-layout of the axes' ticks on most redraws); the legend is the plot's coloured title.
"""

from __future__ import annotations

import functools
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pyqtgraph as pg
from PySide6 import QtCore, QtGui, QtWidgets
from scipy.spatial.transform import Rotation

from core.tracking.jcs import anatomical_frames, default_joints, joint_series, volume_points

from .review import EDITED, FLAGGED, KEYFRAME, ReviewData

__all__ = ["PlotsDock"]

_PENS = ((230, 80, 80), (80, 190, 90), (90, 140, 240))
_MIN_FILTERED = 15  # recorded frames before the low-passed curves are shown
_Y_MARGIN = 0.3  # fraction of the data's span added on each side when a y range must grow
_MIN_PLOT_PX = 105  # the least height of one plot (title, data, frame axis)
_MIN_SPAN = 2.0  # smallest y span shown (mm or °): the first frames do not rescale the axes each time


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
    value is finite) of one plot over frames ``0..n-1``, repainted only where they changed.

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
        if b - a < 2:
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
        else:
            for pen, (y,) in zip(self.pens, self.values[:, :, a:b], strict=True):
                painter.setPen(pen)
                for s, e in _finite_runs(np.isfinite(y)):
                    if e - s > 1:
                        painter.drawPolyline(pg.functions.arrayToQPolygonF(x[s:e], y[s:e]))


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


def _rel_series(P: np.ndarray, centroid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centroid translation (mm) and rotation vector (deg) relative to the first finite pose."""
    n = len(P)
    t = np.full((n, 3), np.nan)
    r = np.full((n, 3), np.nan)
    ok = np.all(np.isfinite(P), axis=(1, 2))
    if not ok.any():
        return t, r
    k0 = int(np.flatnonzero(ok)[0])
    c = P[ok, :3, :3] @ centroid + P[ok, :3, 3]
    t[ok] = c - c[0]
    R0 = P[k0, :3, :3]
    r[ok] = np.rad2deg(Rotation.from_matrix(P[ok, :3, :3] @ R0.T).as_rotvec())
    return t, r


def _lowpass(P: np.ndarray, centroid: np.ndarray) -> tuple[float, tuple[np.ndarray, np.ndarray]]:
    """Winter's residual cut-off (cycles per frame) of the centroid's path and the pose series
    low-passed at it (:func:`_rel_series` of :func:`core.tracking.kinematics.filter_poses`). Runs in
    a worker thread: numpy and scipy only."""
    from core.tracking.kinematics import filter_poses, residual_cutoff

    ok = np.all(np.isfinite(P), axis=(1, 2))
    path = np.full((len(P), 3), np.nan)
    path[ok] = P[ok, :3, :3] @ centroid + P[ok, :3, 3]
    cutoff, _ = residual_cutoff(path, 1.0, candidates=np.linspace(0.02, 0.2, 19))
    return cutoff, _rel_series(filter_poses(P, 1.0, cutoff, center=centroid), centroid)


class PlotsDock(QtWidgets.QWidget):
    """See the module docs. ``review`` feeds the curves; ``model`` (a ViewerModel) the frame."""

    joint_space_requested = QtCore.Signal()
    refreshed = QtCore.Signal()

    def __init__(self, review: ReviewData, model, *, refresh_ms: int = 100,
                 parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        self.review = review
        self.model = model
        self.joints = default_joints(review.bones)
        self.frames = anatomical_frames({layer.name: volume_points(layer.volume) for layer in model.layers
                                         if layer.name in {b for j in self.joints for b in (j.proximal,
                                                                                           j.distal)}})
        self.joint_space: dict[str, np.ndarray] = {}
        self.bone_combo = QtWidgets.QComboBox()
        self.bone_combo.addItems(review.bones)
        self.space_button = QtWidgets.QPushButton("Joint space")
        self.space_button.setToolTip("Compute the smallest surface distance of each joint per frame")
        self.space_button.clicked.connect(self.joint_space_requested.emit)
        top = QtWidgets.QHBoxLayout()
        top.addWidget(QtWidgets.QLabel("Bone"))
        top.addWidget(self.bone_combo, 1)
        top.addWidget(self.space_button)
        pg.setConfigOptions(antialias=False, background="w", foreground="k")
        self.tabs = QtWidgets.QTabWidget()
        self.tabs.setDocumentMode(True)
        self.canvases: dict[str, pg.GraphicsLayoutWidget] = {}  # page name -> its canvas
        self.page_of: dict[str, str] = {}  # plot key -> page name
        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(2, 2, 2, 2)
        layout.addLayout(top)
        layout.addWidget(self.tabs, 1)
        self.plots: dict[str, pg.PlotItem] = {}
        self.curves: dict = {}  # plot key -> its _Live curves; "<key>:band", "<key>:filtered" (Pose)
        self._live: dict[str, list[_Live]] = {}  # plot key -> its _Live items (curves, bands)
        self._series: dict[int, tuple] = {}  # bone -> (reference frame, its centroid, rotation, t, r)
        self._flagged = np.zeros(review.n_frames, bool)
        self._x = np.arange(review.n_frames, dtype=float)
        self._y_range: dict[str, tuple[float, float]] = {}
        self._cutoff: dict[int, tuple[int, float]] = {}  # bone -> (recorded frames, cut-off)
        self._dashed_bone = -1  # the bone whose low-passed curves are drawn
        self._lowpass_job = None  # (bone, recorded frames, future) of the low-pass being computed
        self._lowpass_pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="talus-lowpass")
        self.destroyed.connect(functools.partial(self._lowpass_pool.shutdown, wait=False,
                                                 cancel_futures=True))
        self._lowpass_timer = QtCore.QTimer(self)
        self._lowpass_timer.setInterval(20)
        self._lowpass_timer.timeout.connect(self._poll_lowpass)
        self._cursors: list[pg.InfiniteLine] = []
        self._shading: list[_Live] = []  # per plot: its flagged frames
        self._make_plots()
        # page -> bone -> frames changed since the page was drawn (None: all of them)
        self._dirty: dict[str, dict[int, set[int] | None]] = {page: self._everything()
                                                              for page in self.canvases}
        self._timer = QtCore.QTimer(self)
        self._timer.setSingleShot(True)
        self._timer.setInterval(int(refresh_ms))
        self._timer.timeout.connect(self._on_timer)
        review.changed.connect(self._on_changed)
        review.reset.connect(self._on_reset)
        self.bone_combo.currentIndexChanged.connect(self._on_bone)
        self.tabs.currentChanged.connect(lambda _: self._dirty[self.page] and self.refresh())
        model.current_frame_changed.connect(self.set_cursor)
        model.selection_changed.connect(self._on_selection)
        for canvas in self.canvases.values():
            canvas.scene().sigMouseClicked.connect(lambda ev, c=canvas: self._on_click(ev, c))
        self.refresh()
        self.set_cursor(model.current_frame)

    # ------------------------------------------------------------------ building
    @property
    def page(self) -> str:
        """The page (tab) shown."""
        return self.tabs.tabText(self.tabs.currentIndex())

    def show_page(self, name: str) -> None:
        self.tabs.setCurrentIndex(list(self.canvases).index(name))

    def canvas_of(self, key: str) -> pg.GraphicsLayoutWidget:
        return self.canvases[self.page_of[key]]

    def _plot(self, page: str, key: str, title: str, units: str, names, styles=None) -> pg.PlotItem:
        if page not in self.canvases:
            canvas = pg.GraphicsLayoutWidget()
            canvas.setMinimumHeight(120)
            self.canvases[page] = canvas
            self.tabs.addTab(canvas, page)
        canvas = self.canvases[page]
        row = sum(1 for k in self.page_of.values() if k == page)
        # room for each plot's title, axis and a readable band of data (~60 px) on small screens
        canvas.setMinimumHeight(max(120, _MIN_PLOT_PX * (row + 1)))
        p = canvas.addPlot(row=row, col=0, axisItems={"bottom": _FrameAxis("bottom")})
        self.page_of[key] = page
        p.setTitle(_legend_title(f"{title} — by frame", names, styles), size="8pt")
        p.setLabel("left", units)
        for name in ("left", "bottom"):
            axis = p.getAxis(name)
            axis.enableAutoSIPrefix(False)  # no relabelling ("× 10³ mm") at each change of range
            axis.setStyle(tickLength=4)  # ticks outside: the axis lies outside what new points repaint
            _cache(axis)
        p.setMouseEnabled(x=True, y=False)
        # a text-free grid: the axes' grid would repaint their tick labels with every new point
        p.addItem(_Grid(p), ignoreBounds=True)
        if self.plots:
            p.setXLink(next(iter(self.plots.values())))
        # fixed axes: the frame axis spans the trial, the y range is set by the dock (_fit_y)
        p.setXRange(-0.5, self.review.n_frames - 0.5, padding=0.0)
        p.enableAutoRange(x=False, y=False)
        p.setYRange(-1.0, 1.0, padding=0.0)
        self.plots[key] = p
        self.curves[key] = self._add_live(key, _Live(self.review.n_frames,
                                                     pens=[pg.mkPen(_PENS[k % 3], width=1.5)
                                                           for k in range(len(names))]))
        shade = self._add_live(key, _Live(self.review.n_frames, shade=(220, 70, 60, 45)))
        shade.setZValue(-10)
        self._shading.append(shade)
        cursor = pg.InfiniteLine(angle=90, movable=False, pen=pg.mkPen((40, 40, 40), width=1))
        p.addItem(cursor, ignoreBounds=True)
        self._cursors.append(cursor)
        return p

    def _add_live(self, key: str, item: _Live) -> _Live:
        self.plots[key].addItem(item, ignoreBounds=True)
        self._live.setdefault(key, []).append(item)
        return item

    def curve_data(self, key: str, k: int = 0) -> np.ndarray:
        """The values drawn of curve ``k`` of plot ``key`` (NaN where none), by frame."""
        return self.curves[key].series(k)

    def _make_plots(self) -> None:
        for key, title, units in (("translation", "translation of the centroid", "mm"),
                                  ("rotation", "rotation (vector, lab axes)", "°")):
            p = self._plot("Pose", key, title, units, ["x", "y", "z"],
                           "solid raw, dashed low-passed, band ± σ")
            band = self._add_live(key, _Live(self.review.n_frames, brushes=[(*c, 50) for c in _PENS]))
            band.setZValue(-5)  # under the grid and the curves
            self.curves[key + ":band"] = band
            filt = []
            for k in range(3):  # changed a few times per trial: drawn from a pixmap cache
                dash = pg.mkPen(_PENS[k], width=1, style=QtCore.Qt.PenStyle.DashLine)
                c = pg.PlotCurveItem(pen=dash)
                _cache(c)
                p.addItem(c, ignoreBounds=True)
                filt.append(c)
            self.curves[key + ":filtered"] = filt
        for j in self.joints:
            self._plot("Joint angles", f"jcs:{j.name}", f"{j.name} ({j.proximal}–{j.distal}) JCS angles", "°",
                       ["e1", "e2", "e3"])
        if self.joints:
            names = [j.name for j in self.joints]
            self._plot("Helical axis", "helical_angle", "helical axis: angle per frame", "°", names)
            self._plot("Helical axis", "helical_translation", "helical axis: translation per frame", "mm",
                       names)
            self._plot("Joint space", "joint_space", "joint space (smallest surface distance)", "mm", names)

    # ------------------------------------------------------------------ updates
    def _everything(self) -> dict[int, None]:
        return dict.fromkeys(range(len(self.review.bones)))

    def _on_changed(self, b: int, f: int) -> None:
        for dirty in self._dirty.values():
            frames = dirty.setdefault(b, set())
            if frames is not None:
                frames.add(f)
        if self.review.status[b, f] in (KEYFRAME, EDITED):  # a hand edit: low-pass again
            self._cutoff.pop(b, None)
        if not self._timer.isActive():
            self._timer.start()

    def _on_reset(self) -> None:
        self._cutoff.clear()
        for page in self._dirty:
            self._redraw_page(page, now=False)
        self.refresh()

    def _redraw_page(self, page: str, *, now: bool = True) -> None:
        self._dirty[page] = self._everything()
        if now and page == self.page:
            self.refresh()

    def _on_timer(self) -> None:
        if self.isVisible():  # hidden (a tab behind Messages, closed): caught up in showEvent
            self.refresh()

    def showEvent(self, event) -> None:  # Qt's handler
        super().showEvent(event)
        if self._dirty.get(self.page):
            self._timer.start(0)

    def _on_bone(self, b: int) -> None:
        self._cutoff.pop(b, None)  # the dashed curves show the bone shown
        self._redraw_page("Pose")

    def _on_selection(self, bone: int) -> None:
        if 0 <= bone < self.bone_combo.count():
            self.bone_combo.setCurrentIndex(bone)

    def refresh(self) -> None:
        """Draw the page shown from the review data: the curves of the bones changed since it was
        last drawn, and the shading of flagged frames (the other pages follow when shown)."""
        self._timer.stop()
        page = self.page
        dirty, self._dirty[page] = self._dirty[page], {}
        d = self.review
        b = max(self.bone_combo.currentIndex(), 0)
        if d.bones and page == "Pose":
            for other in dirty:  # drawn from scratch when shown
                if other != b:
                    self._series.pop(other, None)
        if d.bones and page == "Pose" and b in dirty:
            centroid = self.model.layers[self.model.index(d.bones[b])].centroid
            P = d.poses[b]
            t, r = self._pose_series(b, P, centroid, dirty[b])
            self._request_lowpass(b, P, centroid)
            for key, series, sig in (("translation", t, d.sigma_mm[b]), ("rotation", r, d.sigma_deg[b])):
                has_sigma = bool(np.isfinite(sig).any())
                s = np.where(np.isfinite(sig), sig, 0.0)
                lo, hi = series - s[:, None], series + s[:, None]
                self._fit_y(key, lo, hi)
                self.curves[key].set_data(series.T)
                band = self.curves[key + ":band"]
                band.setVisible(has_sigma)
                if has_sigma:
                    band.set_data(np.stack([lo.T, hi.T], axis=1))
        names = {j.proximal for j in self.joints} | {j.distal for j in self.joints}
        if page in ("Joint angles", "Helical axis") and any(d.bones[i] in names for i in dirty):
            poses = {name: d.poses[i] for i, name in enumerate(d.bones)}
            hel_a, hel_t = [], []
            for j in self.joints:
                js = joint_series(poses, j, self.frames)
                if page == "Joint angles":
                    self._fit_y(f"jcs:{j.name}", js["angles_deg"])
                    self.curves[f"jcs:{j.name}"].set_data(js["angles_deg"].T)
                else:
                    hel_a.append(js["helical_angle_deg"])
                    hel_t.append(js["helical_translation_mm"])
            if page == "Helical axis":
                self._fit_y("helical_angle", *hel_a)
                self._fit_y("helical_translation", *hel_t)
                self.curves["helical_angle"].set_data(np.array(hel_a))
                self.curves["helical_translation"].set_data(np.array(hel_t))
        if page == "Joint space" and self.joints:
            nan = np.full(d.n_frames, np.nan)
            spaces = [self.joint_space.get(j.name, nan) for j in self.joints]
            self._fit_y("joint_space", *spaces)
            self.curves["joint_space"].set_data(np.array(spaces))
        self._shade()
        self.refreshed.emit()

    def _fit_y(self, key: str, *series) -> None:
        """Keep the data of plot ``key`` in view: widen its y range (with a margin, so that the
        next points rarely need another change) when the data leave it, narrow it when they use
        less than a quarter of it."""
        vals = [np.asarray(v, float) for v in series if v is not None and np.size(v)]
        finite = [v[np.isfinite(v)] for v in vals]
        finite = [v for v in finite if v.size]
        if not finite:
            return
        lo = min(float(v.min()) for v in finite)
        hi = max(float(v.max()) for v in finite)
        span = max(hi - lo, _MIN_SPAN)
        cur = self._y_range.get(key)
        if cur is not None and cur[0] <= lo and hi <= cur[1] and span >= 0.25 * (cur[1] - cur[0]):
            return
        mid = 0.5 * (lo + hi)
        new = (mid - (0.5 + _Y_MARGIN) * span, mid + (0.5 + _Y_MARGIN) * span)
        self._y_range[key] = new
        self.plots[key].setYRange(*new, padding=0.0)
        for item in self._live.get(key, ()):
            item.set_bounds(*new)

    def _pose_series(self, b: int, P: np.ndarray, centroid: np.ndarray,
                     frames) -> tuple[np.ndarray, np.ndarray]:
        """:func:`_rel_series` of bone ``b``, computed again only at ``frames`` (a set; None: all)
        while the reference frame (the first recorded) and its pose stay as they were."""
        ok = np.all(np.isfinite(P), axis=(1, 2))
        k0 = int(np.argmax(ok)) if ok.any() else -1
        seen = self._series.get(b)
        if frames is None or seen is None or seen[0] != k0 or k0 in frames or k0 < 0:
            t, r = _rel_series(P, centroid)
            if k0 >= 0:
                self._series[b] = (k0, P[k0, :3, :3] @ centroid + P[k0, :3, 3], P[k0, :3, :3].copy(), t, r)
            else:
                self._series.pop(b, None)
            return t, r
        _, c0, R0, t, r = seen
        idx = np.fromiter(frames, int, len(frames))
        t[idx] = r[idx] = np.nan
        idx = idx[ok[idx]]
        if idx.size:
            R = P[idx, :3, :3]
            t[idx] = R @ centroid + P[idx, :3, 3] - c0
            r[idx] = np.rad2deg(Rotation.from_matrix(R @ R0.T).as_rotvec())
        return t, r

    def _request_lowpass(self, b: int, P: np.ndarray, centroid: np.ndarray) -> None:
        """Bring the dashed (low-passed) curves in step with bone ``b``, off the GUI thread: while
        results stream in, the low-pass (and Winter's residual cut-off, in cycles per frame) is
        computed again only when the bone's recorded frames grew by a fifth (a few times per
        trial; each takes tens of ms); a reload of the journal (the job's end), a hand edit or
        another bone shown computes it at once. One computation at a time, in a worker thread
        (:func:`_lowpass`); :meth:`_poll_lowpass` draws its answer on the GUI thread."""
        if self._dashed_bone != b:  # another bone shown: no dashed curves until its own are in
            self._show_lowpass(b, None)
        if self._lowpass_job is not None:
            return  # asked again once the running one is in
        count = int(np.all(np.isfinite(P), axis=(1, 2)).sum())
        seen = self._cutoff.get(b)
        if seen is not None and seen[0] <= count < 1.2 * seen[0]:
            return
        self._cutoff[b] = (count, np.nan)
        if count < _MIN_FILTERED:
            self._show_lowpass(b, None)
            return
        job = self._lowpass_pool.submit(_lowpass, P.copy(), np.array(centroid, float))
        self._lowpass_job = (b, count, job)
        self._lowpass_timer.start()

    def _poll_lowpass(self, *, wait: bool = False) -> None:
        if self._lowpass_job is None:
            self._lowpass_timer.stop()
            return
        b, count, future = self._lowpass_job
        if not (wait or future.done()):
            return
        self._lowpass_job = None
        self._lowpass_timer.stop()
        try:
            cutoff, series = future.result()
        except Exception:  # too few frames, a failed fit: no dashed curves, never a crash
            cutoff, series = np.nan, None
        if self._cutoff.get(b, (None,))[0] == count:  # not asked again from scratch since
            self._cutoff[b] = (count, cutoff)
        shown = max(self.bone_combo.currentIndex(), 0)
        if b == shown:
            self._show_lowpass(b, series)
        if self.page == "Pose" and self.review.bones:  # frames in, or another bone, since: due?
            self._request_lowpass(shown, self.review.poses[shown],
                                  self.model.layers[self.model.index(self.review.bones[shown])].centroid)

    def _show_lowpass(self, b: int, series) -> None:
        """Set the dashed curves to ``series`` (translation, rotation ``(n, 3)`` each) of bone
        ``b``; None: none."""
        self._dashed_bone = b
        for key, k in ((key, k) for key in ("translation", "rotation") for k in range(3)):
            curve = self.curves[key + ":filtered"][k]
            if series is None:
                if curve.xData is not None and len(curve.xData):
                    curve.setData(self._x[:0], self._x[:0])
            else:
                _set(curve, self._x, series[0 if key == "translation" else 1][:, k])

    def _shade(self) -> None:
        """Shade the flagged frames (one item per plot, repainted only at the frames whose flag
        changed)."""
        mask = (self.review.status == FLAGGED).any(axis=0)
        if np.array_equal(mask, self._flagged):
            return
        self._flagged = mask
        values = np.where(mask, 1.0, np.nan)
        for item in self._shading:
            item.set_data(values)

    def set_joint_space(self, distances: dict[str, np.ndarray]) -> None:
        self.joint_space.update({k: np.asarray(v, float) for k, v in distances.items()})
        self._redraw_page("Joint space")

    # ------------------------------------------------------------------ cursor and clicks
    def set_cursor(self, frame: int) -> None:
        for c in self._cursors:
            c.setValue(float(frame))

    @property
    def cursor_frame(self) -> float:
        return self._cursors[0].value() if self._cursors else float("nan")

    def frame_at(self, scene_pos: QtCore.QPointF, canvas=None) -> int | None:
        """The frame under a point of a page's scene (default: the page shown), or None outside
        every plot."""
        canvas = canvas or self.canvases[self.page]
        for key, p in self.plots.items():
            if self.canvases[self.page_of[key]] is not canvas:
                continue
            vb = p.getViewBox()
            if vb.sceneBoundingRect().contains(scene_pos):
                x = vb.mapSceneToView(scene_pos).x()
                return int(np.clip(round(x), 0, self.review.n_frames - 1))
        return None

    def _on_click(self, event, canvas) -> None:
        if event.button() != QtCore.Qt.MouseButton.LeftButton:
            return
        f = self.frame_at(event.scenePos(), canvas)
        if f is not None:
            self.model.set_frame(f)

    def scene_point(self, key: str, frame: float, y_fraction: float = 0.5) -> QtCore.QPointF:
        """Scene coordinates of ``frame`` in plot ``key`` (at a fraction of its height)."""
        vb = self.plots[key].getViewBox()
        _, (y0, y1) = vb.viewRange()
        return vb.mapViewToScene(QtCore.QPointF(float(frame), y0 + y_fraction * (y1 - y0)))

    # ------------------------------------------------------------------ export
    def export(self, path: str) -> list:
        """Write the plots by the file's suffix: ``.pdf`` one page per tab in one file; ``.png`` /
        ``.svg`` the page shown to ``path`` and every other page to ``<stem>-<page><suffix>``
        beside it. Every file is written to a temporary name and renamed into place. Returns
        the paths written."""
        from pathlib import Path

        from core.io.atomic import atomic_path

        p = Path(path)
        suffix = p.suffix.lower()
        if suffix not in (".png", ".svg", ".pdf"):
            raise ValueError(f"path: expected a .png, .svg or .pdf file, got {str(path)!r}")
        if not p.parent.is_dir():
            raise ValueError(f"path: the folder {p.parent} does not exist")
        shown = self.page
        written = []
        cache = QtWidgets.QGraphicsItem.CacheMode
        cached = [item for canvas in self.canvases.values() for item in canvas.scene().items()
                  if item.cacheMode() != cache.NoCache]
        for item in cached:  # vector output: lines and text, not the screen's pixmaps
            item.setCacheMode(cache.NoCache)
        try:
            if suffix == ".pdf":
                with atomic_path(p) as tmp:
                    writer = QtGui.QPdfWriter(str(tmp))
                    writer.setPageSize(QtGui.QPageSize(QtGui.QPageSize.PageSizeId.A4))
                    writer.setPageOrientation(QtGui.QPageLayout.Orientation.Landscape)
                    writer.setResolution(150)
                    painter = QtGui.QPainter(writer)
                    try:
                        for k, page in enumerate(self.canvases):
                            if k:
                                writer.newPage()
                            scene = self._drawn(page).scene()
                            rect, src = painter.viewport(), scene.sceneRect()
                            scale = min(rect.width() / src.width(), rect.height() / src.height())
                            scene.render(painter, QtCore.QRectF(0, 0, src.width() * scale,
                                                                src.height() * scale), src)
                    finally:
                        painter.end()
                written.append(p)
            else:
                from pyqtgraph.exporters import ImageExporter

                for page in [shown, *[q for q in self.canvases if q != shown]]:
                    dest = p if page == shown else p.with_name(f"{p.stem}-{page.replace(' ', '-')}{suffix}")
                    canvas = self._drawn(page)
                    with atomic_path(dest) as tmp:
                        if suffix == ".png":
                            ex = ImageExporter(canvas.scene())
                            ex.parameters()["width"] = max(int(canvas.width()), 1200)
                            ex.export(str(tmp))
                        else:  # Qt's own SVG writer: pyqtgraph's SVGExporter fails on filled items
                            _write_svg(canvas.scene(), tmp)
                    written.append(dest)
        finally:
            for item in cached:
                item.setCacheMode(cache.DeviceCoordinateCache)
            self.show_page(shown)
        for w in written:
            if not w.is_file() or w.stat().st_size == 0:
                raise OSError(f"{w}: the plot export wrote nothing")
        return written

    def _drawn(self, page: str):
        """Show ``page`` with its curves drawn from the current data; its canvas."""
        self.show_page(page)
        if self._dirty[page]:
            self.refresh()
        if page == "Pose":
            self._poll_lowpass(wait=True)
        return self.canvases[page]


def _write_svg(scene, path) -> None:
    """Render a graphics scene to an SVG file with QtSvg (vector paths and text)."""
    from PySide6.QtSvg import QSvgGenerator

    src = scene.sceneRect()
    gen = QSvgGenerator()
    gen.setFileName(str(path))
    gen.setSize(QtCore.QSize(int(src.width()), int(src.height())))
    gen.setViewBox(QtCore.QRectF(0, 0, src.width(), src.height()))
    gen.setTitle("Talus plot")
    painter = QtGui.QPainter(gen)
    try:
        scene.render(painter, QtCore.QRectF(0, 0, src.width(), src.height()), src)
    finally:
        painter.end()
