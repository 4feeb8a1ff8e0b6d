"""File → New study from folder…: a study from a lab's collection folder, without Python.

The folder is read by :func:`core.study.import_folder.scan_folder` in the worker pool: the two
views, the cameras, the CT (or CT + label map, or per-bone CTs) and the frames' bit depth
(cine header, TIFF tags, or the frames' maximum). The dialog shows what was found, asks only
what the files do not say (the bit depth when it was guessed: confirm it; the bones' names),
shows each view's first frame with its unusable pixels in red at the chosen bit depth and says
why when most of a view is unusable, and lists every problem (nothing is written then). Create
writes the study with :func:`~core.study.import_folder.make_study_from_folder`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PySide6 import QtCore, QtWidgets

from .calibration.views import ImageView
from .workers import WorkerPool

__all__ = ["CT_ORIENTATION", "ImportFolderDialog", "usable_overlay"]

CT_ORIENTATION = ("CT orientation: Talus works in LPS (DICOM's patient axes: x to the patient's left, "
                  "y to the back, z to the head). NIfTI headers store RAS; they are converted when read, "
                  "so a volume's header decides where its axes point and nothing needs flipping.")
BITS = (8, 10, 12, 14, 16)


def usable_overlay(frame: np.ndarray, bits: int, usable=(0.02, 0.999)) -> tuple[np.ndarray, float]:
    """The frame in grey with its unusable pixels (outside ``usable`` once divided by
    ``2**bits - 1``) in red, and the usable fraction."""
    x = np.asarray(frame, np.float64) / (2 ** int(bits) - 1)
    ok = (x > usable[0]) & (x < usable[1])
    g = (255 * np.clip(x / max(float(np.percentile(x, 99.5)), 1e-9), 0, 1)).astype(np.uint8)
    rgb = np.stack([g, g, g], axis=-1)
    rgb[~ok] = (0.5 * rgb[~ok] + [127, 0, 0]).astype(np.uint8)
    return rgb, float(ok.mean())


def _scan(folder: str):
    from core.study.import_folder import scan_folder

    return scan_folder(folder)


def _make(scan, out: str, bits: int, bones: dict, trial: str):
    from core.study.import_folder import make_study_from_folder

    return make_study_from_folder(scan, out, bit_depth=bits, bones=bones, trial=trial)


class ImportFolderDialog(QtWidgets.QDialog):
    """The dialog (module docs); ``study_created(path)`` once the study is written."""

    study_created = QtCore.Signal(str)
    step_done = QtCore.Signal(str)  # "scan" or "create" answered (or failed)

    def __init__(self, parent=None, *, folder=None, pool: WorkerPool | None = None) -> None:
        super().__init__(parent)
        self.setWindowTitle("New study from folder")
        self.resize(980, 760)
        self.pool = pool if pool is not None else WorkerPool(self)
        self._own_pool = pool is None
        self.pool.finished.connect(self._finished)
        self.pool.failed.connect(self._failed)
        self.scan = None
        lay = QtWidgets.QVBoxLayout(self)
        row = QtWidgets.QHBoxLayout()
        self.folder_edit = QtWidgets.QLineEdit("" if folder is None else str(folder))
        self.folder_edit.setPlaceholderText("the collection folder: two frame folders or cines, cameras, CT")
        browse = QtWidgets.QPushButton("Browse…")
        browse.clicked.connect(self._browse)
        self.read_button = QtWidgets.QPushButton("Read folder")
        self.read_button.clicked.connect(self.read_folder)
        for w in (QtWidgets.QLabel("Folder"), self.folder_edit, browse, self.read_button):
            row.addWidget(w, 1 if w is self.folder_edit else 0)
        lay.addLayout(row)
        self.found = QtWidgets.QPlainTextEdit()
        self.found.setReadOnly(True)
        self.found.setMaximumHeight(96)
        self.found.text = self.found.toPlainText  # read like a label
        self.found.setText = self.found.setPlainText
        lay.addWidget(self.found)
        form = QtWidgets.QFormLayout()
        brow = QtWidgets.QHBoxLayout()
        self.bits_combo = QtWidgets.QComboBox()
        self.bits_combo.addItems([str(b) for b in BITS])
        self.bits_combo.currentIndexChanged.connect(lambda _: self._draw_views())
        self.bits_combo.currentIndexChanged.connect(lambda _: self._update())
        self.bits_confirm = QtWidgets.QCheckBox("confirmed")
        self.bits_confirm.toggled.connect(lambda _: self._update())
        self.bits_info = QtWidgets.QLabel()
        self.bits_info.setWordWrap(True)
        brow.addWidget(self.bits_combo)
        brow.addWidget(self.bits_confirm)
        brow.addWidget(self.bits_info, 1)
        form.addRow("Bit depth of the frames", brow)
        self.bones_table = QtWidgets.QTableWidget(0, 2)
        self.bones_table.setHorizontalHeaderLabels(["bone name", "from"])
        self.bones_table.horizontalHeader().setStretchLastSection(True)
        self.bones_table.setMaximumHeight(120)
        form.addRow("Bones", self.bones_table)
        self.trial_edit = QtWidgets.QLineEdit("trial1")
        form.addRow("Trial name", self.trial_edit)
        self.out_edit = QtWidgets.QLineEdit()
        form.addRow("New study folder", self.out_edit)
        lay.addLayout(form)
        orient = QtWidgets.QLabel(CT_ORIENTATION)
        orient.setWordWrap(True)
        orient.setStyleSheet("color: #404040")
        lay.addWidget(orient)
        views = QtWidgets.QHBoxLayout()
        self.views = [ImageView(), ImageView()]
        for v in self.views:
            views.addWidget(v)
        lay.addLayout(views, 1)
        self.messages = QtWidgets.QLabel()
        self.messages.setWordWrap(True)
        lay.addWidget(self.messages)
        buttons = QtWidgets.QHBoxLayout()
        buttons.addStretch(1)
        self.create_button = QtWidgets.QPushButton("Create study")
        self.create_button.clicked.connect(self.create)
        close = QtWidgets.QPushButton("Close")
        close.clicked.connect(self.close)
        buttons.addWidget(self.create_button)
        buttons.addWidget(close)
        lay.addLayout(buttons)
        self._update()

    def _browse(self) -> None:
        d = QtWidgets.QFileDialog.getExistingDirectory(self, "Collection folder", self.folder_edit.text())
        if d:
            self.folder_edit.setText(d)
            self.read_folder()

    # ------------------------------------------------------------------ reading
    def read_folder(self) -> None:
        folder = self.folder_edit.text().strip()
        self.scan = None
        self.messages.setStyleSheet("")
        self.messages.setText(f"Reading {folder}…")
        self.read_button.setEnabled(False)
        self._update()
        self.pool.submit("scan", _scan, folder)

    def _finished(self, key: str, result) -> None:
        if key == "scan":
            self.read_button.setEnabled(True)
            self.scan = result
            self._show_scan()
        elif key == "create":
            self.messages.setStyleSheet("")
            self.messages.setText(f"Created the study {result}.")
            self.study_created.emit(str(result))
        self._update()
        self.step_done.emit(key)

    def _failed(self, key: str, text: str) -> None:
        self.read_button.setEnabled(True)
        last = text.strip().splitlines()[-1] if text.strip() else text
        self.messages.setStyleSheet("color: #c00000")
        self.messages.setText(f"{'Reading the folder' if key == 'scan' else 'Creating the study'} failed: "
                              f"{last.split(': ', 1)[-1]}")
        self._update()
        self.step_done.emit(key)

    def _show_scan(self) -> None:
        s = self.scan

        def rel(p) -> str:  # paths inside the folder, as the problems name them
            try:
                return str(Path(p).relative_to(s.folder))
            except ValueError:
                return str(p)

        lines = [f"In {s.folder}:"]
        for v in s.views:
            lines.append(f"View {rel(v.path)}: {v.n_frames} frames of {v.shape[1]}x{v.shape[0]} pixels; "
                         f"{v.bit_depth.text}")
        if s.cameras:
            lines.append(f"Cameras ({s.camera_format}): " + ", ".join(rel(c) for c in s.cameras))
        if s.ct is not None:
            lab = f", label map {rel(s.labels)} (labels {s.label_values})" if s.labels else ""
            lines.append(f"CT: {rel(s.ct)}{lab}")
        for b, p in s.bone_volumes.items():
            lines.append(f"CT of {b}: {rel(p)}")
        self.found.setText("\n".join(lines) if len(lines) > 1 else f"Nothing found in {s.folder}.")
        bits = s.bit_depth
        if bits is not None:
            self.bits_combo.blockSignals(True)
            self.bits_combo.setCurrentText(str(bits))
            self.bits_combo.blockSignals(False)
        certain = all(v.bit_depth.certain for v in s.views)
        self.bits_confirm.setChecked(certain)
        self.bits_info.setText("read from the files" if certain else
                               "guessed from the frames' largest value: check it and confirm")
        bones = s.bones()
        self.bones_table.setRowCount(len(bones))
        for i, (name, label) in enumerate(bones.items()):
            self.bones_table.setItem(i, 0, QtWidgets.QTableWidgetItem(name))
            src = QtWidgets.QTableWidgetItem(f"label {label}" if label is not None else
                                             rel(s.bone_volumes.get(name, s.ct)))
            src.setFlags(src.flags() & ~QtCore.Qt.ItemFlag.ItemIsEditable)
            self.bones_table.setItem(i, 1, src)
        if not self.out_edit.text().strip():
            self.out_edit.setText(str(Path(s.folder) / "study"))
        self._draw_views()

    @property
    def bits(self) -> int:
        return int(self.bits_combo.currentText())

    def _draw_views(self) -> None:
        s = self.scan
        if s is None:
            return
        warn = []
        for view, v in zip(self.views, s.views, strict=False):
            rgb, frac = usable_overlay(v.first_frame, self.bits)
            view.set_rgb(rgb)
            view.caption = f"{v.path.name}: {100 * frac:.0f} % usable at {self.bits} bits (red: unusable)"
            view.update()
            if frac < 0.5:
                from core.study.import_folder import _unusable

                warn.append(_unusable(s.folder, v, self.bits))
        problems = list(s.problems)
        text = ""
        if problems:
            text += "Cannot make a study (nothing will be written):\n" + "\n".join(f"• {p}" for p in problems)
        if warn:
            text += ("\n" if text else "") + "Before tracking:\n" + "\n".join(f"• {w}" for w in warn)
        self.messages.setStyleSheet("color: #c00000" if text else "")
        self.messages.setText(text or "Ready: check the bit depth and the bones' names, then Create study.")

    def _update(self) -> None:
        s = self.scan
        ok = s is not None and not s.problems and self.bits_confirm.isChecked()
        self.create_button.setEnabled(ok)

    # ------------------------------------------------------------------ writing
    def bone_names(self) -> dict:
        default = self.scan.bones()
        names = [self.bones_table.item(i, 0).text().strip() for i in range(self.bones_table.rowCount())]
        return dict(zip(names, default.values(), strict=True))

    def create(self) -> None:
        if self.scan is None or self.scan.problems:
            return
        self.create_button.setEnabled(False)
        self.messages.setText("Creating the study…")
        self.pool.submit("create", _make, self.scan, self.out_edit.text().strip(), self.bits,
                         self.bone_names(), self.trial_edit.text().strip() or "trial1")

    def closeEvent(self, ev) -> None:
        if self._own_pool:
            self.pool.shutdown(wait=False)
        super().closeEvent(ev)
