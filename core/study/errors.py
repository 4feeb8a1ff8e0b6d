"""Errors of the study store."""

from __future__ import annotations

from ..errors import FileError
from ..io.atomic import LockedError

__all__ = ["FileError", "LockedError", "StudyError"]


class StudyError(FileError):
    """A study folder, manifest or result file is invalid, missing or of an unknown version.

    The message names the file (and, inside a manifest, the JSON path such as
    ``trials['walk01'].views[1].path``) and what was expected. A :class:`~core.errors.FileError`
    (so a ``ValueError``): code that catches reader errors catches these too.
    """
