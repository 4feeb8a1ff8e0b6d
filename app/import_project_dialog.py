"""*File → Import project…*: an Autoscoper trial (``.cfg``) or an XMALab project (``.xma``) as
a new study, opened in the window.

The dialog asks for the project file, the new study folder (default ``<project>_study`` beside
it) and the options of the project's kind: an Autoscoper ``.tra`` of poses to start from, or a
folder to look for an XMALab project's images in when the project was moved. *Import* runs
:func:`core.study.import_project.import_project` in the window's worker pool; when it is done
the dialog closes and the window opens the study (or, when it already shows one, says where the
new study is). A failure is said in the dialog, in red, with its reason; nothing is left in the
study folder.
"""

from __future__ import annotations

import os
from pathlib import Path

from PySide6 import QtCore, QtWidgets

__all__ = ["ImportProjectDialog"]

FILTER = "Autoscoper or XMALab project (*.cfg *.xma);;Autoscoper trial (*.cfg);;XMALab project (*.xma)"
JOB = "import-project"


def _run_import(project: str, out: str, options: dict) -> str:
    from core.study.import_project import import_project

    if (Path(out) / "study.json").exists():
        raise ValueError(f"{out} already holds a study: choose a new folder")
    with import_project(project, out, **options):
        pass
    return out


class ImportProjectDialog(QtWidgets.QDialog):
    """Import a peer's project as a study (see the module docs)."""

    imported = QtCore.Signal(str)  # the new study's folder

    def __init__(self, window) -> None:
        super().__init__(window)
        self.window = window
        self.setWindowTitle("Import project")
        self.setObjectName("import-project-dialog")
        self.project = QtWidgets.QLineEdit()
        self.project.setObjectName("import-project-file")
        self.project.setPlaceholderText("an Autoscoper .cfg or an XMALab .xma")
        self.study = QtWidgets.QLineEdit()
        self.study.setObjectName("import-project-study")
        self.tra = QtWidgets.QLineEdit()
        self.tra.setPlaceholderText("optional: poses to start from (.tra)")
        self.search = QtWidgets.QLineEdit()
        self.search.setPlaceholderText("optional: where the images are now, if the project moved")
        self.status = QtWidgets.QLabel()
        self.status.setObjectName("import-project-status")
        self.status.setWordWrap(True)
        self.status.setTextInteractionFlags(QtCore.Qt.TextInteractionFlag.TextSelectableByMouse)
        form = QtWidgets.QFormLayout()
        self.project_browse = self._row(form, "Project", self.project, self._browse_project)
        self.study_browse = self._row(form, "New study folder", self.study, self._browse_study)
        self.tra_browse = self._row(form, "Autoscoper poses", self.tra, self._browse_tra)
        self.search_browse = self._row(form, "Images folder", self.search, self._browse_search)
        self.form = form
        self.buttons = QtWidgets.QDialogButtonBox()
        accept = QtWidgets.QDialogButtonBox.ButtonRole.AcceptRole
        self.import_button = self.buttons.addButton("Import", accept)
        self.buttons.addButton(QtWidgets.QDialogButtonBox.StandardButton.Cancel).clicked.connect(self.reject)
        self.import_button.clicked.connect(self.start)
        lay = QtWidgets.QVBoxLayout(self)
        lay.addLayout(form)
        lay.addWidget(self.status)
        lay.addWidget(self.buttons)
        self.project.textChanged.connect(self._project_changed)
        window.pool.finished.connect(self._finished)
        window.pool.failed.connect(self._failed)
        self._project_changed("")
        self.resize(620, 240)

    def _row(self, form, label, edit, slot) -> QtWidgets.QPushButton:
        button = QtWidgets.QPushButton("Browse…")
        button.clicked.connect(slot)
        row = QtWidgets.QHBoxLayout()
        row.addWidget(edit, 1)
        row.addWidget(button)
        form.addRow(label, row)
        return button

    @property
    def kind(self) -> str | None:
        s = Path(self.project.text().strip()).suffix.lower()
        return s[1:] if s in (".cfg", ".xma") else None

    def _project_changed(self, text: str) -> None:
        kind = self.kind
        for edit, button, want in ((self.tra, self.tra_browse, "cfg"),
                                   (self.search, self.search_browse, "xma")):
            self.form.setRowVisible(self._row_index(edit), kind == want)
            edit.setEnabled(kind == want)
            button.setEnabled(kind == want)
        p = text.strip()
        if p and kind and not self.study.isModified():
            self.study.setText(str(Path(p).with_suffix("")) + "_study")
        self.import_button.setEnabled(kind is not None)
        self.status.clear()

    def _row_index(self, edit) -> int:
        for r in range(self.form.rowCount()):
            item = self.form.itemAt(r, QtWidgets.QFormLayout.ItemRole.FieldRole)
            lay = item.layout() if item is not None else None
            if lay is not None and lay.indexOf(edit) >= 0:
                return r
        return -1

    # ------------------------------------------------------------------ browse
    def _start_dir(self) -> str:
        p = self.project.text().strip()
        return str(Path(p).parent) if p else os.getcwd()

    def _browse_project(self) -> None:
        path, _ = QtWidgets.QFileDialog.getOpenFileName(self, "Project to import", self._start_dir(), FILTER)
        if path:
            self.project.setText(path)

    def _browse_study(self) -> None:
        path, _ = QtWidgets.QFileDialog.getSaveFileName(self, "New study folder", self.study.text(),
                                                        "Study folder (*)")
        if path:
            self.study.setText(path)
            self.study.setModified(True)

    def _browse_tra(self) -> None:
        path, _ = QtWidgets.QFileDialog.getOpenFileName(self, "Autoscoper poses", self._start_dir(),
                                                        "Autoscoper poses (*.tra)")
        if path:
            self.tra.setText(path)

    def _browse_search(self) -> None:
        path = QtWidgets.QFileDialog.getExistingDirectory(self, "Folder of the images", self._start_dir())
        if path:
            self.search.setText(path)

    # ------------------------------------------------------------------ import
    def options(self) -> dict:
        if self.kind == "cfg":
            return {"tra": self.tra.text().strip() or None}
        search = self.search.text().strip()
        return {"search": [search] if search else []}

    def start(self) -> None:
        """Check the fields and start the import in the worker pool."""
        project, out = self.project.text().strip(), self.study.text().strip()
        if self.kind is None:
            return self._say(f"Project: expected an Autoscoper .cfg or an XMALab .xma, got {project!r}")
        if not Path(project).is_file():
            return self._say(f"Project: no file {project}")
        if not out:
            return self._say("New study folder: choose where to write the study")
        self.import_button.setEnabled(False)
        self.status.setStyleSheet("")
        self.status.setText(f"Importing {Path(project).name} into {out} …")
        self.window.pool.submit(JOB, _run_import, project, out, self.options())

    def _say(self, text: str) -> None:
        self.status.setStyleSheet("color: #b00020")
        self.status.setText(text)

    def _finished(self, key: str, result) -> None:
        if key != JOB:
            return
        self.imported.emit(result)
        self.accept()
        w = self.window
        if w.model is None:
            w._open_checked(result)
        else:
            w.notify(f"Imported the project as the study {result}: open it in a new window "
                     "(File → Open study…)")

    def _failed(self, key: str, text: str) -> None:
        if key != JOB:
            return
        self.import_button.setEnabled(True)
        lines = [ln for ln in text.strip().splitlines() if ln.strip()]
        self._say(f"Not imported: {lines[-1] if lines else text}")

    def done(self, r: int) -> None:  # accept, reject, Escape: stop listening to the pool
        self._disconnect()
        super().done(r)

    def _disconnect(self) -> None:
        pool = self.window.pool
        for sig, slot in ((pool.finished, self._finished), (pool.failed, self._failed)):
            try:
                sig.disconnect(slot)
            except (RuntimeError, TypeError):
                pass
