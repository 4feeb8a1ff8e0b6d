"""File-system helpers shared by every writer of ``core`` (no imports from ``core``).

:mod:`core.io.atomic` builds the crash-safe writers on them; the MayaCam writer of
:mod:`core.geometry` (a layer below ``core.io``) uses them directly.
"""

from __future__ import annotations

import os
import sys
import threading

__all__ = ["fsync_dir", "new_file_mode"]

_umask_lock = threading.Lock()


def _umask() -> int:
    """The process umask, read without changing it where the system allows (Linux)."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    with _umask_lock:  # elsewhere: set and restore (not atomic against other threads' umask calls)
        mask = os.umask(0o022)
        os.umask(mask)
    return mask


def new_file_mode(dest: str | os.PathLike) -> int:
    """Permission bits a plain ``open(dest, "w")`` would leave: the existing file's, else
    ``0o666`` less the umask (``tempfile.mkstemp`` alone gives ``0o600``, which would make a
    lab's shared study folder unreadable to colleagues)."""
    try:
        return os.stat(dest).st_mode & 0o7777
    except OSError:
        return 0o666 & ~_umask()


def fsync_dir(folder: str | os.PathLike) -> None:
    """Flush a folder's entries (new names, renames) to disk; a no-op where unsupported."""
    if sys.platform.startswith("win"):  # directories cannot be opened for fsync on Windows
        return
    fd = os.open(os.fspath(folder), os.O_RDONLY)
    try:
        os.fsync(fd)
    except OSError:  # some file systems (e.g. certain network mounts) refuse; nothing to do
        pass
    finally:
        os.close(fd)
