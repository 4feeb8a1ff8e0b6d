"""The calibration wizard's pages as widgets (:class:`~app.calibration.wizard.CalibrationWizard`
builds them once, in order) and the small widget helpers the pages share.

What a page shows once its step's result is in is :mod:`app.calibration.wizard_review` (flatfield,
distortion, calibration object) and :mod:`app.calibration.wizard` (solve, save).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PySide6 import QtCore, QtWidgets

from .scene import SceneView
from .views import FigureView, ImageView

PAGES = ("Session", "Flatfield", "Distortion", "Calibration object", "Solve", "Save")
MODELS = ("auto", "poly(3,3)", "poly(4,4)", "poly(5,5)", "poly(6,6)", "tps", "lwm")
# what defines the lab frame (core.calibration.session.solve_step's lab_frame), as the combo offers it
LAB_FRAMES = (("static", "The static object's frame (the cube on its stand; recommended)"),
              ("object", "The moving object's first labelled frame (the spiral's)"))
LAB_FRAME_HELP = (
    "The lab frame is the one coordinate system the cameras, and every bone pose tracked with them, are "
    "given in. By default it is the static cube's, as it stood on its stand: the same place every "
    "collection day. If the cube frame is missing or its beads could not be labelled, you may accept "
    "the spiral's first labelled frame instead: the cameras are just as accurate, but the axes are "
    "wherever the hand-held spiral happened to be, so poses are not in the lab's axes and do not "
    "compare with another day's. The calibration then carries a warning. (talus calibrate "
    "--lab-frame static|object)")
WARNING_STYLE = ("QLabel { background: #fff3cd; color: #664d03; border: 1px solid #e0a800; "
                 "border-radius: 3px; padding: 4px; }")


def _table(headers) -> QtWidgets.QTableWidget:
    t = QtWidgets.QTableWidget(0, len(headers))
    t.setHorizontalHeaderLabels(list(headers))
    t.horizontalHeader().setStretchLastSection(True)
    t.setEditTriggers(QtWidgets.QAbstractItemView.EditTrigger.NoEditTriggers)
    t.verticalHeader().setVisible(False)
    return t


def _fill(t: QtWidgets.QTableWidget, rows) -> None:
    t.setRowCount(len(rows))
    for i, row in enumerate(rows):
        for j, v in enumerate(row):
            t.setItem(i, j, QtWidgets.QTableWidgetItem(str(v)))
    t.resizeColumnsToContents()


def _fmt(x, nd=3) -> str:
    return "—" if x is None or (isinstance(x, float) and not np.isfinite(x)) else f"{x:.{nd}f}"


def _warning_label() -> QtWidgets.QLabel:
    """A label for a calibration's warnings: hidden while there are none."""
    w = QtWidgets.QLabel()
    w.setWordWrap(True)
    w.setStyleSheet(WARNING_STYLE)
    w.setTextInteractionFlags(QtCore.Qt.TextInteractionFlag.TextSelectableByMouse)
    w.setVisible(False)
    return w


def _show_warnings(label: QtWidgets.QLabel, warnings) -> None:
    warnings = list(warnings or ())
    label.setText("\n".join(f"⚠ Warning: {w}" for w in warnings))
    label.setVisible(bool(warnings))


class WizardPages:
    """The widgets of the six pages, made attributes of the wizard (a mixin of
    :class:`~app.calibration.wizard.CalibrationWizard`, which holds the slots they connect to)."""

    def _page_session(self) -> QtWidgets.QWidget:
        w = QtWidgets.QWidget()
        f = QtWidgets.QFormLayout(w)
        row = QtWidgets.QHBoxLayout()
        self.session_edit = QtWidgets.QLineEdit()
        self.session_edit.setPlaceholderText("calibration session folder (session.json)")
        browse = QtWidgets.QPushButton("Browse…")
        browse.clicked.connect(lambda: self._browse(self.session_edit, "Calibration session folder"))
        row.addWidget(self.session_edit, 1)
        row.addWidget(browse)
        f.addRow("Session folder", row)
        intro = QtWidgets.QLabel(
            "A calibration session holds, per camera, dark and empty-field frames, distortion-grid "
            "frames, calibration-object (spiral) frames and one static-object (cube) frame. Next computes "
            "the flatfield, then each page computes its step; going back keeps what was computed.")
        intro.setWordWrap(True)
        f.addRow(intro)
        self.session_info = QtWidgets.QLabel()
        self.session_info.setWordWrap(True)
        self.session_info.setTextInteractionFlags(QtCore.Qt.TextInteractionFlag.TextSelectableByMouse)
        f.addRow(self.session_info)
        self.session_edit.editingFinished.connect(self._inspect_session)
        self.session_edit.textChanged.connect(lambda _: self._update_next())
        return w

    def _page_flatfield(self) -> QtWidgets.QWidget:
        w = QtWidgets.QWidget()
        g = QtWidgets.QGridLayout(w)
        self.ff_views = [ImageView(), ImageView()]
        for k, v in enumerate(self.ff_views):
            g.addWidget(v, 0, k)
        self.rolloff_view = FigureView()
        g.addWidget(self.rolloff_view, 1, 0, 1, 2)
        return w

    def _page_distortion(self) -> QtWidgets.QWidget:
        w = QtWidgets.QWidget()
        h = QtWidgets.QHBoxLayout(w)
        left = QtWidgets.QVBoxLayout()
        self.dist_camera = QtWidgets.QComboBox()
        self.dist_camera.currentIndexChanged.connect(lambda _: self._draw_distortion())
        left.addWidget(self.dist_camera)
        self.grid_view = ImageView()
        left.addWidget(self.grid_view, 1)
        h.addLayout(left, 3)
        right = QtWidgets.QVBoxLayout()
        right.addWidget(QtWidgets.QLabel("Models, 5-fold cross-validated error on held-out grid points:"))
        self.model_table = _table(["model", "CV RMS (px)", "CV RMS (mm)", ""])
        right.addWidget(self.model_table, 1)
        self.dist_info = QtWidgets.QLabel()
        self.dist_info.setWordWrap(True)
        right.addWidget(self.dist_info)
        row = QtWidgets.QHBoxLayout()
        self.model_combo = QtWidgets.QComboBox()
        self.model_combo.setEditable(True)
        self.model_combo.addItems(MODELS)
        self.refit_button = QtWidgets.QPushButton("Use this model")
        self.refit_button.clicked.connect(self.refit)
        row.addWidget(self.model_combo, 1)
        row.addWidget(self.refit_button)
        right.addLayout(row)
        h.addLayout(right, 2)
        return w

    def _page_object(self) -> QtWidgets.QWidget:
        w = QtWidgets.QWidget()
        h = QtWidgets.QHBoxLayout(w)
        left = QtWidgets.QVBoxLayout()
        self.frame_list = QtWidgets.QListWidget()
        self.frame_list.currentRowChanged.connect(self._select_frame)
        left.addWidget(self.frame_list, 1)
        self.exclude_box = QtWidgets.QCheckBox("Exclude this frame from the solve")
        self.exclude_box.clicked.connect(self._toggle_exclude)
        left.addWidget(self.exclude_box)
        left.addWidget(QtWidgets.QLabel("Click a bead, choose its id:"))
        row = QtWidgets.QHBoxLayout()
        self.bead_combo = QtWidgets.QComboBox()
        self.assign_button = QtWidgets.QPushButton("Assign")
        self.assign_button.setEnabled(False)
        self.assign_button.clicked.connect(self.assign_label)
        row.addWidget(self.bead_combo, 1)
        row.addWidget(self.assign_button)
        left.addLayout(row)
        self.object_info = QtWidgets.QLabel()
        self.object_info.setWordWrap(True)
        left.addWidget(self.object_info)
        h.addLayout(left, 1)
        self.object_views = [ImageView(), ImageView()]
        for v, view in enumerate(self.object_views):
            view.clicked.connect(lambda u, y, v=v: self._click_bead(v, u, y))
            h.addWidget(view, 2)
        self._picked: tuple[int, int] | None = None
        return w

    def _page_solve(self) -> QtWidgets.QWidget:
        w = QtWidgets.QWidget()
        g = QtWidgets.QGridLayout(w)
        row = QtWidgets.QHBoxLayout()
        row.addWidget(QtWidgets.QLabel("Lab frame:"))
        self.lab_frame_combo = QtWidgets.QComboBox()
        for key, text in LAB_FRAMES:
            self.lab_frame_combo.addItem(text, key)
        self.lab_frame_combo.setToolTip(LAB_FRAME_HELP)
        self.lab_frame_combo.currentIndexChanged.connect(lambda _: self._lab_frame_changed())
        row.addWidget(self.lab_frame_combo)
        row.addStretch(1)
        g.addLayout(row, 0, 0, 1, 2)
        self.lab_frame_help = QtWidgets.QLabel(
            "The coordinate system of the cameras and of every pose tracked with them. The static cube's "
            "is the same every collection day; choose the spiral's first labelled frame only when the cube "
            "frame is missing or could not be labelled: the axes are then wherever the hand-held spiral "
            "happened to be, and the calibration carries a warning.")
        self.lab_frame_help.setWordWrap(True)
        self.lab_frame_help.setStyleSheet("color: #555555")
        self.lab_frame_help.setToolTip(LAB_FRAME_HELP)
        g.addWidget(self.lab_frame_help, 1, 0, 1, 2)
        self.solve_warnings = _warning_label()
        g.addWidget(self.solve_warnings, 2, 0, 1, 2)
        self.solve_info = QtWidgets.QLabel()
        self.solve_info.setWordWrap(True)
        self.solve_info.setMinimumHeight(60)
        self.solve_info.setAlignment(QtCore.Qt.AlignmentFlag.AlignTop | QtCore.Qt.AlignmentFlag.AlignLeft)
        g.addWidget(self.solve_info, 3, 0, 1, 2)
        self.reprojection_view = FigureView()
        self.scene_view = SceneView()  # cameras and the object's poses in 3-D (drag to turn)
        self.scene_view.setMinimumSize(320, 240)
        g.addWidget(self.reprojection_view, 4, 0)
        g.addWidget(self.scene_view, 4, 1)
        g.setColumnStretch(0, 2)
        g.setColumnStretch(1, 3)
        self.sd_table = _table(["camera", "f (px)", "SD f", "SD cu", "SD cv", "SID (mm)",
                                "SD source x/y/z (mm)"])
        self.sd_table.setMaximumHeight(110)
        g.addWidget(self.sd_table, 5, 0, 1, 2)
        self.resolve_button = QtWidgets.QPushButton("Solve again")
        self.resolve_button.clicked.connect(lambda: self._run_solve(force=True))
        g.addWidget(self.resolve_button, 6, 0)
        g.setRowStretch(4, 1)
        self.solve_info.setSizePolicy(QtWidgets.QSizePolicy.Policy.Preferred,
                                      QtWidgets.QSizePolicy.Policy.Minimum)
        return w

    def _page_save(self) -> QtWidgets.QWidget:
        w = QtWidgets.QWidget()
        f = QtWidgets.QFormLayout(w)
        row = QtWidgets.QHBoxLayout()
        self.study_edit = QtWidgets.QLineEdit()
        self.study_edit.setPlaceholderText("study folder (study.json)")
        browse = QtWidgets.QPushButton("Browse…")
        browse.clicked.connect(lambda: self._browse(self.study_edit, "Study folder"))
        row.addWidget(self.study_edit, 1)
        row.addWidget(browse)
        f.addRow("Study", row)
        self.series_edit = QtWidgets.QLineEdit("session")
        f.addRow("Calibration series", self.series_edit)
        self.trials_combo = QtWidgets.QComboBox()
        self.trials_combo.addItems(["series", "all", "none"])
        self.trials_combo.setToolTip("trials that use the new version: those on an earlier version of the "
                                     "series, every trial, or none")
        f.addRow("Trials using it", self.trials_combo)
        self.save_summary = QtWidgets.QLabel()  # what is saved: the object, the error, the lab frame
        self.save_summary.setWordWrap(True)
        f.addRow(self.save_summary)
        self.save_warnings = _warning_label()  # the calibration's warnings, saved with its report
        f.addRow(self.save_warnings)
        self.save_button = QtWidgets.QPushButton("Save into the study")
        self.save_button.clicked.connect(self.save)
        f.addRow(self.save_button)
        self.save_info = QtWidgets.QLabel("Earlier versions are kept; the new one is saved as the next "
                                          "version.")
        self.save_info.setWordWrap(True)
        f.addRow(self.save_info)
        self.study_info = QtWidgets.QLabel()
        self.study_info.setWordWrap(True)
        f.addRow(self.study_info)
        self.study_edit.editingFinished.connect(self._describe_study)
        self.trials_combo.currentIndexChanged.connect(lambda _: self._describe_study())
        return w

    def _browse(self, edit: QtWidgets.QLineEdit, title: str) -> None:
        d = QtWidgets.QFileDialog.getExistingDirectory(self, title, edit.text() or str(Path.cwd()))
        if d:
            edit.setText(d)
            edit.editingFinished.emit()  # summarised as when typed

