"""The study store: a folder with a versioned manifest that references raw data, plus results.

See :mod:`core.study.study` for the folder layout and :mod:`core.study.schema` for the manifest.
"""

from .errors import LockedError, StudyError
from .repair import repair_study
from .results import JournalState, PoseRecord, read_journal, salvage_journal
from .schema import SCHEMA_VERSION, validate_manifest
from .study import Study
from .trial import Trial

__all__ = [
    "SCHEMA_VERSION",
    "JournalState",
    "LockedError",
    "PoseRecord",
    "Study",
    "StudyError",
    "Trial",
    "read_journal",
    "repair_study",
    "salvage_journal",
    "validate_manifest",
]
