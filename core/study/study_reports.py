"""A study's JSON reports (calibration reports and other summaries) under
``results/reports/<kind>/<name>.json``, and the check that a destination lies inside the study
(:class:`~core.study.Study`)."""

from __future__ import annotations

import os
import re
from pathlib import Path

from ..io.atomic import FileLock, atomic_write_json
from .errors import StudyError
from .study_edit import _check_name

REPORT_LOCK_S = 30.0  # how long a report's write waits for another writer of it (as a manifest update)


class StudyReports:
    """The report methods of :class:`~core.study.Study`."""

    def _report_path(self, kind: str, name: str) -> Path:
        _check_name(kind, "kind")
        _check_name(name, "name")
        p = self._folder / "results" / "reports" / kind / f"{name}.json"
        return self.inside(p)

    def inside(self, path: str | os.PathLike) -> Path:
        """``path`` if it (following any symbolic links) lies inside the study folder, else
        :class:`StudyError`; writers of study files check their destination with it."""
        p = Path(path)
        p = p if p.is_absolute() else self._folder / p
        root = self._folder.resolve()
        if not p.resolve().is_relative_to(root):
            raise StudyError(
                f"{p}: leads to {p.resolve()}, outside the study folder {root} (a symbolic link?); "
                "expected a path inside the study", path=p, expected="a path inside the study",
            )
        return p

    def write_report(self, kind: str, name: str, data: dict) -> Path:
        """Save a JSON report (e.g. ``kind="calibration"``) atomically; NaN must be given as None."""
        self._require_write()
        if not isinstance(data, dict):
            raise ValueError(f"data: expected a dict, got {type(data).__name__}")
        p = self._report_path(kind, name)
        p.parent.mkdir(parents=True, exist_ok=True)
        lock = FileLock(p.with_name(f".{name}.lock"), purpose=f"report {p}")
        with lock.acquire(timeout=REPORT_LOCK_S):
            atomic_write_json(p, data)
        return p

    def read_report(self, kind: str, name: str) -> dict:
        """A report written by :meth:`write_report`."""
        import json

        p = self._report_path(kind, name)
        if not p.is_file():
            raise StudyError(f"{p}: no {kind!r} report named {name!r}")
        try:
            return json.loads(p.read_text(encoding="utf-8"))
        except (ValueError, UnicodeDecodeError) as exc:
            raise StudyError(f"{p}: expected a JSON report ({exc})") from None

    def report_names(self, kind: str) -> tuple[str, ...]:
        folder = self._folder / "results" / "reports" / _check_name(kind, "kind")
        return tuple(sorted(p.stem for p in folder.glob("*.json") if not re.match(r"^\.", p.name)))
