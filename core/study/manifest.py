"""Reading and writing the study manifest (``study.json``): parse, migrate, validate, save atomically."""

from __future__ import annotations

import datetime as _dt
import json
import os
from pathlib import Path, PurePosixPath

from ..errors import reading
from ..io.atomic import atomic_write_json
from .errors import StudyError
from .migrations import migrate
from .schema import FORMAT, MANIFEST_NAME, SCHEMA_VERSION, validate_manifest

__all__ = ["new_manifest", "read_manifest", "resolve_path", "store_path", "write_manifest"]


def _now() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")


def new_manifest(name: str) -> dict:
    """An empty manifest of the current schema version."""
    now = _now()
    return {
        "format": FORMAT,
        "schema_version": SCHEMA_VERSION,
        "name": name,
        "created": now,
        "modified": now,
        "calibrations": {},
        "volumes": {},
        "bones": {},
        "trials": {},
        "settings": {},
    }


def read_manifest(folder: str | os.PathLike) -> tuple[dict, int]:
    """Parse, migrate and validate ``<folder>/study.json``.

    Returns
    -------
    doc : dict
        Manifest of the current schema version.
    from_version : int
        The schema version found in the file (older ones were migrated in memory).

    Raises
    ------
    StudyError
        Missing or unparsable file, unknown/future version, or an invalid manifest; the message
        names the file and what was expected.
    """
    path = Path(folder) / MANIFEST_NAME
    if not Path(folder).is_dir():
        raise StudyError(f"{folder}: no such study folder", path=folder, expected="a Talus study folder")
    if not path.is_file():
        raise StudyError(f"{folder}: not a Talus study folder (expected a manifest file {path})", path=folder)
    with reading(path, "a Talus study manifest (UTF-8 JSON)", error=StudyError):
        return _read_manifest(path)


def _read_manifest(path: Path) -> tuple[dict, int]:
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise StudyError(f"{path}: expected UTF-8 JSON text, got undecodable bytes ({exc.reason})") from None
    try:
        doc = json.loads(text, parse_constant=_reject_constant)
    except json.JSONDecodeError as exc:
        raise StudyError(
            f"{path}: line {exc.lineno} column {exc.colno}: invalid JSON ({exc.msg}); the manifest is "
            "corrupt (Talus writes it atomically, so it was edited or damaged outside Talus)"
        ) from None
    except ValueError as exc:
        raise StudyError(f"{path}: {exc}") from None
    doc, version = migrate(doc, source=str(path))
    validate_manifest(doc, source=str(path))
    return doc, version


def _reject_constant(name: str):
    raise ValueError(f"expected strict JSON numbers, got {name}")


def write_manifest(folder: str | os.PathLike, doc: dict, *, touch: bool = True) -> None:
    """Validate ``doc`` and write it atomically to ``<folder>/study.json``.

    Nothing is written when validation fails.
    """
    if touch:
        doc["modified"] = _now()
    path = Path(folder) / MANIFEST_NAME
    validate_manifest(doc, source=str(path))
    atomic_write_json(path, doc)


def store_path(folder: str | os.PathLike, path: str | os.PathLike) -> str:
    """How a referenced file is recorded: POSIX-relative inside the study folder, else absolute."""
    p = Path(path).expanduser().absolute()
    base = Path(folder).absolute()
    try:
        return PurePosixPath(p.relative_to(base)).as_posix()
    except ValueError:
        return str(p)


def resolve_path(folder: str | os.PathLike, stored: str) -> Path:
    """The absolute path of a recorded reference."""
    p = Path(stored)
    return p if p.is_absolute() else Path(folder) / PurePosixPath(stored)
