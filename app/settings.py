"""Persistent, versioned user settings (Qt ``QSettings``: per user, per platform).

Stored under organisation/application "Talus"; ``TALUS_SETTINGS_DIR`` puts them in an INI file
in that folder instead (tests, portable installs). A ``version`` key allows migrations: values
written by a newer Talus are ignored, not misread.
"""

from __future__ import annotations

import os

from PySide6 import QtCore

__all__ = ["VERSION", "add_recent", "get", "recent", "set_value"]

VERSION = 1
MAX_RECENT = 10


def _store() -> QtCore.QSettings:
    folder = os.environ.get("TALUS_SETTINGS_DIR")
    if folder:
        s = QtCore.QSettings(os.path.join(folder, "talus.ini"), QtCore.QSettings.Format.IniFormat)
    else:
        s = QtCore.QSettings("Talus", "Talus")
    version = int(s.value("version", VERSION))
    if version > VERSION:  # written by a newer Talus: use defaults, keep the file as it is
        return QtCore.QSettings(QtCore.QSettings.Format.IniFormat,
                                QtCore.QSettings.Scope.UserScope, "Talus", "talus-fallback")
    s.setValue("version", VERSION)
    return s


def get(key: str, default=None):
    return _store().value(key, default)


def set_value(key: str, value) -> None:
    s = _store()
    s.setValue(key, value)
    s.sync()


def recent() -> list[str]:
    value = _store().value("recent_studies", [])
    if isinstance(value, str):
        value = [value]
    return [str(v) for v in (value or [])]


def add_recent(path: str) -> None:
    items = [path, *[p for p in recent() if p != path]][:MAX_RECENT]
    set_value("recent_studies", items)
