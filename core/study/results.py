"""Tracking results saved as they are produced: an append-only, checksummed pose journal.

One file per bone per trial, ``results/<trial>/poses/<bone>.jsonl``. Each finished frame
appends one line and ``fsync``-s it (:func:`core.io.atomic.append_durable`)::

    {"v":2,"frame":12,"pose":[16 numbers, row-major T_lab_from_bone, mm],"score":0.83,"time":"…",
     "tracking":{"flags":[],"converged":true,…}}<TAB>1a2b3c4d

The hexadecimal suffix is the CRC-32 of the JSON text. A crash can only damage the *last*
line (a partial write); :func:`read_journal` drops such a torn tail and reports it, so the
journal reads as it was before the frame in flight. A damaged line followed by good ones is not
a crash artefact: it is refused as corruption (silently wrong data is never read), and
:func:`salvage_journal` (``talus study repair``) keeps every record whose checksum holds, sets
the original aside and reports the lines it dropped.

Records
-------
Three kinds of line, all version 2 (``"v": 2``):

* a **hand-set pose** (no ``"tracking"``): a pose placed or corrected by the user;
* a **tracking result** (``"tracking"``: the tracker's flags — the reasons for review —,
  convergence, retry, work, confidence, time breakdown and notes, as
  :meth:`core.tracking.trial.FrameResult.journal_fields` writes them): everything a tracking
  report holds about the frame, so that a resumed run rebuilds exactly the report of an
  uninterrupted one;
* a **clear** (``"pose": null``).

Version-1 lines (no ``"v"``: Talus before tracking results were journalled) read as *legacy*
poses: a pose with a score and no review state. Later records for a frame supersede earlier
ones for its pose. Per frame the journal also keeps (:class:`JournalState`):

* ``keyframes`` — the latest hand-set (or legacy) pose since the last clear, which a tracking
  result does not replace: the starting poses a tracking run saw;
* ``done`` — the frame's tracking result, or a hand-set pose recorded after one (a hand fix),
  or a legacy pose: what ``resume`` skips.

:func:`rewrite_journal` / :func:`compact_journal` rewrite a journal atomically (temporary file
+ rename), keeping what ``keyframes`` and ``done`` need.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._validate import check_rigid
from ..io.atomic import append_durable, atomic_open, atomic_write
from .errors import StudyError

__all__ = ["RECORD_VERSION", "JournalState", "PoseRecord", "append_pose", "compact_journal", "read_journal",
           "repair_tail", "rewrite_journal", "salvage_journal"]

RECORD_VERSION = 2
REPAIR_HINT = ("`talus study repair STUDY` (core.study.Study.repair) keeps every record whose checksum "
               "holds, sets the original aside as a backup and reports the rest")


@dataclass(frozen=True, eq=False)
class PoseRecord:
    """One journal entry: ``pose`` (4x4, mm) or ``None`` for a cleared frame; ``score`` or NaN;
    ``tracking`` the tracker's review state of the frame (None for a hand-set pose); ``version``
    the record format it was read from (1: before review state was journalled)."""

    frame: int
    pose: np.ndarray | None
    score: float
    time: str = ""
    tracking: dict | None = None
    version: int = RECORD_VERSION

    @property
    def kind(self) -> str:
        """``"cleared"``, ``"tracked"``, ``"hand"`` or ``"legacy"`` (a version-1 pose)."""
        if self.pose is None:
            return "cleared"
        if self.tracking is not None:
            return "tracked"
        return "legacy" if self.version < 2 else "hand"


@dataclass
class _FrameLog:
    latest: PoseRecord | None = None
    keyframe: PoseRecord | None = None
    result: PoseRecord | None = None
    fixed: PoseRecord | None = None

    def add(self, rec: PoseRecord) -> None:
        self.latest = rec
        kind = rec.kind
        if kind == "cleared":
            self.keyframe = self.result = self.fixed = None
        elif kind == "tracked":
            self.result, self.fixed = rec, None
        elif kind == "hand":
            self.keyframe = rec
            if self.result is not None:
                self.fixed = rec
        else:  # legacy: a starting pose and a done frame, as version 1 treated every pose
            self.keyframe = self.fixed = rec
            self.result = None

    def essential(self) -> list[PoseRecord]:
        """The fewest records that rebuild this state."""
        if self.latest is None or self.latest.kind == "cleared":
            return [self.latest] if self.latest is not None else []
        out = []
        if self.keyframe is not None and self.keyframe is not self.fixed:
            out.append(self.keyframe)
        if self.result is not None:
            out.append(self.result)
        if self.fixed is not None:
            out.append(self.fixed)
        return out


@dataclass(frozen=True, eq=False)
class JournalState:
    """The latest record of every frame in a journal.

    Attributes
    ----------
    records : dict[int, PoseRecord]
        Latest record per frame (cleared frames included, with ``pose=None``).
    n_lines : int
        Valid lines read.
    valid_bytes : int
        Length of the valid prefix of the file.
    torn_bytes : int
        Size of a torn last record that was ignored (0 when the file ended cleanly).
    """

    records: dict[int, PoseRecord]
    n_lines: int
    valid_bytes: int
    torn_bytes: int
    _log: dict = field(default_factory=dict, repr=False)

    def poses(self, n_frames: int) -> np.ndarray:
        """``(n_frames, 4, 4)`` poses, NaN for frames without a pose."""
        out = np.full((n_frames, 4, 4), np.nan)
        for f, rec in self.records.items():
            if rec.pose is not None and 0 <= f < n_frames:
                out[f] = rec.pose
        return out

    def scores(self, n_frames: int) -> np.ndarray:
        """``(n_frames,)`` similarity scores, NaN where none was recorded."""
        out = np.full(n_frames, np.nan)
        for f, rec in self.records.items():
            if rec.pose is not None and 0 <= f < n_frames:
                out[f] = rec.score
        return out

    @property
    def tracked_frames(self) -> tuple[int, ...]:
        return tuple(sorted(f for f, r in self.records.items() if r.pose is not None))

    @property
    def keyframes(self) -> dict[int, PoseRecord]:
        """Per frame the latest hand-set (or legacy) pose since its last clear, tracking results
        notwithstanding: the starting poses a tracking run saw."""
        return {f: lg.keyframe for f, lg in sorted(self._log.items()) if lg.keyframe is not None}

    @property
    def done(self) -> dict[int, PoseRecord]:
        """Per frame what a resumed tracking run takes as done: a hand fix recorded after a
        tracking result, else the tracking result (with its review state), else a legacy pose."""
        out = {}
        for f, lg in sorted(self._log.items()):
            rec = lg.fixed or lg.result
            if rec is not None:
                out[f] = rec
        return out

    def essential_records(self) -> dict[int, list[PoseRecord]]:
        """Per frame the fewest records (in order) that rebuild ``records``, ``keyframes`` and
        ``done``: what :func:`compact_journal` keeps."""
        return {f: lg.essential() for f, lg in sorted(self._log.items()) if lg.essential()}


def _encode(frame: int, pose: np.ndarray | None, score: float, time: str, tracking: dict | None = None,
            version: int = RECORD_VERSION) -> bytes:
    rec = {"v": RECORD_VERSION} if version >= 2 else {}
    rec.update({
        "frame": int(frame),
        "pose": None if pose is None else [float(x) for x in np.asarray(pose).ravel()],
        "score": None if not math.isfinite(score) else float(score),
        "time": time,
    })
    if tracking is not None and version >= 2:
        rec["tracking"] = tracking
    text = json.dumps(rec, separators=(",", ":"), allow_nan=False)
    return f"{text}\t{zlib.crc32(text.encode()):08x}\n".encode()


class _NewerRecord(Exception):
    pass


def _parse(line: bytes) -> tuple[PoseRecord | None, str]:
    """Parse one line (without its newline): ``(record, "")`` or ``(None, why it is damaged)``.
    Raises _NewerRecord for an intact record of a newer format."""
    try:
        text, crc = line.decode("utf-8").rsplit("\t", 1)
    except UnicodeDecodeError:
        return None, "not UTF-8 text"
    except ValueError:
        return None, "no checksum (no tab)"
    if len(crc) != 8 or any(c not in "0123456789abcdefABCDEF" for c in crc):
        return None, "malformed checksum"
    if int(crc, 16) != zlib.crc32(text.encode()):
        return None, "checksum mismatch"
    try:
        rec = json.loads(text)
        version = rec.get("v", 1)
        if isinstance(version, bool) or not isinstance(version, int) or version < 1:
            return None, f"bad record version {version!r}"
        if version > RECORD_VERSION:
            raise _NewerRecord(version)
        frame = rec["frame"]
        if isinstance(frame, bool) or not isinstance(frame, int) or frame < 0:
            return None, f"bad frame {frame!r}"
        pose = rec["pose"]
        if pose is not None:
            pose = np.asarray(pose, dtype=float).reshape(4, 4)
        score = rec.get("score")
        tracking = rec.get("tracking") if version >= 2 else None
        if tracking is not None and (not isinstance(tracking, dict) or pose is None):
            return None, "bad tracking state"
        return PoseRecord(frame, pose, math.nan if score is None else float(score), rec.get("time", ""),
                          tracking, version), ""
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        return None, f"invalid record ({type(exc).__name__})"


def _newer(p: Path, i: int, exc: _NewerRecord) -> StudyError:
    return StudyError(f"{p}: line {i + 1}: record version {exc.args[0]} is newer than this Talus reads "
                      f"({RECORD_VERSION}); update Talus to read this journal")


def read_journal(path: str | os.PathLike) -> JournalState:
    """Read a pose journal (a missing file reads as empty).

    Raises
    ------
    StudyError
        If a line other than the last is damaged (corruption, not an interrupted write: the
        message names the line and the salvage, :func:`salvage_journal`), or a record is of a
        newer format than this version reads.
    """
    p = Path(path)
    if not p.exists():
        return JournalState({}, 0, 0, 0)
    data = p.read_bytes()
    log: dict[int, _FrameLog] = {}
    pos = 0
    n = 0
    lines = data.split(b"\n")

    def state(torn: int) -> JournalState:
        recs = {f: lg.latest for f, lg in sorted(log.items()) if lg.latest is not None}
        return JournalState(recs, n, pos, torn, log)

    for i, line in enumerate(lines):
        last = i == len(lines) - 1
        if last and line == b"":  # file ends with a newline
            break
        rec, why = (None, "torn") if last else _parse_or_raise(p, i, line)  # no newline: torn
        if rec is None:
            if last or all(rest == b"" for rest in lines[i + 1 :]):
                return state(len(data) - pos)
            raise StudyError(
                f"{p}: line {i + 1}: damaged record ({why}) followed by valid records; the journal "
                f"is corrupt (not an interrupted write). {REPAIR_HINT}."
            )
        log.setdefault(rec.frame, _FrameLog()).add(rec)
        n += 1
        pos += len(line) + 1
    return state(0)


def _parse_or_raise(p: Path, i: int, line: bytes) -> tuple[PoseRecord | None, str]:
    try:
        return _parse(line)
    except _NewerRecord as exc:
        raise _newer(p, i, exc) from None


def repair_tail(path: str | os.PathLike) -> int:
    """Cut a torn last record off a journal before appending; returns the bytes removed."""
    p = Path(path)
    state = read_journal(p)
    if state.torn_bytes:
        with open(p, "r+b") as fh:
            fh.truncate(state.valid_bytes)
            fh.flush()
            os.fsync(fh.fileno())
    return state.torn_bytes


def _check(frame, pose, score) -> tuple[int, np.ndarray | None, float]:
    if isinstance(frame, bool) or not isinstance(frame, int | np.integer) or frame < 0:
        raise ValueError(f"frame: expected a non-negative integer, got {frame!r}")
    if pose is not None:
        pose = check_rigid(pose, "pose")
    score = math.nan if score is None else float(score)
    if math.isinf(score):
        raise ValueError(f"score: expected a finite number or None, got {score}")
    return int(frame), pose, score


def _check_tracking(tracking, pose) -> dict | None:
    if tracking is None:
        return None
    if not isinstance(tracking, Mapping):
        raise ValueError(f"tracking: expected a dict of the frame's review state, "
                         f"got {type(tracking).__name__}")
    if pose is None:
        raise ValueError("tracking: a tracking result needs a pose (pose=None clears the frame)")
    try:
        return json.loads(json.dumps(dict(tracking), allow_nan=False))
    except (TypeError, ValueError) as exc:
        raise ValueError(f"tracking: expected strict JSON values (None for NaN), {exc}") from None


def _now() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="milliseconds")


def append_pose(path: str | os.PathLike, frame: int, pose, *, score: float | None = None,
                tracking: Mapping | None = None) -> None:
    """Append one frame's result durably (``pose=None`` clears the frame; ``tracking``: the
    tracker's review state, JSON values, for a tracking result — None for a hand-set pose)."""
    frame, pose, score = _check(frame, pose, score)
    append_durable(path, _encode(frame, pose, score, _now(), _check_tracking(tracking, pose)))


def rewrite_journal(path: str | os.PathLike,
                    records: Mapping[int, PoseRecord | Sequence[PoseRecord]]) -> None:
    """Replace a journal atomically by the given records (per frame one record or a list, in
    order; frames sorted), each in its own format (a legacy record stays version 1)."""
    with atomic_open(path, "wb") as fh:
        for f in sorted(records):
            recs = records[f]
            for rec in ([recs] if isinstance(recs, PoseRecord) else recs):
                fh.write(_encode(f, rec.pose, rec.score, rec.time or _now(), rec.tracking, rec.version))


def compact_journal(path: str | os.PathLike) -> JournalState:
    """Rewrite a journal atomically with the fewest lines that keep its poses, keyframes and
    done frames (:meth:`JournalState.essential_records`); returns the state read."""
    state = read_journal(path)
    rewrite_journal(path, state.essential_records())
    return state


def salvage_journal(path: str | os.PathLike, *, dry_run: bool = False) -> dict:
    """Keep every record of a damaged journal whose checksum holds; report the rest.

    The original file is first copied aside (``<name>.damaged-<UTC time>``, atomically), then the
    journal is rewritten atomically with the intact lines, byte for byte and in order (later
    records still supersede earlier ones). Nothing is written when no line is dropped or with
    ``dry_run``.

    Returns
    -------
    dict
        JSON-ready: ``path``, ``lines`` (lines read), ``kept`` (count), ``dropped`` (one
        ``{"line": n (1-based), "bytes": size, "reason": …}`` per dropped line, with ``"frame"``
        where the damaged text still names one), ``frames_lost`` (frames named by dropped lines
        that have no intact record left; a dropped line may also have superseded an intact
        earlier record of its frame), ``changed`` and ``backup`` (the copy's path, or None).

    Raises
    ------
    StudyError
        If an intact record is of a newer format than this version reads (nothing is touched).
    """
    p = Path(path)
    report = {"path": str(p), "lines": 0, "kept": 0, "dropped": [], "frames_lost": [], "changed": False,
              "backup": None}
    if not p.exists():
        return report
    data = p.read_bytes()
    torn = bool(data) and not data.endswith(b"\n")
    lines = data.split(b"\n")
    if lines[-1] == b"":
        lines.pop()
    keep, frames_kept, frames_named = [], set(), set()
    for i, line in enumerate(lines):
        if i == len(lines) - 1 and torn:
            rec, why = None, "torn last record (no newline: an interrupted write)"
        elif line == b"":
            rec, why = None, "empty line"
        else:
            try:
                rec, why = _parse(line)
            except _NewerRecord as exc:
                raise _newer(p, i, exc) from None
        if rec is not None:
            keep.append(line + b"\n")
            frames_kept.add(rec.frame)
            continue
        entry = {"line": i + 1, "bytes": len(line), "reason": why}
        frame = _frame_hint(line)
        if frame is not None:
            entry["frame"] = frame
            frames_named.add(frame)
        report["dropped"].append(entry)
    report["lines"], report["kept"] = len(lines), len(keep)
    report["frames_lost"] = sorted(frames_named - frames_kept)
    if not report["dropped"] or dry_run:
        return report
    stamp = _dt.datetime.now(_dt.UTC).strftime("%Y%m%dT%H%M%S.%fZ")
    backup = p.with_name(f"{p.name}.damaged-{stamp}")
    atomic_write(backup, data)
    atomic_write(p, b"".join(keep))
    report["changed"], report["backup"] = True, str(backup)
    return report


def _frame_hint(line: bytes) -> int | None:
    """The frame number a damaged line still shows, if any (for the salvage report)."""
    import re

    m = re.search(rb'"frame":(\d{1,9})[,}]', line)
    return int(m.group(1)) if m else None
