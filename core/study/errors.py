"""Errors of the study store."""

from __future__ import annotations

from ..io.atomic import LockedError

__all__ = ["LockedError", "StudyError"]


class StudyError(ValueError):
    """A study folder, manifest or result file is invalid, missing or of an unknown version.

    The message names the file (and, inside a manifest, the JSON path such as
    ``trials['walk01'].views[1].path``) and what was expected.
    """
