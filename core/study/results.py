"""Tracking results saved as they are produced: an append-only, checksummed pose journal.

One file per bone per trial, ``results/<trial>/poses/<bone>.jsonl``. Each finished frame
appends one line and ``fsync``-s it (:func:`core.io.atomic.append_durable`)::

    {"frame": 12, "pose": [16 numbers, row-major T_lab_from_bone, mm], "score": 0.83}<TAB>1a2b3c4d

The hexadecimal suffix is the CRC-32 of the JSON text. A crash can only damage the *last*
line (a partial write); :func:`read_journal` drops such a torn tail and reports it, so the
journal reads as it was before the frame in flight. A damaged line followed by good ones is not
a crash artefact and is reported as corruption. Later records for a frame supersede earlier ones
(re-tracking a frame); ``"pose": null`` clears a frame. :func:`rewrite_journal` compacts a journal
atomically (temporary file + rename).
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._validate import check_rigid
from ..io.atomic import append_durable, atomic_open
from .errors import StudyError

__all__ = ["JournalState", "PoseRecord", "append_pose", "read_journal", "repair_tail", "rewrite_journal"]


@dataclass(frozen=True, eq=False)
class PoseRecord:
    """One journal entry: ``pose`` (4x4, mm) or ``None`` for a cleared frame; ``score`` or NaN."""

    frame: int
    pose: np.ndarray | None
    score: float
    time: str = ""


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


def _encode(frame: int, pose: np.ndarray | None, score: float, time: str) -> bytes:
    rec = {
        "frame": int(frame),
        "pose": None if pose is None else [float(x) for x in np.asarray(pose).ravel()],
        "score": None if not math.isfinite(score) else float(score),
        "time": time,
    }
    text = json.dumps(rec, separators=(",", ":"), allow_nan=False)
    return f"{text}\t{zlib.crc32(text.encode()):08x}\n".encode()


def _decode(line: bytes) -> PoseRecord | None:
    """Parse one line (without its newline); None if damaged."""
    try:
        text, crc = line.decode("utf-8").rsplit("\t", 1)
        if int(crc, 16) != zlib.crc32(text.encode()) or len(crc) != 8:
            return None
        rec = json.loads(text)
        frame = rec["frame"]
        if not isinstance(frame, int) or frame < 0:
            return None
        pose = rec["pose"]
        if pose is not None:
            pose = np.asarray(pose, dtype=float).reshape(4, 4)
        score = rec.get("score")
        return PoseRecord(frame, pose, math.nan if score is None else float(score), rec.get("time", ""))
    except (ValueError, KeyError, TypeError, UnicodeDecodeError):
        return None


def read_journal(path: str | os.PathLike) -> JournalState:
    """Read a pose journal (a missing file reads as empty).

    Raises
    ------
    StudyError
        If a line other than the last is damaged (corruption, not an interrupted write).
    """
    p = Path(path)
    if not p.exists():
        return JournalState({}, 0, 0, 0)
    data = p.read_bytes()
    records: dict[int, PoseRecord] = {}
    pos = 0
    n = 0
    lines = data.split(b"\n")
    for i, line in enumerate(lines):
        last = i == len(lines) - 1
        if last and line == b"":  # file ends with a newline
            break
        rec = _decode(line) if not last else None  # a last line without newline is torn
        if rec is None:
            if last or all(rest == b"" for rest in lines[i + 1 :]):
                return JournalState(records, n, pos, len(data) - pos)
            raise StudyError(
                f"{p}: line {i + 1}: damaged record (bad checksum or JSON) followed by valid "
                "records; the journal is corrupt (not an interrupted write)"
            )
        records[rec.frame] = rec
        n += 1
        pos += len(line) + 1
    return JournalState(records, n, pos, 0)


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


def _now() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="milliseconds")


def append_pose(path: str | os.PathLike, frame: int, pose, *, score: float | None = None) -> None:
    """Append one frame's result durably (``pose=None`` clears the frame)."""
    frame, pose, score = _check(frame, pose, score)
    append_durable(path, _encode(frame, pose, score, _now()))


def rewrite_journal(path: str | os.PathLike, records: dict[int, PoseRecord]) -> None:
    """Replace a journal atomically by one line per frame (sorted), e.g. to compact it."""
    with atomic_open(path, "wb") as fh:
        for f in sorted(records):
            rec = records[f]
            fh.write(_encode(f, rec.pose, rec.score, rec.time or _now()))
