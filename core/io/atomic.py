"""Crash-safe file writing and an exclusive lock between processes.

Every file Talus writes for a user goes through :func:`atomic_write` / :func:`atomic_open`: the
content is written to a temporary file *in the destination's folder*, flushed and ``fsync``-ed,
then renamed over the destination with :func:`os.replace` (atomic on POSIX and on Windows for
files on one volume), and finally the folder itself is ``fsync``-ed so the rename survives a
power cut. A crash at any point leaves either the complete old file or the complete new one,
never a mixture; a stray ``.<name>.*.tmp`` file may remain and is ignored by readers
(:func:`remove_stale_temporaries` clears old ones; a study does so when opened for writing).
New files get the permissions a plain ``open()`` would give (``0o666`` less the umask, or the
replaced file's mode), not ``mkstemp``'s owner-only ``0o600``.

Append-only journals (tracking results saved frame by frame) use :func:`append_durable`, which
``fsync``-s each appended record; their readers detect and drop a torn last record (see
:mod:`core.study.results`).

:class:`FileLock` is an advisory, exclusive lock on a lock file (``fcntl.flock`` on POSIX,
``msvcrt.locking`` on Windows). The kernel releases it when the holding process dies, so a
crashed writer never leaves anything locked. The lock file records the holder (pid, host, time,
purpose) so the error raised to a second process can say who holds it. Writers lock what they
write: a study's pose journal for as long as they track that bone (refused at once when held
elsewhere), the study manifest only for one read-modify-write (``acquire(timeout=...)`` waits
for such a short lock).
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import json
import os
import re
import socket
import sys
import tempfile
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import IO, Any

from .._files import fsync_dir, new_file_mode

__all__ = [
    "FileLock",
    "LockedError",
    "append_durable",
    "atomic_open",
    "atomic_path",
    "atomic_write",
    "atomic_write_json",
    "fsync_dir",
    "json_checkpoint",
    "output_file",
    "print_json",
    "remove_stale_temporaries",
]


def _finite(x: Any) -> bool:
    """True for a finite real number (no numpy needed)."""
    import math

    try:
        return math.isfinite(float(x))
    except (TypeError, ValueError):
        return False


def _chmod(fd: int, tmp: str, dest: Path) -> None:
    """Give the temporary file the mode ``dest`` would get from a plain ``open()``."""
    mode = new_file_mode(dest)
    if hasattr(os, "fchmod"):
        os.fchmod(fd, mode)
    else:  # pragma: no cover - Windows
        os.chmod(tmp, mode)


@contextlib.contextmanager
def atomic_open(
    path: str | os.PathLike, mode: str = "w", *, encoding: str = "utf-8", newline: str | None = "\n"
) -> Iterator[IO[Any]]:
    """Open a temporary file that replaces ``path`` atomically when the block exits cleanly.

    Parameters
    ----------
    path : str or os.PathLike
        Destination; its folder must exist. An existing file is replaced only after the new
        content is complete and on disk.
    mode : {"w", "wb"}
        Text or binary.
    encoding, newline
        For text mode (``newline="\\n"`` writes the same bytes on every platform).

    Yields
    ------
    file object
        Write the new content to it. If the block raises, the temporary file is removed and
        ``path`` is left untouched.

    Raises
    ------
    ValueError
        For a ``mode`` other than ``"w"`` or ``"wb"``, or a missing destination folder.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f'mode: expected "w" or "wb", got {mode!r}')
    dest = Path(path)
    folder = dest.parent if str(dest.parent) else Path(".")
    if not folder.is_dir():
        raise ValueError(f"path: folder {folder} of {dest.name} does not exist")
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=f".{dest.name}.", suffix=".tmp")
    try:
        _chmod(fd, tmp, dest)
        if mode == "wb":
            fh = os.fdopen(fd, "wb")
        else:
            fh = os.fdopen(fd, "w", encoding=encoding, newline=newline)
        with fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, dest)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    fsync_dir(folder)


def output_file(path: str | os.PathLike, suffixes: Sequence[str], expected: str, name: str = "path") -> Path:
    """``path`` when its suffix (in any case) is one of ``suffixes`` and its folder exists, else a
    ``ValueError`` naming the argument ``name`` and the ``expected`` files ("a .png file"): what a
    writer checks before it starts."""
    p = Path(path)
    if p.suffix.lower() not in suffixes:
        raise ValueError(f"{name}: expected {expected}, got {str(path)!r}")
    if not p.parent.is_dir():
        raise ValueError(f"{name}: the folder {p.parent} does not exist")
    return p


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """A temporary path (same folder and suffix) for a library that writes files by name.

    On a clean exit the file written there is ``fsync``-ed and renamed over ``path``; on an
    exception it is removed and ``path`` is untouched.
    """
    dest = Path(path)
    folder = dest.parent if str(dest.parent) else Path(".")
    if not folder.is_dir():
        raise ValueError(f"path: folder {folder} of {dest.name} does not exist")
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=f".{dest.stem}.", suffix=f".tmp{dest.suffix}")
    try:
        _chmod(fd, tmp, dest)
    finally:
        os.close(fd)
    try:
        yield Path(tmp)
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, dest)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise
    fsync_dir(folder)


_TEMP = re.compile(r"\..+\.[A-Za-z0-9_]{8}\.tmp(\.[A-Za-z0-9]+)?")  # mkstemp's names above


def remove_stale_temporaries(
    folder: str | os.PathLike, *, older_than_s: float = 600.0, recursive: bool = True
) -> list[Path]:
    """Delete the temporary files that crashed atomic writes left in ``folder``.

    Only names of the form :func:`atomic_open` / :func:`atomic_path` create
    (``.<name>.<8 characters>.tmp`` or ``.tmp<suffix>``) last modified more than
    ``older_than_s`` seconds ago are removed: a live writer keeps its temporary file for
    milliseconds to seconds, so an old one belongs to a process that died. Symbolic links are
    neither followed nor removed. Call it while holding the folder's write lock.

    Returns
    -------
    list of Path
        The files removed.
    """
    import time

    root = Path(folder)
    limit = time.time() - float(older_than_s)
    removed: list[Path] = []
    walker = os.walk(root, followlinks=False) if recursive else [(str(root), [], os.listdir(root))]
    for dirpath, _dirs, names in walker:
        for name in names:
            if not _TEMP.fullmatch(name):
                continue
            p = Path(dirpath) / name
            try:
                st = p.lstat()
                if not p.is_symlink() and p.is_file() and st.st_mtime < limit:
                    p.unlink()
                    removed.append(p)
            except FileNotFoundError:  # removed meanwhile
                continue
    if removed:
        for d in {p.parent for p in removed}:
            fsync_dir(d)
    return removed


def atomic_write(path: str | os.PathLike, data: bytes | str, *, encoding: str = "utf-8") -> None:
    """Write ``data`` (bytes, or text encoded with ``encoding``) to ``path`` atomically."""
    if isinstance(data, str):
        with atomic_open(path, "w", encoding=encoding) as fh:
            fh.write(data)
    elif isinstance(data, bytes | bytearray | memoryview):
        with atomic_open(path, "wb") as fh:
            fh.write(data)
    else:
        raise ValueError(f"data: expected bytes or str, got {type(data).__name__}")


def print_json(obj: Any, out: str | os.PathLike | None = None, *, indent: int = 2) -> None:
    """Print ``obj`` as JSON on stdout and, with ``out``, also write it there atomically: the
    output of the ``python -m core.<package>.benchmark`` and study commands."""
    text = json.dumps(obj, indent=indent)
    if out:
        atomic_write(out, text + "\n")
    sys.stdout.write(text + "\n")


def json_checkpoint(out: str | os.PathLike | None, *, indent: int = 2,
                    **fields: Any) -> Callable[[dict], None]:
    """A long study's checkpoint: ``checkpoint(res)`` sets in ``res`` the ``fields`` that have a
    value (a machine's name, say) and writes it to ``out`` atomically as JSON (NaN allowed, as
    :func:`print_json` writes it; ``out`` None: not written), so a run stopped part-way keeps what
    it measured."""
    given = {k: v for k, v in fields.items() if v}

    def checkpoint(res: dict) -> None:
        res.update(given)
        if out:
            atomic_write(out, json.dumps(res, indent=indent) + "\n")

    return checkpoint


def atomic_write_json(path: str | os.PathLike, obj: Any, *, indent: int = 2) -> None:
    """Write ``obj`` as strict JSON (no NaN/Infinity: use ``None``) atomically, UTF-8.

    Raises
    ------
    ValueError
        If ``obj`` holds NaN/Infinity or a value JSON cannot represent; nothing is written.
    """
    try:
        text = json.dumps(obj, indent=indent, allow_nan=False, ensure_ascii=False, sort_keys=False)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{os.fspath(path)}: cannot be written as strict JSON ({exc})") from exc
    atomic_write(path, text + "\n")


def append_durable(path: str | os.PathLike, data: bytes) -> None:
    """Append ``data`` to ``path`` (created if missing) and ``fsync`` it before returning."""
    p = Path(path)
    new = not p.exists()
    with open(p, "ab") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())
    if new:
        fsync_dir(p.parent)


# ---------------------------------------------------------------------------- locking
class LockedError(RuntimeError):
    """Raised when a :class:`FileLock` is already held (by another process or handle).

    Attributes
    ----------
    path : Path
        The lock file.
    holder : dict
        What the holder recorded (``pid``, ``host``, ``since``, ``purpose``, and ``by`` where it
        said what in it holds the lock), possibly empty.
    """

    def __init__(self, path: Path, holder: dict[str, Any], what: str = ""):
        self.path = path
        self.holder = holder
        who = (
            f"process {holder.get('pid', '?')} on {holder.get('host', '?')} "
            f"since {holder.get('since', '?')}" + (f" ({holder['by']})" if holder.get("by") else "")
            if holder
            else "another process"
        )
        target = what or str(path)
        super().__init__(
            f"{target} is locked for writing by {who} (lock file {path}); close it there first, "
            "or open it read-only"
        )


if sys.platform.startswith("win"):  # pragma: no cover - exercised on Windows only
    import msvcrt

    def _try_lock(fd: int) -> bool:
        try:
            os.lseek(fd, 0, os.SEEK_SET)
            msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
        except OSError:
            return False
        return True

    def _unlock(fd: int) -> None:
        os.lseek(fd, 0, os.SEEK_SET)
        msvcrt.locking(fd, msvcrt.LK_UNLCK, 1)

else:
    import fcntl

    def _try_lock(fd: int) -> bool:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return False
        return True

    def _unlock(fd: int) -> None:
        fcntl.flock(fd, fcntl.LOCK_UN)


#: times :meth:`FileLock.read_holder` reads a holder line that does not parse before it gives up: a
#: read can meet the line half written over by :meth:`FileLock.relabel` (the kernel does not make a
#: write and a read of the same bytes exclusive), which a read a millisecond later does not.
_TORN_READS = 5


class FileLock:
    """Exclusive, non-blocking, inter-process lock held on the file ``path``.

    Parameters
    ----------
    path : str or os.PathLike
        Lock file (created if missing; left in place on release).
    purpose : str
        Recorded in the lock file and used in the error message (e.g. the study folder).
    by : str
        What in the holding process holds it (e.g. ``"talus batch's trajectory check"``), recorded
        in the lock file beside ``purpose`` where given: a refused writer can name the holder,
        also one in its own process.

    Notes
    -----
    Two :class:`FileLock` objects on one file conflict even inside one process (``flock``
    locks belong to the open file description), so a study cannot be opened for writing twice.
    The lock is advisory: it protects Talus processes from each other, not against other tools.
    """

    def __init__(self, path: str | os.PathLike, *, purpose: str = "", by: str = ""):
        self.path = Path(path)
        self.purpose = str(purpose)
        self.by = str(by)
        self._fd: int | None = None

    @property
    def locked(self) -> bool:
        """True while this object holds the lock."""
        return self._fd is not None

    def read_holder(self) -> dict[str, Any]:
        """The holder information stored in the lock file (empty if unreadable). Its first JSON
        object: a line being rewritten (:meth:`relabel`: the new line written over the old one, then
        the old one's longer tail cut) reads as the new line, never as nothing; a line read while it
        was being written over (it does not parse) is read again, up to :data:`_TORN_READS` times."""
        import time

        for attempt in range(_TORN_READS):
            try:
                text = self.path.read_text(encoding="utf-8").lstrip()
            except (OSError, ValueError):
                return {}
            try:
                info = json.JSONDecoder().raw_decode(text)[0] if text else {}
            except ValueError:  # read while the line was being written over (torn): read it again
                if attempt + 1 < _TORN_READS:
                    time.sleep(0.001)
                continue
            return info if isinstance(info, dict) else {}
        return {}

    def acquire(self, timeout: float = 0.0) -> FileLock:
        """Take the lock, or raise :class:`LockedError` if it is still held elsewhere after
        ``timeout`` seconds (0, the default: at once; a short lock, such as the study
        manifest's, is waited for)."""
        import time

        if self._fd is not None:
            raise LockedError(self.path, self.read_holder(), self.purpose)
        if not _finite(timeout) or timeout < 0:
            raise ValueError(f"timeout: expected a finite number of seconds >= 0, got {timeout!r}")
        deadline = time.monotonic() + float(timeout)
        delay = 0.002
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            if _try_lock(fd):
                break
            os.close(fd)
            if time.monotonic() >= deadline:
                holder = self.read_holder()
                if not holder:  # taken a moment ago, its holder line not yet written (or an old one)
                    time.sleep(0.005)
                    holder = self.read_holder()
                raise LockedError(self.path, holder, self.purpose)
            time.sleep(min(delay, max(0.0, deadline - time.monotonic())))
            delay = min(delay * 2, 0.05)
        try:
            self._write_holder(fd)
        except BaseException:  # e.g. a full disk: let the lock go, or the open fd keeps it taken
            with contextlib.suppress(OSError):
                _unlock(fd)
            os.close(fd)
            raise
        self._fd = fd
        return self

    def relabel(self, by: str) -> None:
        """Name ``by`` as what holds the lock now (e.g. a tracker taking over a journal its handle
        already locked): the holder line is rewritten with ``since`` now, the lock kept throughout.
        The new line is written over the old one before the rest is cut, so that a writer refused
        meanwhile reads a holder (:meth:`read_holder`), never an empty file. The line cannot be
        replaced by renaming a new file over it: the lock belongs to the file itself.

        Raises
        ------
        ValueError
            This object does not hold the lock.
        """
        if self._fd is None:
            raise ValueError(f"{self.path}: relabel needs the lock held (acquire it first)")
        self.by = str(by)
        self._write_holder(self._fd)

    def _write_holder(self, fd: int) -> None:
        info = {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "since": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
            "purpose": self.purpose,
        }
        if self.by:
            info["by"] = self.by
        blob = json.dumps(info).encode()
        os.lseek(fd, 0, os.SEEK_SET)
        if os.write(fd, blob) != len(blob):
            raise OSError(f"{self.path}: the holder line was written in part")
        os.ftruncate(fd, len(blob))  # the old line's tail, where it was longer
        os.fsync(fd)

    def release(self) -> None:
        """Release the lock (idempotent)."""
        fd, self._fd = self._fd, None
        if fd is None:
            return
        try:
            os.ftruncate(fd, 0)
            _unlock(fd)
        finally:
            os.close(fd)

    def __enter__(self) -> FileLock:
        # ``with FileLock(p):`` takes the lock; ``with FileLock(p).acquire(timeout=...):`` keeps it
        return self if self._fd is not None else self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()

    def __del__(self) -> None:  # a forgotten lock is released with its object
        with contextlib.suppress(Exception):
            self.release()
