"""The collection day's File-menu actions: Calibrate… (the wizard) and New study from folder…."""

from __future__ import annotations

import json
from pathlib import Path

from PySide6 import QtWidgets

__all__ = ["add_file_actions", "default_session"]


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


def default_session(study_folder) -> Path | None:
    """The calibration session the wizard starts with for the open study: the one its newest saved
    calibration was made from, else the study's own ``calibration_session`` folder (the demo's),
    when it still holds a ``session.json``; None otherwise (the field was always empty, though the
    demo study holds its session)."""
    if study_folder is None:
        return None
    folder = Path(study_folder)
    try:
        doc = json.loads((folder / "study.json").read_text(encoding="utf-8"))
        saved = doc.get("settings", {}).get("calibration_files", {}).values()
        newest = max(saved, key=lambda e: e.get("created") or "", default={})
    except (OSError, ValueError, AttributeError):
        newest = {}
    for candidate in (newest.get("session"), folder / "calibration_session"):
        if candidate and (Path(candidate) / "session.json").is_file():
            return Path(candidate)
    return None


def _trials_calibrations(folder) -> dict[str, str]:
    """Each trial's calibration in the study at ``folder`` (empty without a study)."""
    try:
        doc = json.loads((Path(folder) / "study.json").read_text(encoding="utf-8"))
        return {t: e["calibration"] for t, e in doc["trials"].items()}
    except (TypeError, OSError, ValueError, KeyError):
        return {}


def _moved_notes(folder, saved, in_use: dict[str, str]) -> list[str]:
    """:func:`core.study.calibrations.lab_frame_note` of each trial of the study at ``folder`` the
    save moved (as ``talus calibrate`` warns): its recorded poses are in its earlier calibration's
    lab frame."""
    from core.study import Study
    from core.study.calibrations import lab_frame_note

    moved = [t for t in saved.trials if in_use.get(t) not in (None, saved.name)]
    if not moved:
        return []
    with Study.open(folder) as study:
        return [n for t in moved if (n := lab_frame_note(study, t, in_use[t], saved.name))]


def calibrate(window):
    """Open the calibration wizard, saving into the open study by default, on the study's session
    (:func:`default_session`) when it has one."""
    from .wizard import CalibrationWizard

    folder = _study_folder(window)
    w = CalibrationWizard(window, study_folder=folder, session_folder=default_session(folder))
    in_use = _trials_calibrations(folder)  # what each trial used before the save

    def saved(s) -> None:
        window.notify(f"Calibration {s.name} saved in {s.folder}; trials using it: "
                      f"{', '.join(s.trials) or 'none'}")
        for note in _moved_notes(folder, s, in_use):
            window.notify(f"Warning: {note}", error=True)

    w.saved_calibration.connect(saved)
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
