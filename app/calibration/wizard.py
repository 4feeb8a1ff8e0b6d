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

This module holds the dialog, its navigation, the worker answers and the solve and save pages; the
pages' widgets are built by :mod:`app.calibration.wizard_pages`, and what the flatfield, distortion
and calibration-object pages show and edit is :mod:`app.calibration.wizard_review`.
"""

from __future__ import annotations

import json
from pathlib import Path

from PySide6 import QtCore, QtWidgets

from ..workers import WorkerPool
from .jobs import job_inspect, job_save, job_solve, short_name
from .wizard_pages import LAB_FRAMES, PAGES, WizardPages, _fill, _fmt, _show_warnings
from .wizard_review import StepReview

__all__ = ["CalibrationWizard"]


class CalibrationWizard(WizardPages, StepReview, QtWidgets.QDialog):
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
