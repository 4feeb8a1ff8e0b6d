"""Per-frame review state of the open trial and the frame table that shows it.

:class:`ReviewData` holds, per bone and frame, what the tracker and the user left in the trial's
journal (:mod:`core.study.results`): status (untracked, keyframe, tracked, flagged, edited),
score, per-frame confidence σ (mm, °), the reasons for review, and the recorded pose (NaN where
none). It is filled from the journal when a study opens and updated frame by frame from tracking
results as they finish (:meth:`ReviewData.apply_result`), and emits ``changed(bone, frame)`` (or
``reset()``) so that every view follows: the frame table (:class:`FrameTableModel`, a
``QAbstractTableModel``), the plots dock and the timeline strip.

Frame numbers are 0-based everywhere: in the API, the journal, the table and the window.
"""

from __future__ import annotations

import numpy as np
from PySide6 import QtCore, QtGui, QtWidgets

__all__ = ["STATUS_COLORS", "STATUS_NAMES", "FrameTableDock", "FrameTableModel", "ReviewData"]

UNTRACKED, KEYFRAME, TRACKED, FLAGGED, EDITED = range(5)
STATUS_NAMES = ("untracked", "keyframe", "tracked", "flagged", "edited")
STATUS_COLORS = np.array([[60, 60, 60], [240, 200, 60], [70, 170, 90], [220, 70, 60], [80, 140, 230]],
                         np.uint8)


class ReviewData(QtCore.QObject):
    """Review state of ``n_bones`` bones over ``n_frames`` frames (see the module docs)."""

    changed = QtCore.Signal(int, int)  # bone, frame
    reset = QtCore.Signal()

    def __init__(self, bones: list[str], n_frames: int, parent: QtCore.QObject | None = None) -> None:
        super().__init__(parent)
        self.bones = list(bones)
        self.n_frames = int(n_frames)
        shape = (len(self.bones), self.n_frames)
        self.status = np.zeros(shape, np.uint8)
        self.score = np.full(shape, np.nan)
        self.sigma_mm = np.full(shape, np.nan)
        self.sigma_deg = np.full(shape, np.nan)
        self.poses = np.full((*shape, 4, 4), np.nan)
        self.reasons: dict[tuple[int, int], str] = {}

    # ------------------------------------------------------------------ filling
    def load_journal(self, trial) -> None:
        """Fill everything from ``trial`` (a :class:`core.study.Trial`) journals; emits ``reset``."""
        for b, name in enumerate(self.bones):
            self._load_bone(b, trial.results(name))
        self.reset.emit()

    def reload_bone(self, trial, bone: str) -> None:
        self._load_bone(self.bones.index(bone), trial.results(bone))
        self.reset.emit()

    def _load_bone(self, b: int, state) -> None:
        self.status[b] = UNTRACKED
        self.score[b] = self.sigma_mm[b] = self.sigma_deg[b] = np.nan
        self.poses[b] = np.nan
        for key in [k for k in self.reasons if k[0] == b]:
            del self.reasons[key]
        done = state.done
        for f, rec in state.records.items():
            if not 0 <= f < self.n_frames or rec.pose is None:
                continue
            self.poses[b, f] = rec.pose
            res = done.get(f)
            if rec.kind == "tracked":
                self._set_tracked(b, f, rec.score, rec.tracking or {})
            elif rec.kind == "hand" and res is not None and res.kind == "hand":
                self.status[b, f] = EDITED  # a hand fix recorded after a tracking result
                self.reasons[(b, f)] = "corrected by hand"
            else:
                self.status[b, f] = KEYFRAME
            if rec.kind != "tracked" and np.isfinite(rec.score):
                self.score[b, f] = rec.score

    def _set_tracked(self, b: int, f: int, score, tracking: dict) -> None:
        flags = list(tracking.get("flags") or ())
        self.status[b, f] = FLAGGED if flags else TRACKED
        self.score[b, f] = np.nan if score is None else float(score)
        conf = tracking.get("confidence") or {}
        self.sigma_mm[b, f] = _num(conf.get("translation_mm"))
        self.sigma_deg[b, f] = _num(conf.get("rotation_deg"))
        # a frame the trajectory check could not judge says so (a note, not a flag: flags_post.UNCHECKED)
        unchecked = [n for n in tracking.get("notes") or () if n.startswith("trajectory unchecked")]
        if flags or unchecked:
            self.reasons[(b, f)] = "; ".join(flags or unchecked)
        else:
            self.reasons.pop((b, f), None)

    def apply_result(self, result: dict, pose=None) -> None:
        """One finished tracking result (``FrameResult.to_dict()`` and its pose); emits ``changed``."""
        name, f = result["bone"], int(result["frame"])
        if name not in self.bones or not 0 <= f < self.n_frames:
            return
        b = self.bones.index(name)
        if pose is not None:
            self.poses[b, f] = pose
        elif result.get("flags"):
            self.reasons[(b, f)] = "; ".join(result["flags"])
            self.status[b, f] = FLAGGED
            self.changed.emit(b, f)
            return
        self._set_tracked(b, f, result.get("score"), result)
        self.changed.emit(b, f)

    def mark_edited(self, b: int, f: int, pose) -> None:
        """A pose set by hand at a frame: a keyframe, or an edit of a tracked/flagged frame."""
        was = self.status[b, f]
        self.poses[b, f] = pose
        if was in (TRACKED, FLAGGED, EDITED):
            self.status[b, f] = EDITED
            self.reasons[(b, f)] = "corrected by hand"
        else:
            self.status[b, f] = KEYFRAME
        self.changed.emit(b, f)

    # ------------------------------------------------------------------ queries
    def frame_status(self) -> np.ndarray:
        """``(n_frames,)`` the most severe status over bones (flagged > edited > tracked > keyframe)."""
        rank = np.array([0, 1, 2, 4, 3])[self.status]  # flagged outranks edited
        inv = np.array([0, 1, 2, 4, 3])
        return inv[rank.max(axis=0)] if len(self.bones) else np.zeros(self.n_frames, np.uint8)

    def frame_status_at(self, f: int) -> int:
        """The most severe status over bones at frame ``f`` (as :meth:`frame_status`)."""
        rank = np.array([0, 1, 2, 4, 3])
        return int(rank[int(rank[self.status[:, f]].max())]) if len(self.bones) else 0

    def frame_reason(self, f: int) -> str:
        parts = []
        for b, name in enumerate(self.bones):
            s = STATUS_NAMES[self.status[b, f]]
            why = self.reasons.get((b, f))
            parts.append(f"{name}: {s}" + (f" — {why}" if why else ""))
        return "\n".join(parts)

    def flagged(self) -> list[tuple[int, int]]:
        """``(bone, frame)`` of every frame flagged for review."""
        b, f = np.nonzero(self.status == FLAGGED)
        return sorted(zip(b.tolist(), f.tolist(), strict=True), key=lambda k: (k[1], k[0]))


def _num(v) -> float:
    return float(v) if v is not None else np.nan


# ---------------------------------------------------------------------------- the table
COLUMNS = ("Frame", "Bone", "Status", "Score", "σ mm", "σ °", "Edited", "Reason")
SORT_ROLE = QtCore.Qt.ItemDataRole.UserRole + 1


class FrameTableModel(QtCore.QAbstractTableModel):
    """One row per (frame, bone): row ``frame * n_bones + bone``."""

    def __init__(self, data: ReviewData, parent: QtCore.QObject | None = None) -> None:
        super().__init__(parent)
        self.review = data
        data.changed.connect(self._on_changed)
        data.reset.connect(self._on_reset)

    def rowCount(self, parent=QtCore.QModelIndex()) -> int:  # noqa: B008 (Qt's signature)
        return 0 if parent.isValid() else self.review.n_frames * len(self.review.bones)

    def columnCount(self, parent=QtCore.QModelIndex()) -> int:  # noqa: B008
        return 0 if parent.isValid() else len(COLUMNS)

    def headerData(self, section, orientation, role=QtCore.Qt.ItemDataRole.DisplayRole):
        R = QtCore.Qt.ItemDataRole
        if role in (R.DisplayRole, R.ToolTipRole) and orientation == QtCore.Qt.Orientation.Horizontal:
            return COLUMNS[section]  # the tooltip: the name of a header elided in a narrow dock
        return None

    def locate(self, row: int) -> tuple[int, int]:
        """``(bone, frame)`` of a row."""
        n = len(self.review.bones)
        return row % n, row // n

    def row_of(self, bone: int, frame: int) -> int:
        return frame * len(self.review.bones) + bone

    def data(self, index, role=QtCore.Qt.ItemDataRole.DisplayRole):
        if not index.isValid():
            return None
        d = self.review
        b, f = self.locate(index.row())
        c = index.column()
        st = int(d.status[b, f])
        R = QtCore.Qt.ItemDataRole
        if role == R.DisplayRole:
            if c == 0:
                return f
            if c == 1:
                return d.bones[b]
            if c == 2:
                return STATUS_NAMES[st]
            if c in (3, 4, 5):
                v = (d.score, d.sigma_mm, d.sigma_deg)[c - 3][b, f]
                return "" if not np.isfinite(v) else f"{v:.3f}"
            if c == 6:
                return "yes" if st == EDITED else ""
            return d.reasons.get((b, f), "")
        if role == SORT_ROLE:
            if c in (3, 4, 5):
                v = (d.score, d.sigma_mm, d.sigma_deg)[c - 3][b, f]
                return float(v) if np.isfinite(v) else -1.0
            if c == 0:
                return f
            if c == 2:
                return st
            return self.data(index, R.DisplayRole)
        if role == R.ToolTipRole:
            return d.reasons.get((b, f)) or STATUS_NAMES[st]
        if role == R.DecorationRole and c == 2:
            return QtGui.QColor(*STATUS_COLORS[st].tolist())
        return None

    def _on_changed(self, b: int, f: int) -> None:
        # the row's frame and bone never change: leaving their columns out of the signal spares
        # the sorting proxy a search for the row's new place when the table is sorted by them
        r = self.row_of(b, f)
        self.dataChanged.emit(self.index(r, 2), self.index(r, len(COLUMNS) - 1))

    def _on_reset(self) -> None:
        self.beginResetModel()
        self.endResetModel()


class _Filter(QtCore.QSortFilterProxyModel):
    def __init__(self, parent=None) -> None:
        super().__init__(parent)
        self.statuses: set[int] | None = None
        self.bone: int | None = None
        self.setSortRole(SORT_ROLE)

    def set_filter(self, statuses: set[int] | None, bone: int | None) -> None:
        if hasattr(self, "beginFilterChange"):  # Qt >= 6.9 (invalidateFilter is deprecated there)
            self.beginFilterChange()
            self.statuses, self.bone = statuses, bone
            self.endFilterChange(QtCore.QSortFilterProxyModel.Direction.Rows)
        else:
            self.statuses, self.bone = statuses, bone
            self.invalidateFilter()

    def filterAcceptsRow(self, row: int, parent) -> bool:
        src = self.sourceModel()
        b, f = src.locate(row)
        if self.bone is not None and b != self.bone:
            return False
        return self.statuses is None or int(src.review.status[b, f]) in self.statuses


class _StatusDelegate(QtWidgets.QStyledItemDelegate):
    """The Status cell: the status's colour square and name, or the square alone while
    :attr:`compact` (a narrow dock; the name in the row's tooltip and the colour's legend)."""

    compact = False

    def initStyleOption(self, option, index) -> None:
        super().initStyleOption(option, index)
        if self.compact:
            option.text = ""
            option.features &= ~QtWidgets.QStyleOptionViewItem.ViewItemFeature.HasDisplay


class FrameTableDock(QtWidgets.QWidget):
    """The frame table with its filters; selecting a row moves the window to that frame and bone."""

    FILTERS = (("All frames", None), ("Flagged", {FLAGGED}), ("Flagged or edited", {FLAGGED, EDITED}),
               ("Tracked", {TRACKED, FLAGGED, EDITED}), ("Keyframes", {KEYFRAME, EDITED}))

    def __init__(self, data: ReviewData, model, parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        self.viewer = model
        self.table_model = FrameTableModel(data, self)
        self.proxy = _Filter(self)
        self.proxy.setSourceModel(self.table_model)
        self.proxy.setDynamicSortFilter(True)
        self.status_filter = QtWidgets.QComboBox()
        for text, _ in self.FILTERS:
            self.status_filter.addItem(text)
        self.bone_filter = QtWidgets.QComboBox()
        self.bone_filter.addItem("All bones")
        self.bone_filter.addItems(data.bones)
        self.view = QtWidgets.QTableView()
        self.view.setModel(self.proxy)
        self.view.setSortingEnabled(True)
        self.view.sortByColumn(0, QtCore.Qt.SortOrder.AscendingOrder)
        self.view.setSelectionBehavior(QtWidgets.QAbstractItemView.SelectionBehavior.SelectRows)
        self.view.setSelectionMode(QtWidgets.QAbstractItemView.SelectionMode.SingleSelection)
        self.view.verticalHeader().hide()
        self.view.verticalHeader().setDefaultSectionSize(20)
        self._status_delegate = _StatusDelegate(self.view)
        self.view.setItemDelegateForColumn(COLUMNS.index("Status"), self._status_delegate)
        self._fitting = False  # while the layout sets widths (not the user)
        self._bone_narrowed = False  # the Bone elided by the narrow layout
        self._user_widths: dict[int, int] = {}  # Status / Bone as the user resized them: kept
        self._layout_columns(data.bones)
        self.view.horizontalHeader().sectionResized.connect(self._section_resized)
        self.view.setAlternatingRowColors(True)
        # the current row's whole reason, word-wrapped under the table (hidden for a row without one)
        self.reason_label = QtWidgets.QLabel()
        self.reason_label.setObjectName("frames-reason")
        self.reason_label.setWordWrap(True)
        self.reason_label.setTextInteractionFlags(QtCore.Qt.TextInteractionFlag.TextSelectableByMouse)
        self.reason_label.hide()
        top = QtWidgets.QHBoxLayout()
        top.addWidget(self.status_filter, 1)
        top.addWidget(self.bone_filter, 1)
        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(2, 2, 2, 2)
        layout.addLayout(top)
        layout.addWidget(self.view, 1)
        layout.addWidget(self.reason_label)
        self.status_filter.currentIndexChanged.connect(self._refilter)
        self.bone_filter.currentIndexChanged.connect(self._refilter)
        # go to a row's frame when the user picks it (a click, or the keys while the table has the
        # focus) — not when an edit moves or hides the current row (e.g. a fixed frame leaving the
        # "Flagged" filter), which would jump the window to a neighbouring row's frame
        self.view.clicked.connect(lambda index: self._on_row(index, None))
        self.view.selectionModel().currentRowChanged.connect(
            lambda cur, prev: self.view.hasFocus() and self._on_row(cur, prev))
        self.view.selectionModel().currentRowChanged.connect(lambda cur, prev: self._show_reason())
        self.table_model.dataChanged.connect(lambda *a: self._show_reason())
        self.table_model.modelReset.connect(self._show_reason)

    def _layout_columns(self, bones) -> None:
        """Column widths from the font (the header's text or the widest value a column can show; no
        scan of every row), and the Reason column placed after Score with its text elided (the
        whole reason in the row's tooltip and, for the current row, word-wrapped under the table),
        as wide as the dock leaves it (:meth:`_fit_reason`): Frame, Bone, Status and Score stay in
        view at the dock's default width (340 px at 1280x800), and where they would leave the
        Reason fewer than 20 letters the Status shows its colour square alone and the Bone is
        elided (to 6 letters at least), so that the Reason gets 20 letters at 340 px (it had 3,
        readable only from the tooltip) — unless the user resized them: their widths are kept
        (:meth:`_section_resized`). The Reason after Status pushed the Score past the dock's
        edge there; as the last column it was itself past the edge."""
        header = self.view.horizontalHeader()
        fm = self.view.fontMetrics()
        pad = fm.horizontalAdvance("M") + 8  # the cell's margins; the sort arrow of the sorted column
        samples = ([str(max(self.table_model.review.n_frames - 1, 0)) + "MM"], list(bones) or [""],
                   [f"{n}M" for n in STATUS_NAMES],  # and the status's colour square
                   ["-0.000"], ["0.000"], ["0.000"], ["yes"])
        self._widths = [max(fm.horizontalAdvance(v) for v in [COLUMNS[col], *values]) + pad
                        for col, values in enumerate(samples)]
        for col, width in enumerate(self._widths):
            self.view.setColumnWidth(col, width)
        self._status_square = fm.height() + 12  # the colour square and the cell's margins
        self._bone_min = min(self._widths[1], 6 * fm.averageCharWidth() + fm.horizontalAdvance("…") + 8)
        header.setStretchLastSection(False)
        reason = COLUMNS.index("Reason")
        header.moveSection(header.visualIndex(reason), COLUMNS.index("Score") + 1)
        self._reason_min = 3 * fm.averageCharWidth()  # an ellipsis and a letter or two
        self._reason_wanted = 20 * fm.averageCharWidth()  # before the σ columns come into view
        header.setMinimumSectionSize(min(header.minimumSectionSize(), self._reason_min))
        self.view.setTextElideMode(QtCore.Qt.TextElideMode.ElideRight)
        header.setTextElideMode(QtCore.Qt.TextElideMode.ElideRight)  # "R…", not the middle of "Reason"
        self.view.setWordWrap(False)
        self.view.viewport().installEventFilter(self)
        self._fit_reason()

    def _section_resized(self, col: int, _old: int, new: int) -> None:
        """A column the user resized (the header's drag): Status or Bone keep that width (the
        narrow layout no longer narrows them), and the Reason is fitted to what is left."""
        if self._fitting:
            return
        if col in (COLUMNS.index("Status"), COLUMNS.index("Bone")):
            self._user_widths[col] = new
        if col != COLUMNS.index("Reason"):
            self._fit_reason()

    def _fit_reason(self) -> None:
        self._fitting = True
        try:
            self._fit()
        finally:
            self._fitting = False

    def _fit(self) -> None:
        """The Reason column's width: what the table's width leaves beside the columns before it
        (Frame to Score; narrowed, Status to its square and Bone elided, where at their widths
        they would leave it fewer than 20 letters) and as many of those after it (σ, Edited) as
        leave it 20 letters (all of them: it fills the table; the columns left out are scrolled
        to); at least 3 letters, so that the columns before it keep their room in a narrower dock."""
        reason, status, bone = (COLUMNS.index(n) for n in ("Reason", "Status", "Bone"))
        header = self.view.horizontalHeader()
        order = sorted(range(len(COLUMNS)), key=header.visualIndex)
        at = order.index(reason)
        user = self._user_widths  # Status / Bone the user resized: their widths, never narrowed
        narrowed = {status} if self._status_delegate.compact else set()
        narrowed |= {bone} if self._bone_narrowed else set()
        # the columns before it as they are (a user may have widened one), Status and Bone at their
        # full widths where they are narrowed now
        widths = {c: user.get(c, self._widths[c]) if c in narrowed else self.view.columnWidth(c)
                  for c in order[:at]}
        short = self._reason_wanted - (self.view.viewport().width() - sum(widths.values()))
        compact = short > 0 and status in widths and status not in user
        if compact:  # the status's name goes (its colour stays), then letters of the bone's name
            short -= widths[status] - self._status_square
            widths[status] = self._status_square
        if short > 0 and bone in widths and bone not in user:
            widths[bone] = max(self._bone_min, widths[bone] - short)
        self._bone_narrowed = bone in widths and bone not in user and widths[bone] < self._widths[bone]
        if compact != self._status_delegate.compact:
            self._status_delegate.compact = compact
            self.view.viewport().update()
        for c in (status, bone):
            if c in widths and self.view.columnWidth(c) != widths[c]:
                self.view.setColumnWidth(c, widths[c])
        used = sum(widths.values())
        after = [self.view.columnWidth(c) for c in order[at + 1:]]
        room = self.view.viewport().width() - used
        for k in range(len(after), -1, -1):
            rest = room - sum(after[:k])
            if rest >= self._reason_wanted:
                break
        self.view.setColumnWidth(reason, max(rest, self._reason_min))

    def eventFilter(self, obj, event) -> bool:
        if obj is self.view.viewport() and event.type() == QtCore.QEvent.Type.Resize:
            self._fit_reason()
        return super().eventFilter(obj, event)

    def _show_reason(self) -> None:
        """The current row's reason, whole and word-wrapped under the table (hidden without one)."""
        current = self.view.currentIndex()
        text = ""
        if current.isValid():
            b, f = self.table_model.locate(self.proxy.mapToSource(current).row())
            reason = self.table_model.review.reasons.get((b, f))
            if reason:
                text = f"Frame {f}, {self.table_model.review.bones[b]}: {reason}"
        self.reason_label.setText(text)
        self.reason_label.setToolTip(text)
        if bool(text) != self.reason_label.isVisibleTo(self):
            self.reason_label.setVisible(bool(text))
            if text:  # the table shrinks under it: keep the row in view once it is laid out
                QtCore.QTimer.singleShot(0, self, lambda: self.view.scrollTo(self.view.currentIndex()))

    def set_filter(self, name: str) -> None:
        """Show rows of one filter by its name (``"Flagged"``, ``"All frames"``, …)."""
        names = [t for t, _ in self.FILTERS]
        if name not in names:
            raise ValueError(f"filter: expected one of {names}, got {name!r}")
        self.status_filter.setCurrentIndex(names.index(name))

    def _refilter(self) -> None:
        b = self.bone_filter.currentIndex() - 1
        self.proxy.set_filter(self.FILTERS[self.status_filter.currentIndex()][1], None if b < 0 else b)

    def visible_rows(self) -> list[tuple[int, int]]:
        """``(bone, frame)`` of the rows shown, in their order."""
        out = []
        for r in range(self.proxy.rowCount()):
            src = self.proxy.mapToSource(self.proxy.index(r, 0))
            out.append(self.table_model.locate(src.row()))
        return out

    def select_row(self, row: int) -> None:
        """Select a shown row and go to its frame and bone (as a click does)."""
        self.view.selectRow(row)
        self.view.setCurrentIndex(self.proxy.index(row, 0))
        self.view.scrollTo(self.proxy.index(row, 0))
        self._on_row(self.proxy.index(row, 0), None)

    def _on_row(self, current, _previous) -> None:
        if not current.isValid():
            return
        b, f = self.table_model.locate(self.proxy.mapToSource(current).row())
        self.viewer.select(b)
        self.viewer.set_frame(f)
