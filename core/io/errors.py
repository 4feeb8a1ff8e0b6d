"""Reader errors of :mod:`core.io` (defined in :mod:`core.errors`, re-exported here)."""

from ..errors import FileError, reading, reads

__all__ = ["FileError", "reading", "reads"]
