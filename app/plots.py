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

The graphics items live in :mod:`app.plots_items`, the pose series and their low-pass in
:mod:`app.plots_series`, the export to PNG, SVG and PDF in :mod:`app.plots_export`.
"""

from __future__ import annotations

import functools
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pyqtgraph as pg
from PySide6 import QtCore, QtWidgets
from scipy.spatial.transform import Rotation

from core.tracking.jcs import anatomical_frames, default_joints, joint_series, volume_points

from .plots_export import export_pages
from .plots_items import _PENS, _cache, _FrameAxis, _Grid, _legend_title, _Live, _set
from .plots_series import _lowpass, _rel_series
from .review import EDITED, FLAGGED, KEYFRAME, ReviewData

__all__ = ["PlotsDock"]

_MIN_FILTERED = 15  # recorded frames before the low-passed curves are shown
_Y_MARGIN = 0.3  # fraction of the data's span added on each side when a y range must grow
_MIN_PLOT_PX = 105  # the least height of one plot (title, data, frame axis)
_MIN_SPAN = 2.0  # smallest y span shown (mm or °): the first frames do not rescale the axes each time


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
        self._flagged: dict[str, np.ndarray] = {}  # plot key -> the flagged frames it shades
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
        self._shading: dict[str, _Live] = {}  # plot key -> its shading of flagged frames
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
        self._shading[key] = shade
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

    def shaded_bones(self, key: str) -> list[int]:
        """The bones (indices of the review's) whose flagged frames plot ``key`` shades: the bone
        shown on the Pose page, a joint's two bones on its JCS plot, the joints' bones on the other
        pages. (Every bone's flags shaded every plot: the tibia's pose showed the talus's flagged
        frames.)"""
        d = self.review
        if self.page_of.get(key) == "Pose":
            return [max(self.bone_combo.currentIndex(), 0)] if d.bones else []
        joints = [j for j in self.joints if key == f"jcs:{j.name}"] or self.joints
        names = {n for j in joints for n in (j.proximal, j.distal)}
        return [i for i, b in enumerate(d.bones) if b in names]

    def _shade(self) -> None:
        """Shade the flagged frames of each plot's bones (:meth:`shaded_bones`; one item per plot,
        repainted only at the frames whose flag changed)."""
        flagged = self.review.status == FLAGGED
        for key, item in self._shading.items():
            bones = self.shaded_bones(key)
            mask = flagged[bones].any(axis=0) if bones else np.zeros(self.review.n_frames, bool)
            if key in self._flagged and np.array_equal(mask, self._flagged[key]):
                continue
            self._flagged[key] = mask
            item.set_data(np.where(mask, 1.0, np.nan))

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

    def export(self, path: str) -> list:
        """Write the plots by the file's suffix: ``.pdf`` one page per tab in one file; ``.png`` /
        ``.svg`` the page shown to ``path`` and every other page to ``<stem>-<page><suffix>``
        beside it. Every file is written to a temporary name and renamed into place. Returns
        the paths written (:func:`app.plots_export.export_pages`)."""
        return export_pages(path, self.canvases, self.page, self._drawn, self.show_page)

    def _drawn(self, page: str):
        """Show ``page`` with its curves drawn from the current data; its canvas."""
        self.show_page(page)
        if self._dirty[page]:
            self.refresh()
        if page == "Pose":
            self._poll_lowpass(wait=True)
        return self.canvases[page]
