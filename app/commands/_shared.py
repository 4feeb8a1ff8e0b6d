"""What every ``talus`` command shares: exit statuses, JSON output, progress, Ctrl-C, errors.

* **JSON** results go to stdout (:func:`print_json`), progress and diagnostics to stderr.
* **Progress** (:class:`Progress`) is one line per step with the elapsed time and an estimate
  of the time left; on a terminal the line is rewritten in place (a bar).
* **Ctrl-C** (:func:`sigint_cancels`) sets a :class:`CancelToken` that the ``core`` job polls,
  so the job stops cleanly after the step in flight; a second Ctrl-C interrupts at once.
* **Errors** (:func:`report_error`): library errors become one line (a ``core`` error names its
  file), a study locked by another writer a paragraph saying who holds it; ``talus --debug`` or
  ``TALUS_DEBUG=1`` shows the traceback instead.

Nothing here imports ``core`` or numpy at module level: ``talus --help`` stays fast.
"""

from __future__ import annotations

import contextlib
import importlib
import json
import numbers
import os
import signal
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TextIO

PROG = "talus"

# exit statuses (documented in the README's `talus` section)
EXIT_OK = 0
EXIT_ERROR = 1  # bad input, unreadable or invalid file (the message names it)
EXIT_USAGE = 2  # bad command-line arguments (argparse's own status)
EXIT_LOCKED = 3  # the study is open for writing elsewhere
EXIT_NOTHING_DONE = 4  # the command ran but had nothing it could do (no bone could be tracked)
EXIT_CANCELLED = 130  # stopped by Ctrl-C (the shell's convention for SIGINT)

DEBUG_ENV = "TALUS_DEBUG"


class CliError(Exception):
    """An error reported to the user as one line, without a traceback."""

    def __init__(self, message: str, status: int = EXIT_ERROR) -> None:
        super().__init__(message)
        self.status = status


# ------------------------------------------------------------------------------ lazy imports
def load(target: str, *, needed_for: str, hint: str = "") -> Callable[..., Any]:
    """Import ``"module:attr"`` on first use; a missing module is named in the error."""
    module, _, attr = target.partition(":")
    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError as exc:
        missing = exc.name or module
        where = "" if missing == module else f" (imported by '{module}')"
        extra = f" {hint}" if hint else ""
        raise CliError(
            f"{needed_for} needs the module '{missing}'{where}, which is not installed or "
            f"cannot be imported.{extra}"
        ) from exc
    try:
        return getattr(mod, attr)
    except AttributeError as exc:
        raise CliError(
            f"{needed_for} needs '{module}.{attr}', which this installation does not provide"
        ) from exc


# ------------------------------------------------------------------------------------ JSON
def _json_default(obj: Any) -> Any:
    """JSON for paths, numpy scalars/arrays and dataclasses found in result dicts."""
    if isinstance(obj, Path):
        return str(obj)
    if hasattr(obj, "tolist"):  # numpy arrays and scalars
        return obj.tolist()
    if hasattr(obj, "__dataclass_fields__"):
        return {name: getattr(obj, name) for name in obj.__dataclass_fields__}
    return repr(obj)


def to_json(result: Any) -> str:
    return json.dumps(result, indent=2, default=_json_default)


def write_atomically(path: Path, content: str | bytes) -> None:
    """Write text (plus a newline) or bytes to ``path``: temporary file, fsync, rename."""
    from core.io.atomic import atomic_write

    path = Path(path).expanduser()
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, content if isinstance(content, bytes) else content + "\n")


def print_json(result: Any, out: str | os.PathLike | None = None) -> None:
    """Print ``result`` as JSON on stdout and, with ``out``, also write it there atomically."""
    text = to_json(result)
    if out:
        write_atomically(Path(out), text)
    sys.stdout.write(text + "\n")
    sys.stdout.flush()


def study_folder(path: str | os.PathLike, what: str = "STUDY") -> Path:
    """``path`` (``~`` expanded) when it is a folder (its ``study.json`` given stands for it), else a
    :class:`CliError` naming the argument ``what``: the first check of every command that takes a
    study."""
    folder = Path(path).expanduser()
    if folder.name == "study.json" and folder.is_file():
        folder = folder.parent
    if not folder.is_dir():
        raise CliError(f"{what}: no study folder at {folder}")
    return folder


def names(text: str | None) -> list[str] | None:
    """A comma-separated list of names (``--bones talus, calcaneus``, ``--trials``), spaces around
    each name dropped (' calcaneus' was 'no bone'); None for None."""
    return None if text is None else [n for n in (t.strip() for t in text.split(",")) if n]


def warp_device(device: str | None, option: str = "--device") -> str | None:
    """``device`` checked before any work: None (the default device), ``cpu``, or ``cuda`` /
    ``cuda:N`` when Warp finds that GPU; else a :class:`CliError` naming ``option`` and what this
    machine has. ('--device cuda' without a GPU was 'RuntimeError: "cuda" device requested but
    CUDA is not supported ...' with a hint to report a bug; '--device gpu' was 'Invalid device
    identifier: gpu'.)"""
    if device is None or device == "cpu":
        return device
    head, _, index = device.partition(":")
    if head != "cuda" or (index and not index.isdigit()):
        raise CliError(f"{option}: expected cpu, cuda or cuda:N (a GPU's number), got {device!r}")
    try:
        import warp as wp

        with stdout_to_stderr():
            wp.config.quiet = True
            wp.init()
            count = int(wp.get_cuda_device_count())
    except Exception as exc:  # Warp cannot start: the command would fail the same way
        raise CliError(f"{option} {device}: Warp could not start ({exc})") from None
    if count == 0:
        raise CliError(f"{option} {device}: no CUDA GPU found on this machine (or its driver is "
                       "missing); use --device cpu, or leave --device out")
    if index and int(index) >= count:
        raise CliError(f"{option} {device}: this machine has {count} CUDA GPU(s), cuda:0 to cuda:{count - 1}")
    return device


def text_bar(done: int, total: int, width: int = 20) -> str:
    """``[####......]``: ``width`` characters, ``#`` in proportion to ``done / total``."""
    k = int(width * done / max(total, 1))
    return f"[{'#' * k}{'.' * (width - k)}]"


@contextlib.contextmanager
def stdout_to_stderr() -> Iterator[None]:
    """Keep stdout pure JSON while library code runs (Warp prints its banner on stdout)."""
    with contextlib.redirect_stdout(sys.stderr):
        yield


# -------------------------------------------------------------------------------- progress
def _duration(seconds: float) -> str:
    seconds = max(0.0, float(seconds))
    if seconds < 60:
        return f"{seconds:.1f} s" if seconds < 10 else f"{seconds:.0f} s"
    minutes, s = divmod(round(seconds), 60)
    if minutes < 60:
        return f"{minutes} min {s:02d} s"
    hours, minutes = divmod(minutes, 60)
    return f"{hours} h {minutes:02d} min"


class Progress:
    """A progress callback for ``core`` jobs, printing to stderr with elapsed time and ETA.

    Called as ``progress(done, total)``, ``progress(done, total, message)`` or
    ``progress(fraction)``. Each call prints ``talus <what>: <unit> done/total [message]
    (elapsed, ETA …)``; on a terminal the line is rewritten in place, elsewhere (a log file,
    a pipe) each call is one line. ``quiet`` prints nothing.
    """

    def __init__(self, what: str, unit: str = "", *, quiet: bool = False,
                 stream: TextIO | None = None, in_place: bool | None = None) -> None:
        self.what, self.unit, self.quiet = what, unit, quiet
        self.stream = stream if stream is not None else sys.stderr
        self.in_place = (bool(getattr(self.stream, "isatty", lambda: False)())
                         if in_place is None else in_place)
        self.start = time.perf_counter()
        self._open_line = False
        # a job in stages (the demo's trial, then its calibration session) counts each stage's
        # steps afresh: the ETA runs from the stage's start (the previous stage's last step)
        self._count, self._stage_start, self._last = None, self.start, self.start
        self._skipped = 0  # steps of the stage done before (resumed work): not timed

    def eta(self, fraction: float) -> float | None:
        """Seconds left at ``fraction`` done of the current stage (None before the first step)."""
        if not 0.0 < fraction <= 1.0:
            return None
        elapsed = time.perf_counter() - self._stage_start
        return elapsed * (1.0 - fraction) / fraction

    def resumed(self, steps: int, *, restart: bool = True) -> None:
        """The first ``steps`` of the current count were done before (a resumed run's frames
        taken back from its journal in no time): the ETA counts only the steps after them, timed
        from now (``restart=False``: from when it was last restarted). Without it a resumed
        ``talus track`` said 'ETA 0.8 s' before a minute-long frame."""
        self._skipped = int(steps)
        if restart:
            self._stage_start = time.perf_counter()

    def __call__(self, *args: Any, **kwargs: Any) -> None:
        if self.quiet:
            return
        values = [a for a in args if isinstance(a, numbers.Real) and not isinstance(a, bool)]
        texts = [str(a) for a in args if not isinstance(a, numbers.Real) and a is not None]
        texts += [str(v) for k, v in kwargs.items() if k in ("message", "msg", "stage")]
        fraction = None
        if len(values) >= 2:
            count = (int(values[0]), int(values[1]))
            if self._count is not None and (count[1] != self._count[1] or count[0] < self._count[0]):
                self._stage_start = self._last  # the count restarted: a new stage
                self._skipped = 0
            self._count = count
        self._last = time.perf_counter()
        if len(values) >= 2:
            done, total = int(values[0]), int(values[1])
            status = f"{self.unit} {done}/{total}".strip()
            timed = total - self._skipped  # the steps this run does
            fraction = (done - self._skipped) / timed if timed > 0 and done > self._skipped else None
        elif len(values) == 1:
            fraction = float(values[0])
            status = f"{100.0 * fraction:.0f}%"
        else:
            status = ""
        elapsed = time.perf_counter() - self.start
        timing = _duration(elapsed)
        left = self.eta(fraction) if fraction is not None else None
        if left is not None and fraction < 1.0:
            timing += f", ETA {_duration(left)}"
        line = " ".join(s for s in [status, *texts] if s)
        text = f"{PROG} {self.what}: {line} ({timing})"
        if self.in_place:
            self.stream.write(f"\r{text}\033[K")
            self._open_line = True
        else:
            self.stream.write(text + "\n")
        self.stream.flush()

    def note(self, text: str) -> None:
        """A line that stays (e.g. a flagged frame), above an in-place progress line."""
        if self.quiet:
            return
        self.close()
        self.stream.write(f"{PROG} {self.what}: {text}\n")
        self.stream.flush()

    def close(self) -> None:
        """End an in-place progress line (call before printing anything else to stderr)."""
        if self._open_line:
            self.stream.write("\n")
            self.stream.flush()
            self._open_line = False


# ---------------------------------------------------------------------------------- Ctrl-C
class CancelToken:
    """Cancellation flag handed to :mod:`core` jobs as their ``cancel`` callback.

    ``token()``, ``token.is_set()`` and ``bool(token)`` answer "has the user asked to stop?".
    """

    def __init__(self) -> None:
        self._set = False

    def set(self) -> None:
        self._set = True

    def is_set(self) -> bool:
        return self._set

    __call__ = is_set
    __bool__ = is_set


@contextlib.contextmanager
def sigint_cancels(token: CancelToken, what: str) -> Iterator[CancelToken]:
    """First Ctrl-C sets ``token`` (the job stops cleanly); a second one interrupts at once."""
    previous = signal.getsignal(signal.SIGINT)

    def on_sigint(signum, frame):
        token.set()
        print(f"\n{PROG} {what}: cancelling after the step in progress (Ctrl-C again to abort) ...",
              file=sys.stderr, flush=True)
        signal.signal(signal.SIGINT, signal.default_int_handler)

    try:
        signal.signal(signal.SIGINT, on_sigint)
    except ValueError:  # not the main thread: leave Ctrl-C alone
        yield token
        return
    try:
        yield token
    finally:
        signal.signal(signal.SIGINT, previous)


# ---------------------------------------------------------------------------------- errors
def debugging() -> bool:
    """True when tracebacks are wanted (``talus --debug`` or ``TALUS_DEBUG=1``)."""
    return os.environ.get(DEBUG_ENV, "").strip().lower() not in ("", "0", "false", "no")


def locked_message(exc: BaseException) -> str:
    """One paragraph for a study (or file) locked by another writer: what, who, since when."""
    holder = dict(getattr(exc, "holder", None) or {})
    path = getattr(exc, "path", None)
    purpose = str(holder.get("purpose") or "")
    if purpose.startswith(("study ", "bone ", "the manifest ", "report ")):
        what = purpose
    elif path is not None:
        what = f"study {Path(path).parent}" if Path(path).name == ".talus.lock" else str(path)
    else:
        what = "the study"
    if holder.get("pid"):
        who = f"process {holder['pid']} on {holder.get('host', 'an unknown host')}"
        since = f" since {holder['since']}" if holder.get("since") else ""
    else:
        who, since = "another process", ""
    lock = f" (lock file {path})" if path is not None else ""
    return (f"{what} is open for writing by {who}{since}{lock}. Only one program may write it "
            "at a time (others may track other bones or trials of the study): close it there or "
            "wait for that job to finish, then try again. Reading the study is possible meanwhile.")


def _is_locked(exc: BaseException) -> bool:
    return any(c.__name__ == "LockedError" and c.__module__.startswith("core.")
               for c in type(exc).__mro__)


def report_error(exc: BaseException, command: str, *, stream: TextIO | None = None) -> int:
    """Print ``exc`` for the user (no traceback) and return the exit status for it.

    * a study locked by another writer: a paragraph, :data:`EXIT_LOCKED`;
    * :class:`CliError`: its message and status;
    * ``ValueError``/``OSError``/``LookupError`` (the library's errors name the file or
      argument at fault): one line, :data:`EXIT_ERROR`;
    * anything else (a bug): one line with the exception's type and a hint to rerun with
      ``--debug`` for the traceback, :data:`EXIT_ERROR`.
    """
    stream = stream if stream is not None else sys.stderr
    where = f"{PROG} {command}" if command else PROG
    if _is_locked(exc):
        print(f"{where}: {locked_message(exc)}", file=stream)
        return EXIT_LOCKED
    if isinstance(exc, CliError):
        print(f"{where}: error: {exc}", file=stream)
        return exc.status
    text = " ".join(str(exc).split()) or type(exc).__name__
    if isinstance(exc, FileNotFoundError) and exc.filename and exc.filename not in text:
        text = f"{exc.filename}: {text}"
    if isinstance(exc, ValueError | OSError | LookupError):
        print(f"{where}: error: {text}", file=stream)
    else:
        print(f"{where}: error: {type(exc).__name__}: {text} (run '{PROG} --debug {command}' "
              "for the traceback)", file=stream)
    return EXIT_ERROR
