"""*File → Export…*: one dialog for every export of the open trial.

The list holds every pose format of :func:`core.study.exports.available_formats` (labelled with
the coordinate frame its numbers are in: the two ``.tra`` formats say which is Autoscoper's),
the plots of the Plots dock as PNG, SVG or PDF (:meth:`app.plots.PlotsDock.export`) and the
trial report as HTML or PDF (:func:`core.study.report.write_report`). Below: what the selected
format holds, the bones to write (pose formats), the frame rate the C3D, OpenSim and JCS files
record (an imported XMALab trial's recording speed, else 100 Hz), *Smoothed poses* (pose formats:
each bone's poses smoothed over the trial written instead of the tracked ones,
:func:`core.tracking.smoothing_trial.smoothed_poses`; off by default), and where (a file, or a folder
for the formats written one file per bone), filled with ``<study>/exports/<trial>…`` and changed by typing or
*Browse…*. *Export* writes it and keeps the dialog open for the next one; a failure is said in
the dialog, in red, with its reason.
"""

from __future__ import annotations

from pathlib import Path

from PySide6 import QtCore, QtGui, QtWidgets

__all__ = ["ExportDialog"]

_KIND = QtCore.Qt.ItemDataRole.UserRole
RATE_FORMATS = ("c3d", "mot", "trc", "jcs")  # the formats that record a frame rate
#: *Smoothed poses*' tooltip (core.tracking.smoothing_trial.smoothed_poses)
SMOOTHED_TIP = ("Write each bone's poses smoothed over the trial (a constant-acceleration "
                "Rauch-Tung-Striebel smoother; its smoothing and the confidence's scale from the data) "
                "instead of the tracked ones, which stay the results. On the synthetic walking trial's "
                "stored runs x the single-frame Cramer-Rao bound 0.55-1.13 mm / 0.42-1.21 deg against "
                "1.18-1.92 / 1.27-1.81 per frame; about a fast impact it can be further off than the frames "
                "themselves (rotation, 6 of 18 runs with a 1 mm / 1 deg jerk added).")


class ExportDialog(QtWidgets.QDialog):
    """Export the window's open trial (see the module docs)."""

    def __init__(self, window) -> None:
        super().__init__(window)
        from core.study.exports import available_formats, recording_rate

        self.window = window
        s = window.session
        if s is None:
            raise ValueError("study: open a study first")
        self.setWindowTitle("Export")
        self.setObjectName("export-dialog")
        self.trial = s.study.trial(s.trial_name)
        self.formats = QtWidgets.QListWidget()
        self.formats.setObjectName("export-formats")
        self._choices: list[tuple[str, str, str, bool, str]] = []  # kind, format, suffix, folder, about
        for name, f in available_formats().items():
            self._add(f"Poses: {f.text}", "poses", name, f.suffix, f.folder, f"{name}: {f.description}")
        plots = getattr(window.review, "plots", None)
        if plots is not None:
            for suffix, what in ((".png", "PNG, one file per page"), (".svg", "SVG, one file per page"),
                                 (".pdf", "PDF")):
                self._add(f"Plots: {what}", "plots", "plots", suffix, False,
                          "The Plots dock's pages (pose, joint angles, helical axis, joint space).")
        for suffix in (".html", ".pdf"):
            self._add(f"Trial report ({suffix[1:].upper()})", "report", "report", suffix, False,
                      "One page: calibration, tracking summary, plots and the flagged frames.")
        self.about = QtWidgets.QLabel()
        self.about.setObjectName("export-about")
        self.about.setWordWrap(True)
        self.bones = QtWidgets.QListWidget()
        self.bones.setObjectName("export-bones")
        for b in self.trial.bones:
            it = QtWidgets.QListWidgetItem(b)
            it.setFlags(it.flags() | QtCore.Qt.ItemFlag.ItemIsUserCheckable)
            it.setCheckState(QtCore.Qt.CheckState.Checked)
            self.bones.addItem(it)
        self.bones.setMaximumHeight(90)
        self.rate = QtWidgets.QDoubleSpinBox()
        self.rate.setObjectName("export-rate")
        self.rate.setRange(0.1, 100000.0)
        self.rate.setDecimals(2)
        self.rate.setSuffix(" Hz")
        self.rate.setValue(recording_rate(s.study, s.trial_name))
        self.rate.setToolTip("Frame rate written into the C3D, OpenSim and JCS files (an imported XMALab "
                             "trial's recording speed, else 100 Hz)")
        self.smoothed = QtWidgets.QCheckBox("Smoothed poses (pooled over neighbouring frames)")
        self.smoothed.setObjectName("export-smoothed")
        self.smoothed.setToolTip(SMOOTHED_TIP)
        self.path = QtWidgets.QLineEdit()
        self.path.setObjectName("export-path")
        self.browse = QtWidgets.QPushButton("Browse…")
        self.browse.clicked.connect(self._browse)
        self.status = QtWidgets.QLabel()
        self.status.setObjectName("export-status")
        self.status.setWordWrap(True)
        self.status.setTextInteractionFlags(QtCore.Qt.TextInteractionFlag.TextSelectableByMouse)
        self.buttons = QtWidgets.QDialogButtonBox()
        accept = QtWidgets.QDialogButtonBox.ButtonRole.AcceptRole
        self.export_button = self.buttons.addButton("Export", accept)
        self.close_button = self.buttons.addButton(QtWidgets.QDialogButtonBox.StandardButton.Close)
        self.export_button.clicked.connect(self.export)
        self.close_button.clicked.connect(self.reject)
        where = QtWidgets.QHBoxLayout()
        where.addWidget(self.path, 1)
        where.addWidget(self.browse)
        form = QtWidgets.QFormLayout()
        form.addRow("Bones", self.bones)
        form.addRow("Frame rate", self.rate)
        form.addRow("", self.smoothed)
        form.addRow("Save to", where)
        lay = QtWidgets.QVBoxLayout(self)
        lay.addWidget(QtWidgets.QLabel(f"Trial {s.trial_name!r} of {s.study.folder}"))
        lay.addWidget(self.formats, 1)
        lay.addWidget(self.about)
        lay.addLayout(form)
        lay.addWidget(self.status)
        lay.addWidget(self.buttons)
        self.resize(640, 560)
        self.formats.currentRowChanged.connect(self._chosen)
        self.formats.setCurrentRow(0)

    def _add(self, text, kind, fmt, suffix, folder, about) -> None:
        it = QtWidgets.QListWidgetItem(text)
        it.setToolTip(about)
        it.setData(_KIND, len(self._choices))
        self._choices.append((kind, fmt, suffix, folder, about))
        self.formats.addItem(it)

    # ------------------------------------------------------------------ choices
    @property
    def choice(self) -> tuple[str, str, str, bool, str]:
        """``(kind, format, suffix, folder, about)`` of the selected row."""
        return self._choices[max(0, self.formats.currentRow())]

    def select(self, fmt: str, suffix: str | None = None) -> None:
        """Select the row of ``fmt`` (a pose format name, ``"plots"`` or ``"report"``; ``suffix``
        picks among the plots' and report's)."""
        for k, (_, f, sfx, _, _) in enumerate(self._choices):
            if f == fmt and (suffix is None or sfx == suffix):
                self.formats.setCurrentRow(k)
                return
        have = sorted({c[1] for c in self._choices})
        raise ValueError(f"fmt: no export named {fmt!r} {suffix or ''} (have {have})")

    def _default_path(self) -> Path:
        kind, fmt, suffix, folder, _ = self.choice
        study_folder = Path(self.window.session.study.folder)
        if kind == "poses":  # the name talus export writes without --out
            from core.study.exports import default_path

            return default_path(study_folder, self.trial.name, fmt)
        stem = f"{self.trial.name}_{kind}"
        return study_folder / "exports" / (stem if folder else f"{stem}{suffix}")

    def _chosen(self, row: int) -> None:
        kind, about = self.choice[0], self.choice[4]
        self.about.setText(about)
        self.bones.setEnabled(kind == "poses")
        self.rate.setEnabled(kind == "poses" and self.choice[1] in RATE_FORMATS)
        self.smoothed.setEnabled(kind == "poses")
        self.path.setText(str(self._default_path()))
        self.status.clear()

    def _browse(self) -> None:
        _, fmt, suffix, folder, _ = self.choice
        start = self.path.text() or str(self._default_path())
        if folder:
            path = QtWidgets.QFileDialog.getExistingDirectory(self, "Export to the folder", start)
        else:
            path, _ = QtWidgets.QFileDialog.getSaveFileName(self, "Export", start, f"{fmt} (*{suffix})")
            if path and not path.lower().endswith(suffix):
                path += suffix
        if path:
            self.path.setText(path)

    def chosen_bones(self) -> list[str]:
        return [self.bones.item(i).text() for i in range(self.bones.count())
                if self.bones.item(i).checkState() == QtCore.Qt.CheckState.Checked]

    # ------------------------------------------------------------------ export
    def export(self):
        """Write the selected export; returns what was written (a path or a list), None on failure
        (the reason is in the dialog)."""
        kind, fmt, suffix, folder, _ = self.choice
        text = self.path.text().strip()
        try:
            if not text:
                raise ValueError("Save to: choose a file or folder")
            p = Path(text).expanduser()
            if p == self._default_path():
                p.parent.mkdir(parents=True, exist_ok=True)
            if kind == "poses":
                from core.study.exports import export_poses

                bones = self.chosen_bones()
                if not bones:
                    raise ValueError("Bones: tick at least one bone")
                options = {"rate": self.rate.value()} if fmt in RATE_FORMATS else {}
                if self.smoothed.isChecked():
                    from core.tracking.smoothing_trial import smoothed_poses

                    s = self.window.session
                    QtGui.QGuiApplication.setOverrideCursor(QtCore.Qt.CursorShape.WaitCursor)
                    try:
                        options["poses"] = smoothed_poses(s.study, s.trial_name, bones)
                    finally:
                        QtGui.QGuiApplication.restoreOverrideCursor()
                out = export_poses(self.trial, p, fmt, bones=bones, **options)
            else:
                if not folder and p.suffix.lower() != suffix:
                    raise ValueError(f"Save to: expected a {suffix} file for this export, got {p.name}")
                out = self.window.review.export(p, kind)
        except Exception as exc:  # shown in the dialog with its reason
            self.status.setStyleSheet("color: #b00020")
            self.status.setText(f"Not exported: {exc}")
            return None
        shown = ", ".join(map(str, out)) if isinstance(out, list) else str(out)
        self.status.setStyleSheet("")
        self.status.setText(f"Exported {shown}")
        self.window.notify(f"Exported {shown}")
        return out
