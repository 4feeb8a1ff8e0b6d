"""File → New study / Import: dialogs that build a :class:`core.study.Study` step by step.

A new study starts empty; the user imports a calibration (one MayaCam file per camera), CT
volumes (DICOM folder, NIfTI, NRRD, MHA, or a TIFF stack with its voxel size; each becomes a
bone), and a trial (one fluoroscope sequence per camera: cine, TIFF folder or stack, AVI). Once
a trial exists the window shows it. Every step validates the files (a bad one is named in the
error) and saves the manifest atomically.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from PySide6 import QtWidgets

if TYPE_CHECKING:
    from core.study import Study

__all__ = ["ImportActions"]

_CT_FILTER = "CT volumes (*.nii *.nii.gz *.nrrd *.nhdr *.mha *.mhd *.tif *.tiff);;All files (*)"
_SEQ_FILTER = "Fluoroscope sequences (*.cine *.tif *.tiff *.avi *.mp4);;All files (*)"


class ImportActions:
    """The dialogs; ``window`` provides ``notify``, ``open_study`` and the study in progress."""

    def __init__(self, window) -> None:
        self.window = window
        self.study: Study | None = None  # an open study without a trial yet

    # -- helpers (dialogs are module attributes so tests can replace them)
    def _ask_text(self, title: str, label: str, default: str = "") -> str | None:
        text, ok = QtWidgets.QInputDialog.getText(self.window, title, label, text=default)
        return text.strip() if ok and text.strip() else None

    def _target(self) -> Study:
        if self.study is not None:
            return self.study
        session = self.window.session
        if session is not None and session.writable:
            return session.study
        raise ValueError("study: create or open a study (writable) first")

    # -- actions
    def new_study(self) -> None:
        folder = QtWidgets.QFileDialog.getExistingDirectory(self.window, "Folder of the new study")
        if folder:
            self.create(folder)

    def create(self, folder: str | Path) -> None:
        if self.study is not None:
            self.study.close()
        from core.study import Study

        self.study = Study.create(folder)
        self.window.notify(f"New study in {folder}: import a calibration, CT volumes and a trial.")

    def import_calibration(self) -> None:
        files, _ = QtWidgets.QFileDialog.getOpenFileNames(
            self.window, "MayaCam files, one per camera", "", "Camera files (*.txt *.csv)")
        name = self._ask_text("Calibration", "Name of this calibration:", "day1") if files else None
        if files and name:
            self.add_calibration(name, files)

    def add_calibration(self, name: str, files) -> None:
        self._target().add_calibration(name, sorted(files))
        self.window.notify(f"Calibration {name!r}: {len(files)} cameras.")

    def import_volume(self) -> None:
        path, _ = QtWidgets.QFileDialog.getOpenFileName(self.window, "CT volume", "", _CT_FILTER)
        if not path:
            return
        name = self._ask_text("Bone", "Bone name:", Path(path).stem.split(".")[0])
        voxel = None
        if name and Path(path).suffix.lower() in (".tif", ".tiff"):
            text = self._ask_text("Voxel size", "Voxel size x, y, z (mm):", "0.5, 0.5, 0.5")
            if text is None:
                return
            voxel = [float(v) for v in text.replace(",", " ").split()]
        if name:
            self.add_volume(name, path, voxel_size_mm=voxel)

    def add_volume(self, name: str, path, *, voxel_size_mm=None) -> None:
        st = self._target()
        st.add_volume(name, path, voxel_size_mm=voxel_size_mm)
        st.add_bone(name, volume=name)
        self.window.notify(f"Bone {name!r} from {path}.")

    def import_trial(self) -> None:
        st = self._target()
        if not st.calibrations:
            raise ValueError("calibration: import a calibration before a trial")
        views = []
        for k in range(2):
            path, _ = QtWidgets.QFileDialog.getOpenFileName(
                self.window, f"Sequence of camera {k + 1}", "", _SEQ_FILTER)
            if not path:
                return
            views.append(path)
        name = self._ask_text("Trial", "Trial name:", "trial1")
        if name:
            self.add_trial(name, views)

    def add_trial(self, name: str, views, *, calibration: str | None = None) -> None:
        st = self._target()
        cal = calibration or st.calibrations[-1]
        st.add_trial(name, views, calibration=cal, bones=list(st.bones))
        self.window.notify(f"Trial {name!r} ({cal}) with bones {', '.join(st.bones)}.")
        if self.study is not None and self.window.model is None:
            folder = self.study.folder
            self.study.close()
            self.study = None
            self.window.open_study(folder)
