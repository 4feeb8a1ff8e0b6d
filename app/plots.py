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
moves to the frame under the mouse. Updates during tracking are coalesced: results mark the
plots stale and one redraw follows per ``refresh_ms``.
"""

from __future__ import annotations

import numpy as np
import pyqtgraph as pg
from PySide6 import QtCore, QtGui, QtWidgets
from scipy.spatial.transform import Rotation

from core.tracking.jcs import anatomical_frames, default_joints, joint_series, volume_points

from .review import FLAGGED, ReviewData

__all__ = ["PlotsDock"]

_PENS = ((230, 80, 80), (80, 190, 90), (90, 140, 240))


def _set(curve, x: np.ndarray, y: np.ndarray) -> None:
    """Set a curve's data, gaps where ``y`` is NaN; an empty curve when nothing is finite."""
    y = np.asarray(y, float)
    ok = np.isfinite(y)
    if not ok.any():
        curve.setData([], [])
    elif ok.all():
        curve.setData(x, y)
    else:
        curve.setData(x, y, connect="finite")


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


class PlotsDock(QtWidgets.QWidget):
    """See the module docs. ``review`` feeds the curves; ``model`` (a ViewerModel) the frame."""

    joint_space_requested = QtCore.Signal()
    refreshed = QtCore.Signal()

    def __init__(self, review: ReviewData, model, *, refresh_ms: int = 250,
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
        self.curves: dict[str, list] = {}
        self._cursors: list[pg.InfiniteLine] = []
        self._shading: list = []
        self._shaded: tuple = ()
        self._make_plots()
        self._fresh: set[str] = set()  # pages drawn from the current data
        self._stale = False
        self._timer = QtCore.QTimer(self)
        self._timer.setSingleShot(True)
        self._timer.setInterval(int(refresh_ms))
        self._timer.timeout.connect(self.refresh)
        review.changed.connect(self._on_changed)
        review.reset.connect(self.refresh)
        self.bone_combo.currentIndexChanged.connect(lambda _: self.refresh())
        self.tabs.currentChanged.connect(lambda _: self.page not in self._fresh and self.refresh())
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

    def _plot(self, page: str, key: str, title: str, units: str, names) -> pg.PlotItem:
        if page not in self.canvases:
            canvas = pg.GraphicsLayoutWidget()
            canvas.setMinimumHeight(120)
            self.canvases[page] = canvas
            self.tabs.addTab(canvas, page)
        canvas = self.canvases[page]
        row = sum(1 for k in self.page_of.values() if k == page)
        p = canvas.addPlot(row=row, col=0)
        self.page_of[key] = page
        p.setTitle(f"{title} — by frame", size="8pt")
        p.setLabel("left", units)
        p.showGrid(x=True, y=True, alpha=0.25)
        p.setMouseEnabled(x=True, y=False)
        p.addLegend(offset=(5, 5), labelTextSize="8pt", verSpacing=-6)
        if self.plots:
            p.setXLink(next(iter(self.plots.values())))
        # a fixed frame axis: no re-layout of its ticks as frames come in
        p.setXRange(-0.5, self.review.n_frames - 0.5, padding=0.0)
        p.enableAutoRange(x=False)
        p.setClipToView(True)
        p.setDownsampling(auto=True, mode="peak")
        self.plots[key] = p
        curves = []
        for k, name in enumerate(names):
            pen = pg.mkPen(_PENS[k % 3], width=1.5)
            curves.append(p.plot([], [], pen=pen, name=name))
        self.curves[key] = curves
        cursor = pg.InfiniteLine(angle=90, movable=False, pen=pg.mkPen((40, 40, 40), width=1))
        p.addItem(cursor, ignoreBounds=True)
        self._cursors.append(cursor)
        return p

    def _make_plots(self) -> None:
        for key, title, units in (("translation", "translation of the centroid", "mm"),
                                  ("rotation", "rotation (vector, lab axes)", "°")):
            p = self._plot("Pose", key, title, units, ["x", "y", "z"])
            bands, filt = [], []
            for k in range(3):
                lo = p.plot([], [], pen=None)
                hi = p.plot([], [], pen=None)
                fill = pg.FillBetweenItem(lo, hi, brush=pg.mkBrush(*_PENS[k], 50))
                p.addItem(fill)
                bands.append((lo, hi))
                dash = pg.mkPen(_PENS[k], width=1, style=QtCore.Qt.PenStyle.DashLine)
                filt.append(p.plot([], [], pen=dash))
            self.curves[key + ":band"] = bands
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
    def _on_changed(self, _b: int, _f: int) -> None:
        self._stale = True
        if not self._timer.isActive():
            self._timer.start()

    def _on_selection(self, bone: int) -> None:
        if 0 <= bone < self.bone_combo.count():
            self.bone_combo.setCurrentIndex(bone)

    def refresh(self) -> None:
        """Redraw the curves of the page shown from the review data (and the shading of flagged
        frames); the other pages are redrawn when they are shown."""
        self._stale = False
        self._fresh = {self.page}
        page = self.page
        d = self.review
        x = np.arange(d.n_frames, dtype=float)
        b = max(self.bone_combo.currentIndex(), 0)
        if d.bones and page == "Pose":
            layer = self.model.layers[self.model.index(d.bones[b])]
            P = d.poses[b]
            t, r = _rel_series(P, layer.centroid)
            filt = self._filtered(P, layer.centroid)
            for key, series, sig, fser in (("translation", t, d.sigma_mm[b], filt[0]),
                                           ("rotation", r, d.sigma_deg[b], filt[1])):
                s = np.where(np.isfinite(sig), sig, 0.0)
                for k in range(3):
                    _set(self.curves[key][k], x, series[:, k])
                    lo, hi = self.curves[key + ":band"][k]
                    _set(lo, x, series[:, k] - s)
                    _set(hi, x, series[:, k] + s)
                    _set(self.curves[key + ":filtered"][k], x, fser[:, k])
        poses = {name: d.poses[i] for i, name in enumerate(d.bones)}
        for n, j in enumerate(self.joints if page in ("Joint angles", "Helical axis", "Joint space") else ()):
            if page == "Joint space":
                space = self.joint_space.get(j.name)
                if space is not None:
                    _set(self.curves["joint_space"][n], x, space)
                continue
            js = joint_series(poses, j, self.frames)
            for k in range(3):
                _set(self.curves[f"jcs:{j.name}"][k], x, js["angles_deg"][:, k])
            _set(self.curves["helical_angle"][n], x, js["helical_angle_deg"])
            _set(self.curves["helical_translation"][n], x, js["helical_translation_mm"])
        self._shade()
        self.refreshed.emit()

    def _filtered(self, P: np.ndarray, centroid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        n = len(P)
        none = (np.full((n, 3), np.nan), np.full((n, 3), np.nan))
        ok = np.all(np.isfinite(P), axis=(1, 2))
        if ok.sum() < 15:
            return none
        from core.tracking.kinematics import filter_poses, residual_cutoff

        try:
            path = np.full((n, 3), np.nan)
            path[ok] = P[ok, :3, :3] @ centroid + P[ok, :3, 3]
            cutoff, _ = residual_cutoff(path, 1.0)
            return _rel_series(filter_poses(P, 1.0, cutoff, center=centroid), centroid)
        except ValueError:
            return none

    def _shade(self) -> None:
        """Shade the flagged frames: one bar item per plot (a region item per run of frames made
        each repaint cost grow with the number of flagged runs)."""
        flagged = np.flatnonzero((self.review.status == FLAGGED).any(axis=0))
        runs = tuple(_runs(flagged))
        if runs == self._shaded:
            return
        x = np.array([(a + b) / 2 for a, b in runs], float)
        w = np.array([b - a + 1 for a, b in runs], float)
        if not self._shading:
            for p in self.plots.values():
                item = pg.BarGraphItem(x=x, width=w, y0=-1e6, height=2e6, brush=pg.mkBrush(220, 70, 60, 45),
                                       pen=pg.mkPen(None))
                item.setZValue(-10)
                p.addItem(item, ignoreBounds=True)
                self._shading.append((p, item))
        else:
            for _, item in self._shading:
                item.setOpts(x=x, width=w, y0=-1e6, height=2e6)
        self._shaded = runs

    def set_joint_space(self, distances: dict[str, np.ndarray]) -> None:
        self.joint_space.update({k: np.asarray(v, float) for k, v in distances.items()})
        self.refresh()

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
            self.show_page(shown)
        for w in written:
            if not w.is_file() or w.stat().st_size == 0:
                raise OSError(f"{w}: the plot export wrote nothing")
        return written

    def _drawn(self, page: str):
        """Show ``page`` with its curves drawn from the current data; its canvas."""
        self.show_page(page)
        if page not in self._fresh:
            self.refresh()
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


def _runs(frames: np.ndarray):
    """Contiguous runs ``(first, last)`` of sorted frame numbers."""
    if len(frames) == 0:
        return
    start = prev = int(frames[0])
    for f in frames[1:]:
        f = int(f)
        if f != prev + 1:
            yield start, prev
            start = f
        prev = f
    yield start, prev
