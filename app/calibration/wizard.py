"""The calibration wizard: a calibration session, one step per page, saved into a study.

Pages: session folder → flatfield (the corrected field and its roll-off) → distortion (grid
points found on a frame, residual vectors, the cross-validated model table; another model can
be chosen) → calibration object (the frames with their detections and labels; a frame can be
excluded, a wrong label fixed by clicking the bead and choosing its id) → solve (bundle
adjustment: reprojection, cameras and object poses, parameter SDs; what defines the lab frame)
→ save into a study. The calibration report's warnings (``report["warnings"]``, e.g. a lab frame
that is not the static cube's) are shown on the solve and save pages.

The lab frame is the static object's (cube's) by default, as ``talus calibrate``: a cube frame
that was recorded but cannot be labelled makes the solve fail, naming the file. The solve page
offers the other choice of ``talus calibrate --lab-frame object``: the moving object's first
labelled frame, accepted with a warning.

The computing is that of ``talus calibrate``, step by step (:mod:`core.calibration.session`:
:func:`~core.calibration.session.prepare`, ``flatfield_step``, ``distortion_step``,
``refit_distortion``, ``beads_step``, ``exclude_frames``, ``relabel``, ``solve_step``; saving is
:func:`core.study.calibrations.save_session_calibration`), as :mod:`app.calibration.jobs` runs
them. Every step runs in a :class:`~app.workers.WorkerPool`; its result is kept, so going back
shows it at once, and only the steps after a change are computed again. A saved calibration can
be opened again (:meth:`CalibrationWizard.inspect_saved`) to see what it was made from and redo it.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from PySide6 import QtCore, QtWidgets

from ..workers import WorkerPool
from .jobs import (
    flatfield_for,
    job_beads,
    job_distortion,
    job_frame,
    job_inspect,
    job_refit,
    job_save,
    job_solve,
    short_name,
)
from .scene import SceneView
from .views import FigureView, ImageView

__all__ = ["CalibrationWizard"]

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


# ---------------------------------------------------------------------------- pages
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


class CalibrationWizard(QtWidgets.QDialog):
    """File → Calibrate… (module docs). ``saved_calibration`` is emitted with the
    :class:`~core.study.calibrations.SavedCalibration` once saved."""

    saved_calibration = QtCore.Signal(object)
    step_done = QtCore.Signal(str)  # the key of a step whose result arrived (or failed/cancelled)

    def __init__(self, parent=None, *, session_folder=None, study_folder=None,
                 pool: WorkerPool | None = None):
        super().__init__(parent)
        self.setWindowTitle("Calibrate")
        self.resize(1000, 720)
        self.pool = pool if pool is not None else WorkerPool(self)
        self._own_pool = pool is None
        self.results: dict = {}  # step -> result (kept: going back is instant)
        self._frames: dict = {}  # object frame -> corrected images
        self._solves: dict = {}  # lab frame -> solve result of the current beads (switching back is instant)
        self._running: str | None = None
        self._closed = False
        self._last_saved: str | None = None  # the version this wizard saved last
        self._inspected: str | None = None  # the session folder last summarised on the first page
        self._saved_note = ""  # what a reopened saved calibration was made from (inspect_saved)
        self.pool.finished.connect(self._finished)
        self.pool.failed.connect(self._failed)
        self.pool.cancelled.connect(self._cancelled)
        self.pool.progress.connect(self._progress)

        self.stack = QtWidgets.QStackedWidget()
        self.title = QtWidgets.QLabel()
        self.title.setStyleSheet("font-weight: bold; font-size: 14px")
        self.status = QtWidgets.QLabel()
        self.status.setWordWrap(True)
        self.bar = QtWidgets.QProgressBar()
        self.bar.setVisible(False)
        self.cancel_button = QtWidgets.QPushButton("Cancel step")
        self.cancel_button.setEnabled(False)
        self.cancel_button.clicked.connect(self.cancel_step)
        self.back_button = QtWidgets.QPushButton("< Back")
        self.next_button = QtWidgets.QPushButton("Next >")
        self.close_button = QtWidgets.QPushButton("Close")
        self.back_button.clicked.connect(self.back)
        self.next_button.clicked.connect(self.next)
        self.close_button.clicked.connect(self.close)
        buttons = QtWidgets.QHBoxLayout()
        for w in (self.bar, self.cancel_button):
            buttons.addWidget(w)
        buttons.addStretch(1)
        for w in (self.back_button, self.next_button, self.close_button):
            buttons.addWidget(w)
        lay = QtWidgets.QVBoxLayout(self)
        lay.addWidget(self.title)
        lay.addWidget(self.stack, 1)
        lay.addWidget(self.status)
        lay.addLayout(buttons)
        for build in (self._page_session, self._page_flatfield, self._page_distortion, self._page_object,
                      self._page_solve, self._page_save):
            self.stack.addWidget(build())
        if session_folder is not None:
            self.session_edit.setText(str(session_folder))
        if study_folder is not None:
            self.study_edit.setText(str(study_folder))
        self._show(0)
        self._inspect_session()

    # ------------------------------------------------------------------ pages
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

    # ------------------------------------------------------------------ navigation
    @property
    def page(self) -> int:
        return self.stack.currentIndex()

    def _show(self, k: int) -> None:
        self.stack.setCurrentIndex(k)
        self.title.setText(f"Step {k + 1} of {len(PAGES)}: {PAGES[k]}")
        self.back_button.setEnabled(k > 0)
        if self._running is None:
            self.status.setText("")
        {1: self._enter_flatfield, 2: self._enter_distortion, 3: self._enter_object, 4: self._enter_solve,
         5: self._enter_save}.get(k, lambda: None)()
        self._update_next()

    def _update_next(self) -> None:
        need = {0: None, 1: "flatfield", 2: "distortion", 3: "beads", 4: "solve", 5: None}[self.page]
        ok = self.page < len(PAGES) - 1 and (need is None or need in self.results) and self._running is None
        if self.page == 0:
            ok = bool(self.session_edit.text().strip()) and self._running is None
        self.next_button.setEnabled(ok)

    def next(self) -> None:
        if self.page < len(PAGES) - 1:
            self._show(self.page + 1)

    def back(self) -> None:
        if self._running is not None:
            self.cancel_step()
        if self.page > 0:
            self._show(self.page - 1)

    def _submit(self, key: str, fn, *args, **kwargs) -> None:
        self._running = key
        self.bar.setRange(0, 0)
        self.bar.setVisible(True)
        self.cancel_button.setEnabled(True)
        self.status.setStyleSheet("")
        self.status.setText(f"{key}: computing…")
        self.pool.submit(key, fn, *args, **kwargs)
        self._update_next()

    def cancel_step(self) -> None:
        """Cancel the step that is computing: the window is free at once; the step stops at its next
        frame and its result, if one still comes, is dropped (nothing is saved)."""
        key = self._running
        if key is not None:
            self.pool.cancel(key)
            self._cancelled(key)

    def _invalidate(self, *steps: str) -> None:
        for s in steps:
            self.results.pop(s, None)
        if "beads" in steps:
            self._frames.clear()
        if "solve" in steps:
            self._solves.clear()

    # ------------------------------------------------------------------ worker answers
    def _idle(self) -> None:
        self._running = None
        self.bar.setVisible(False)
        self.cancel_button.setEnabled(False)

    def _progress(self, key: str, done: int, total: int) -> None:
        if key == self._running:
            self.bar.setRange(0, max(total, 1))
            self.bar.setValue(done)
            self.status.setText(f"{key}: {done} of {total}")

    def _inspect_session(self) -> None:
        folder = self.session_edit.text().strip()
        if folder and folder != self._inspected:
            self._inspected = folder
            self.session_info.setStyleSheet("")
            self.session_info.setText(f"Reading {folder}…")
            self.pool.submit("inspect", job_inspect, folder)

    def _finished(self, key: str, result) -> None:
        if key == "inspect":
            self.session_info.setStyleSheet("")
            self.session_info.setText(self._saved_note + result)
            self.step_done.emit(key)
            return
        if key == "frame":
            k, imgs = result
            self._frames[k] = imgs
            if self.frame_list.currentRow() == k:
                self._draw_frame()
            self.step_done.emit(key)
            return
        if key != self._running:
            return  # a step cancelled or superseded: its answer is dropped
        self._idle()
        self.status.setText(f"{key}: done")
        if key == "save":
            self.save_info.setText(f"Saved as {result.name} in {result.folder}; used by "
                                   f"{', '.join(result.trials) or 'no trial yet'}.")
            self._last_saved = result.name
            self._describe_study()
            self.saved_calibration.emit(result)
        elif key == "refit":
            self.results["distortion"] = result
            self._invalidate("beads", "solve")
        else:
            self.results[key] = result
        if key == "solve":
            self._solves[result["lab_frame"]] = result
        enter = {"flatfield": self._enter_flatfield, "distortion": self._enter_distortion,
                 "refit": self._enter_distortion, "beads": self._enter_object, "solve": self._enter_solve}
        enter.get(key, lambda: None)()
        self._update_next()
        self.step_done.emit(key)

    def _failed(self, key: str, text: str) -> None:
        if key == "inspect":
            last = text.strip().splitlines()[-1] if text.strip() else text
            self.session_info.setStyleSheet("color: #c00000")
            self.session_info.setText(self._saved_note
                                      + f"Not a usable calibration session: {last.split(': ', 1)[-1]}")
            self.step_done.emit(key)
            return
        if key != "frame" and key != self._running:
            return  # a step cancelled or superseded
        if "CalibrationCancelled" in text:  # cancel() seen between frames: the step stopped there
            self._cancelled(key)
            return
        if key != "frame":
            self._idle()
        last = text.strip().splitlines()[-1] if text.strip() else text
        msg = last.split(": ", 1)[1] if last.split(":", 1)[0].endswith(("Error", "Exception")) else last
        self.status.setStyleSheet("color: #c00000")
        self.status.setText(f"{key} failed: {msg}")
        if key == "solve":
            self._solve_failed(msg)
        self._update_next()
        self.step_done.emit(key)

    def _clear_solve(self) -> None:
        """Nothing of an earlier solve stays on the page while another computes or after it failed."""
        self.reprojection_view.clear_figure()
        self.scene_view.set_scene(None)
        self.sd_table.setRowCount(0)
        _show_warnings(self.solve_warnings, [])

    def _solve_failed(self, msg: str) -> None:
        """The solve page says that it failed (the message, with the file, is in the status line)
        and what the wizard offers when the cube cannot define the lab frame."""
        b, setup = self.results.get("beads"), self.results["flatfield"]["setup"]
        text = "The solve failed: the message below says why and where."
        if self.lab_frame == "static" and b is not None and any(not f.ok for f in b.static_frames):
            text = (f"The solve failed: the static {setup.static.name} frame could not be labelled, so it "
                    f"cannot define the lab frame. Record it again, or choose “{LAB_FRAMES[1][1]}” under Lab "
                    "frame above: the solve runs again, and the calibration carries a warning that its lab "
                    f"frame is not the {setup.static.name}'s.")
        self.solve_info.setStyleSheet("color: #c00000")
        self.solve_info.setText(text)
        self._clear_solve()

    def _cancelled(self, key: str) -> None:
        if key == "frame":
            return
        if key != self._running:
            return
        self._idle()
        self.status.setText(f"{key}: cancelled")
        self._update_next()
        self.step_done.emit(key)

    # ------------------------------------------------------------------ flatfield
    def _enter_flatfield(self) -> None:
        folder = self.session_edit.text().strip()
        r = self.results.get("flatfield")
        if r is not None and r.get("folder") != folder:
            self._invalidate("flatfield", "distortion", "beads", "solve")
            r = None
        if r is None:
            if self._running is None:
                self._submit("flatfield", flatfield_for, folder)
            return
        setup = r["setup"]
        for view, cam, img, (ff, kv) in zip(self.ff_views, setup.cameras, r["corrected"], r["flatfields"],
                                            strict=True):
            view.set_image(img, levels=(0.0, 1.25))
            from .figures import field_fraction

            view.caption = (f"{cam}: a corrected empty-field frame" + (f" ({kv:g} kV)" if kv else "")
                            + f"; {100 * field_fraction(ff):.0f} % of the image inside the field")
            view.set_points(np.zeros((0, 2)))
        self.rolloff_view.set_figure(r["rolloff"])

    # ------------------------------------------------------------------ distortion
    def _enter_distortion(self) -> None:
        r = self.results.get("distortion")
        if r is None:
            ff = self.results.get("flatfield")
            if ff is not None and self._running is None:
                self._submit("distortion", job_distortion, ff["setup"], ff["flatfields"])
            return
        if self.dist_camera.count() != len(r["dist"].cameras):
            self.dist_camera.blockSignals(True)
            self.dist_camera.clear()
            self.dist_camera.addItems([c.name for c in r["dist"].cameras])
            self.dist_camera.blockSignals(False)
        self._draw_distortion()

    def _draw_distortion(self) -> None:
        r = self.results.get("distortion")
        if r is None:
            return
        k = max(self.dist_camera.currentIndex(), 0)
        c, view = r["dist"].cameras[k], r["views"][k]
        g = c.grid
        n = np.linalg.norm(view["resid"], axis=1)
        scale = 10.0 / max(float(np.percentile(n, 99)) if n.size else 1.0, 1e-6)
        self.grid_view.set_image(view["image"])
        self.grid_view.set_points(view["uv"], vectors=view["resid"], vector_scale=scale)
        st = g.residuals.to_dict()["mm"]
        self.grid_view.caption = (f"{c.name}: {len(view['uv'])} grid points of {view['ref']}; residual "
                                  f"vectors × {scale:.0f}")
        rows = []
        for t in g.table:
            rows.append([t["model"], _fmt(t.get("rms_px")), _fmt(t.get("rms_mm"), 4),
                         "chosen" if t["model"] == g.spec.label else ""])
        if not any(row[3] for row in rows):
            rows.append([g.spec.label, "(given)", "", "chosen"])
        _fill(self.model_table, rows)
        self.dist_info.setText(f"{c.name}: {g.spec.label}; grid residual RMS {st['rms']:.4f} mm (max "
                               f"{st['max']:.4f} mm) over {len(g.ideal_uv)} points of {g.n_placements} "
                               f"placement(s)." + "".join(f"\n{n}" for n in g.notes))

    def refit(self) -> None:
        """Fit the chosen model to the current camera's grid points (later steps are redone)."""
        r, ff = self.results.get("distortion"), self.results.get("flatfield")
        if r is None or self._running is not None:
            return
        self._submit("refit", job_refit, ff["setup"], r["dist"], max(self.dist_camera.currentIndex(), 0),
                     self.model_combo.currentText().strip())

    # ------------------------------------------------------------------ object frames
    def _enter_object(self) -> None:
        b = self.results.get("beads")
        if b is None:
            ff, d = self.results.get("flatfield"), self.results.get("distortion")
            if d is not None and self._running is None:
                self._submit("beads", job_beads, ff["setup"], d["dist"])
            return
        setup = self.results["flatfield"]["setup"]
        if self.bead_combo.count() != len(setup.target):
            self.bead_combo.clear()
            self.bead_combo.addItems([str(i) for i in setup.target.bead_ids])
        row = max(self.frame_list.currentRow(), 0)
        self._fill_frames()
        self.frame_list.setCurrentRow(row)
        self._select_frame(row)

    def _fill_frames(self) -> None:
        b = self.results["beads"]
        self.frame_list.blockSignals(True)
        row = self.frame_list.currentRow()
        self.frame_list.clear()
        for k, fr in enumerate(b.frames):
            labs = "/".join(str(lab.n_labelled) for lab in fr.labellings)
            state = "excluded" if k in b.excluded else ("ok" if fr.ok else f"not used: {fr.reason}")
            manual = " (edited)" if any(lab.manual for lab in fr.labellings) else ""
            self.frame_list.addItem(f"frame {k}: {labs} labelled, {state}{manual}")
        self.frame_list.setCurrentRow(row)
        self.frame_list.blockSignals(False)
        n = sum(1 for k, fr in enumerate(b.frames) if fr.ok and k not in b.excluded)
        setup = self.results["flatfield"]["setup"]
        static = getattr(setup.static, "name", "static object")
        bad = [f for f in b.static_frames if not f.ok]
        if not b.static_frames:
            cube = (f"no static {static} frame: the lab frame will be the {setup.target.name}'s first "
                    "labelled frame (with a warning)")
        elif bad:
            cube = (f"the static {static} frame could not be labelled ({bad[0].reason}): the solve needs "
                    f"it for the lab frame, unless the {setup.target.name}'s first labelled frame is "
                    "chosen on the Solve page")
        else:
            cube = f"the static {static} frame is labelled (it defines the lab frame)"
        self.object_info.setText(f"{n} of {len(b.frames)} frames go to the solve; {cube}.")

    def _select_frame(self, k: int) -> None:
        b = self.results.get("beads")
        if b is None or k < 0:
            return
        self._picked = None
        self.assign_button.setEnabled(False)
        self.exclude_box.setChecked(k in b.excluded)
        if k in self._frames:
            self._draw_frame()
        else:
            ff, d = self.results["flatfield"], self.results["distortion"]
            for v in self.object_views:
                v.caption = f"frame {k}: correcting…"
                v.update()
            self.pool.submit("frame", lambda: (k, job_frame(ff["setup"], d["dist"], b, k)))

    def _draw_frame(self) -> None:
        b = self.results.get("beads")
        k = self.frame_list.currentRow()
        if b is None or k not in self._frames:
            return
        setup = self.results["flatfield"]["setup"]
        fr = b.frames[k]
        for v, (view, img) in enumerate(zip(self.object_views, self._frames[k], strict=True)):
            lab = fr.labellings[v]
            ids = [str(setup.target.bead_ids[i]) if i >= 0 else "" for i in lab.labels]
            cols = ["#40ff40" if i >= 0 else "#ff4040" for i in lab.labels]
            view.set_image(img)
            view.set_points(lab.uv, colors=cols, labels=ids)
            if self._picked is not None and self._picked[0] == v:
                view.selected = self._picked[1]
            view.caption = (f"{setup.cameras[v]}, frame {k}: {lab.n_labelled} of {len(lab.uv)} detections "
                            f"labelled" + (" (edited)" if lab.manual else ""))

    def _click_bead(self, v: int, u: float, y: float) -> None:
        b = self.results.get("beads")
        k = self.frame_list.currentRow()
        if b is None or k < 0:
            return
        i = self.object_views[v].nearest(u, y)
        self._picked = None if i is None else (v, i)
        self.assign_button.setEnabled(i is not None)
        for w, view in enumerate(self.object_views):
            view.selected = i if w == v else None
            view.update()
        if i is not None:
            lab = b.frames[k].labellings[v]
            cur = int(lab.labels[i])
            if cur >= 0:
                self.bead_combo.setCurrentIndex(cur)
            ids = self.results["flatfield"]["setup"].target.bead_ids
            now = f"bead {ids[cur]}" if cur >= 0 else "unlabelled"
            self.status.setText(f"detection {i} of view {v + 1} selected (now {now}); choose its id and "
                                "Assign")

    def assign_label(self) -> None:
        """The picked detection becomes the bead chosen in the list (the solve is redone)."""
        from core.calibration.session import relabel

        b = self.results.get("beads")
        k = self.frame_list.currentRow()
        if b is None or self._picked is None:
            return
        v, i = self._picked
        bead = self.bead_combo.currentIndex()
        self.results["beads"] = relabel(b, k, v, i, bead)
        self._invalidate("solve")
        self.status.setText(f"frame {k}, view {v + 1}: detection {i} is now bead "
                            f"{self.bead_combo.currentText()}")
        self._fill_frames()
        self._draw_frame()

    def _toggle_exclude(self, checked: bool) -> None:
        from core.calibration.session import exclude_frames

        b = self.results.get("beads")
        k = self.frame_list.currentRow()
        if b is None or k < 0:
            return
        ex = set(b.excluded) | {k} if checked else set(b.excluded) - {k}
        self.results["beads"] = exclude_frames(b, ex)
        self._invalidate("solve")
        self._fill_frames()

    # ------------------------------------------------------------------ solve
    @property
    def lab_frame(self) -> str:
        """What defines the lab frame of the solve: ``"static"`` (the cube's) or ``"object"``."""
        return self.lab_frame_combo.currentData()

    def _lab_frame_changed(self) -> None:
        """Another lab frame chosen: its solve is shown (computed once per choice and kept)."""
        if self._running == "solve":
            self.cancel_step()
        if self.page == 4:
            self._run_solve(force=False)
            self._update_next()

    def _enter_solve(self) -> None:
        self._run_solve(force=False)

    def _run_solve(self, *, force: bool) -> None:
        lab = self.lab_frame
        r = self.results.get("solve")
        if r is None or r["lab_frame"] != lab:  # this choice's solve, if it was computed
            r = self._solves.get(lab)
            if r is None:
                self.results.pop("solve", None)
            else:
                self.results["solve"] = r
        if r is None or force:
            b = self.results.get("beads")
            _show_warnings(self.solve_warnings, [])
            if b is not None and self._running is None:
                self._solves.pop(lab, None)
                self._clear_solve()
                self.solve_info.setStyleSheet("")
                self.solve_info.setText("Bundle adjustment running…")
                self._submit("solve", job_solve, self.results["flatfield"]["setup"],
                             self.results["distortion"]["dist"], b, lab)
            return
        cal = r["cal"]
        rep = cal.report
        _show_warnings(self.solve_warnings, rep.get("warnings"))
        self.solve_info.setStyleSheet("")
        self.reprojection_view.set_figure(r["reprojection"])
        if self.scene_view.scene is None or getattr(self.scene_view.scene, "cal", None) is not cal:
            # drawn once the page's text and plots are on screen (VTK renders on the GUI thread)
            self.scene_view.caption = "drawing the cameras and object poses…"
            self.scene_view.update()
            QtCore.QTimer.singleShot(0, lambda: self._draw_scene(cal))
        rows = []
        for c in rep["rig"]:
            sd = c["std"]
            rows.append([c["name"], _fmt(c["fx_px"], 1), _fmt(sd["f_px"]), _fmt(sd["cu_px"]),
                         _fmt(sd["cv_px"]), _fmt(c["sid_mm"], 1),
                         " / ".join(_fmt(s) for s in sd["source_mm"])])
        _fill(self.sd_table, rows)
        ev = rep.get("error_volume", {}).get("rms_mm")
        self.solve_info.setText(f"Reprojection RMS {rep['bundle']['rms_px']:.3f} px over "
                                f"{rep['n_frames_labelled']} labelled frames; predicted 3-D reconstruction "
                                f"error {_fmt(ev)} mm RMS over the capture volume."
                                + "".join(f"\n{n}" for n in rep.get("notes", [])))

    def _draw_scene(self, cal) -> None:
        r = self.results.get("solve")
        if (self._closed or r is None or r["cal"] is not cal
                or getattr(self.scene_view.scene, "cal", None) is cal):
            return
        from .scene import scene_from_calibration

        scene = scene_from_calibration(cal)
        scene.cal = cal
        self.scene_view.caption = ""
        self.scene_view.set_scene(scene)

    # ------------------------------------------------------------------ save
    def _enter_save(self) -> None:
        self.save_button.setEnabled("solve" in self.results and self._running is None)
        r = self.results.get("solve")
        if r is None:
            self.save_summary.setText("Nothing to save yet: solve first.")
            _show_warnings(self.save_warnings, [])
        else:
            rep = r["cal"].report
            lab = rep.get("lab_frame") or {}
            obj = lab.get("object", "?")
            where = (f"the static {obj} frame" if lab.get("defined_by") == "static"
                     else f"the first labelled frame of the {obj}")
            self.save_summary.setText(
                f"To save: reprojection RMS {rep['bundle']['rms_px']:.3f} px over {rep['n_frames_labelled']} "
                f"labelled frames; lab frame: {where}"
                + (f" ({short_name(lab['frame'][0], self.results['flatfield']['setup'])})" if lab.get("frame")
                   else "") + " (chosen on the Solve page).")
            _show_warnings(self.save_warnings, rep.get("warnings"))
        self._describe_study()

    def _describe_study(self) -> None:
        """The study's trials and the calibration each uses, and which will use the new version."""
        folder = Path(self.study_edit.text().strip() or ".")
        try:
            doc = json.loads((folder / "study.json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            self.study_info.setText(f"No study (study.json) in {folder}." if self.study_edit.text().strip()
                                    else "Choose the study folder.")
            return
        series = self.series_edit.text().strip() or "session"
        mode = self.trials_combo.currentText()
        rows = []
        for name, tr in doc.get("trials", {}).items():
            cur = tr.get("calibration") or "none"
            if cur == self._last_saved:
                rows.append(f"• {name}: uses {cur} (just saved)")
                continue
            new = mode == "all" or (mode == "series" and str(cur).startswith(f"{series}.v"))
            rows.append(f"• {name}: uses {cur}" + (" → will use the new version" if new else ""))
        saved = doc.get("settings", {}).get("calibration_files", {})
        mine = sorted(k for k in saved if k.startswith(f"{series}.v"))
        self.study_info.setText(
            f"Trials using it: 'series' moves the trials on an earlier version of {series} to the new one, "
            "'all' moves every trial, 'none' only saves it.\n"
            f"Saved versions of {series}: {', '.join(mine) or 'none yet'}.\nTrials of the study:\n"
            + ("\n".join(rows) or "(none)"))

    def save(self) -> None:
        """Save the solved calibration into the study as the next version of the series."""
        r = self.results.get("solve")
        folder = self.study_edit.text().strip()
        if r is None or self._running is not None:
            return
        if not folder or not (Path(folder) / "study.json").is_file():
            self.status.setStyleSheet("color: #c00000")
            self.status.setText(f"Study: no study (study.json) in {folder or '(no folder given)'}")
            return
        self._submit("save", job_save, folder, r["cal"], self.series_edit.text().strip(),
                     self.trials_combo.currentText(), self.session_edit.text().strip())

    # ------------------------------------------------------------------ a saved calibration
    @classmethod
    def inspect_saved(cls, study_folder, name: str, parent=None, **kwargs) -> CalibrationWizard:
        """A wizard on the saved calibration version ``name`` of the study: what it was made from
        (its session folder, object, reprojection error, report) on the first page; Next redoes it."""
        folder = Path(study_folder)
        doc = json.loads((folder / "study.json").read_text(encoding="utf-8"))
        entry = doc.get("settings", {}).get("calibration_files", {}).get(name)
        if entry is None:
            have = list(doc.get("settings", {}).get("calibration_files", {}))
            raise ValueError(f"calibration: no saved session calibration named {name!r} in {folder} "
                             f"(have {have})")
        meta = json.loads((folder / entry["folder"] / "version.json").read_text(encoding="utf-8"))
        w = cls(parent, session_folder=meta.get("session") or "", study_folder=folder, **kwargs)
        w.series_edit.setText(str(entry.get("series", "session")))
        report = {}
        if entry.get("report"):
            try:
                report = json.loads((folder / entry["report"]).read_text(encoding="utf-8"))
            except (OSError, ValueError):
                report = {}
        if (report.get("lab_frame") or {}).get("defined_by") == "object":  # redone as it was made
            w.lab_frame_combo.setCurrentIndex(1)
        warned = "".join(f"\n⚠ Warning: {x}" for x in report.get("warnings", []))
        w._saved_note = (
            f"Saved calibration {name} ({meta.get('created')}): object {meta.get('object')}, static object "
            f"{meta.get('static_object')}, reprojection RMS {meta.get('rms_px', float('nan')):.3f} px; "
            f"report: {folder / entry['report'] if entry.get('report') else '(none)'}.{warned}\n"
            f"Made from the session {meta.get('session')}. Next recomputes it step by step; saving makes "
            "a new version (this one is kept).\n\n")
        w.session_info.setText(w._saved_note + w.session_info.text())
        return w

    def closeEvent(self, ev) -> None:
        if self._running is not None:
            self.pool.cancel(self._running)
        if self._own_pool:
            self.pool.shutdown(wait=False)
        self._closed = True
        self.scene_view.close_scene()
        super().closeEvent(ev)
