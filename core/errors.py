"""The error every reader raises for a file it cannot read, and the wrapper that produces it.

Kept at the root of ``core`` (no imports) so that every package can use it: the MayaCam reader of
:mod:`core.geometry` as well as the formats of :mod:`core.io` (which re-exports it).
A reader wraps its parsing in :func:`reading` (or is decorated with :func:`reads`)::

    with reading(path, "a multipage TIFF of grey-level frames"):
        ...  # tifffile, struct, numpy, SimpleITK, meshio, open(), ...

Whatever a third-party parser (or the reader's own checks) raises inside the block comes out as
:class:`FileError`: a :class:`ValueError` whose message names the file and what was expected,
with the original exception chained as ``__cause__`` for the traceback. Messages that already
name the file (the readers' own checks) are kept as they are.

:class:`core.study.StudyError` is a subclass (the study store's files).
"""

from __future__ import annotations

import contextlib
import functools
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TypeVar

__all__ = ["FileError", "reading", "reads"]

F = TypeVar("F", bound=Callable)


class FileError(ValueError):
    """A file or folder is missing, unreadable or not what was expected.

    Attributes
    ----------
    path : Path or None
        The file (or folder) at fault.
    expected : str
        What the reader expected to find there (may be empty).
    """

    def __init__(self, message: str, *, path: str | os.PathLike | None = None, expected: str = ""):
        super().__init__(message)
        self.path = Path(path) if path is not None else None
        self.expected = expected


def _message(path: Path, expected: str, exc: BaseException) -> str:
    text = str(exc).strip()
    if isinstance(exc, OSError) and exc.strerror:  # its own text repeats the path with quotes
        other = exc.filename is not None and os.fspath(exc.filename) != str(path)
        text = f"{exc.strerror}: {os.fspath(exc.filename)}" if other else exc.strerror
    if str(path) in text and not isinstance(exc, OSError):
        return text  # the reader's own check already says which file and what was wrong
    why = f"{type(exc).__name__}: {text}" if text else type(exc).__name__
    return f"{path}: cannot read as {expected} ({why})" if expected else f"{path}: cannot read ({why})"


@contextlib.contextmanager
def reading(path: str | os.PathLike, expected: str, *, error: type[FileError] = FileError) -> Iterator[None]:
    """Turn any error raised while reading ``path`` into a :class:`FileError` naming it.

    Parameters
    ----------
    path : str or os.PathLike
        The file (or folder) being read.
    expected : str
        What it should hold, e.g. ``"a Phantom cine file"``; used in the message.
    error : subclass of FileError
        The class raised (e.g. :class:`core.study.StudyError` for the study's own files).

    Notes
    -----
    A :class:`FileError` raised inside (e.g. by a nested reader) passes unchanged. Every other
    :class:`Exception` (``OSError``, ``ValueError``, ``struct.error``, ``EOFError``,
    ``MemoryError`` for an absurd size announced by a damaged header, or whatever a third-party
    parser raises) becomes a :class:`FileError` with the original as ``__cause__``.
    ``KeyboardInterrupt`` and ``SystemExit`` pass through.
    """
    p = Path(path)
    try:
        yield
    except FileError:
        raise
    except Exception as exc:
        raise error(_message(p, expected, exc), path=p, expected=expected) from exc


def reads(expected: str) -> Callable[[F], F]:
    """Decorate a reader whose first argument is the path: its body runs inside :func:`reading`.

    Keep the checks of the other arguments outside (in a wrapper), so that a wrong argument
    stays a plain ``ValueError`` naming the argument.
    """

    def deco(fn: F) -> F:
        @functools.wraps(fn)
        def wrapper(path, *args, **kwargs):
            with reading(path, expected):
                return fn(path, *args, **kwargs)

        return wrapper  # type: ignore[return-value]

    return deco
