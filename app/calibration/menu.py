"""The collection day's File-menu actions: Calibrate… (the wizard) and New study from folder…."""

from __future__ import annotations

from PySide6 import QtWidgets

__all__ = ["add_file_actions"]


def _study_folder(window):
    session = getattr(window, "session", None)
    return None if session is None else getattr(session, "folder", None)


def add_file_actions(window, menu: QtWidgets.QMenu) -> None:
    """Add the actions to ``menu`` (the window's File menu); they are kept as
    ``window.new_from_folder_action``, ``window.calibrate_action`` and
    ``window.inspect_calibration_action``."""
    window.new_from_folder_action = menu.addAction("New study from &folder…")
    window.new_from_folder_action.triggered.connect(lambda: window._guard(lambda: new_from_folder(window)))
    window.calibrate_action = menu.addAction("&Calibrate…")
    window.calibrate_action.triggered.connect(lambda: window._guard(lambda: calibrate(window)))
    window.inspect_calibration_action = menu.addAction("Saved calibrations…")
    window.inspect_calibration_action.triggered.connect(lambda: window._guard(lambda: inspect(window)))


def new_from_folder(window):
    """Open the New-study-from-folder dialog; the new study opens in the window when none is shown."""
    from ..import_dialog import ImportFolderDialog

    dlg = ImportFolderDialog(window)

    def created(path: str) -> None:
        if getattr(window, "model", None) is None:
            window._guard(lambda: window.open_study(path))
            dlg.close()
        else:
            window.notify(f"Created the study {path}; open it with File → Open study…")

    dlg.study_created.connect(created)
    dlg.show()
    return dlg


def calibrate(window):
    """Open the calibration wizard, saving into the open study by default."""
    from .wizard import CalibrationWizard

    w = CalibrationWizard(window, study_folder=_study_folder(window))
    w.saved_calibration.connect(lambda s: window.notify(
        f"Calibration {s.name} saved in {s.folder}; trials using it: {', '.join(s.trials) or 'none'}"))
    w.show()
    return w


def inspect(window, name: str | None = None):
    """Reopen the wizard on a calibration version saved in the open study (chosen from a list)."""
    import json

    from .wizard import CalibrationWizard

    folder = _study_folder(window)
    if folder is None:
        raise ValueError("calibration: open a study first (its saved calibrations are listed)")
    doc = json.loads((folder / "study.json").read_text(encoding="utf-8"))
    names = sorted(doc.get("settings", {}).get("calibration_files", {}))
    if not names:
        raise ValueError(f"calibration: {folder} has no calibration saved from a session (File → Calibrate…)")
    if name is None:
        name, ok = QtWidgets.QInputDialog.getItem(window, "Saved calibrations", "Calibration version", names,
                                                  len(names) - 1, False)
        if not ok:
            return None
    w = CalibrationWizard.inspect_saved(folder, name, window)
    w.show()
    return w
