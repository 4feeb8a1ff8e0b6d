"""The :class:`Trial` façade: one trial of a :class:`~core.study.Study` (views, rig, bones, results)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .errors import StudyError
from .results import JournalState, append_pose, compact_journal, read_journal, repair_tail

if TYPE_CHECKING:
    from ..geometry.camera import Rig
    from ..io.paired import TwoViewSequence

__all__ = ["Trial"]


class Trial:
    """A trial of a study: its fluoro views, calibration, bones and tracking results.

    Obtain it with :meth:`Study.trial`. Frame ``t`` of the trial is frame ``t`` of view 0 and
    frame ``t + frame_offset`` of view 1. Results are kept per bone in an append-only journal
    (:mod:`core.study.results`): :meth:`record_pose` makes one frame durable before returning,
    so a crash or cancel loses at most the frame in flight.
    """

    def __init__(self, study, name: str):  # study: a Study (not imported: study.py imports this module)
        self._study = study
        self._name = name
        self._seq: TwoViewSequence | None = None
        self._repaired: set[str] = set()
        self._left_size: dict[str, tuple] = {}  # bone -> _size(journal) after our last append

    def _entry(self) -> dict:
        try:
            return self._study._doc["trials"][self._name]
        except KeyError:
            raise StudyError(f"trial: {self._name!r} is no longer in the study") from None

    def _close(self) -> None:
        if self._seq is not None:
            self._seq.close()
            self._seq = None

    def __repr__(self) -> str:
        return f"Trial({self._name!r}, views={len(self.view_paths)}, bones={list(self.bones)})"

    # ------------------------------------------------------------------ description
    @property
    def name(self) -> str:
        return self._name

    @property
    def calibration(self) -> str:
        return self._entry()["calibration"]

    @property
    def frame_offset(self) -> int:
        return int(self._entry().get("frame_offset", 0))

    @property
    def bones(self) -> tuple[str, ...]:
        return tuple(self._entry().get("bones", ()))

    @property
    def view_paths(self) -> tuple[Path, ...]:
        return tuple(self._study.path(v["path"]) for v in self._entry()["views"])

    def rig(self) -> Rig:
        return self._study.rig(self.calibration)

    def sequences(self) -> TwoViewSequence:
        """The paired views (opened lazily, kept open until the study is closed)."""
        from ..io.paired import TwoViewSequence
        from ..io.sequences import open_sequence

        if self._seq is None:
            views = self._entry()["views"]
            if len(views) != 2:
                raise StudyError(
                    f"trial {self._name!r}: expected 2 views for a biplane trial, got {len(views)}"
                )
            seqs = [open_sequence(self._study.path(v["path"]), bit_depth=v.get("bit_depth")) for v in views]
            try:
                self._seq = TwoViewSequence(seqs[0], seqs[1], offset=self.frame_offset)
            except BaseException:
                for s in seqs:
                    s.close()
                raise
        return self._seq

    @property
    def n_frames(self) -> int:
        return len(self.sequences())

    def frames(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        """The two images of trial frame ``t`` (see :class:`~core.io.TwoViewSequence`)."""
        return self.sequences()[t]

    # ------------------------------------------------------------------ results
    def _journal(self, bone: str) -> Path:
        if bone not in self.bones:
            raise StudyError(f"bone: trial {self._name!r} has no bone {bone!r} (has {list(self.bones)})")
        return self._study.folder / "results" / self._name / "poses" / f"{bone}.jsonl"

    def results(self, bone: str) -> JournalState:
        """Everything recorded for ``bone`` (latest record per frame)."""
        return read_journal(self._journal(bone))

    def poses(self, bone: str) -> np.ndarray:
        """``(n_frames, 4, 4)`` ``T_lab_from_bone`` in mm; NaN for untracked frames."""
        return self.results(bone).poses(self.n_frames)

    def scores(self, bone: str) -> np.ndarray:
        """``(n_frames,)`` similarity scores; NaN where none was recorded."""
        return self.results(bone).scores(self.n_frames)

    def _writable_journal(self, bone: str) -> Path:
        self._study._require_write()
        path = self._journal(bone)
        if bone not in self._repaired:
            self._study.lock_journal(self._name, bone)  # held until the study is closed
            if self._left_size.get(bone) != _size(path):  # written by others since (or never by us)
                repair_tail(path)  # safe: we hold the journal's lock
            self._repaired.add(bone)
        return path

    def _appended(self, bone: str, path: Path) -> None:
        """Note the journal's size after our complete append: taken again (the window's lock per
        hand fix, :meth:`core.study.Study.unlock_journal`) with that size, no writer has appended
        since, so no torn record is there to repair (repair_tail reads the whole journal: 28 ms for
        2000 records on a 2-core x86_64 machine, per move of a drag)."""
        self._left_size[bone] = _size(path)

    def record_pose(self, bone: str, frame: int, pose, *, score: float | None = None,
                    tracking: dict | None = None) -> None:
        """Save one frame's pose (4x4 rigid ``T_lab_from_bone``, mm) and score durably.

        ``tracking`` is the tracker's review state of the frame (flags and their reasons,
        confidence, …: :meth:`core.tracking.trial.FrameResult.journal_fields`) for a tracking
        result; without it the pose is a hand-set one (a keyframe, or a fix of a tracked frame).
        See :mod:`core.study.results`."""
        path = self._writable_journal(bone)
        n = self.n_frames
        if isinstance(frame, bool) or not isinstance(frame, int | np.integer) or not 0 <= frame < n:
            raise ValueError(
                f"frame: expected an integer in [0, {n}) for trial {self._name!r}, got {frame!r}"
            )
        append_pose(path, int(frame), pose, score=score, tracking=tracking)
        self._appended(bone, path)

    def clear_pose(self, bone: str, frame: int) -> None:
        """Mark ``frame`` untracked for ``bone`` (e.g. before re-tracking a bad frame)."""
        path = self._writable_journal(bone)
        append_pose(path, frame, None)
        self._appended(bone, path)

    def compact(self, bone: str) -> None:
        """Rewrite the bone's journal with the fewest lines that keep its poses, keyframes and
        tracking results (atomic; :func:`core.study.results.compact_journal`)."""
        compact_journal(self._writable_journal(bone))
        self._left_size.pop(bone, None)

    def export_tra(self, path: str | os.PathLike, bones: tuple[str, ...] | None = None, **options) -> None:
        """Write the poses of ``bones`` (default: all) as an Autoscoper ``.tra`` file.

        ``options`` are passed to :func:`core.io.autoscoper.write_tra`. Note that the poses are
        Talus ``T_lab_from_bone`` matrices (CT physical frame), written as they are.
        """
        from ..io.autoscoper import write_tra

        bones = self.bones if bones is None else tuple(bones)
        poses = np.stack([self.poses(b) for b in bones], axis=1)
        write_tra(path, poses, **options)


def _size(path: Path) -> tuple:
    """The journal's signature: size, file and modification time. Another writer's appends change
    the size; a rewrite (a compaction or salvage, atomic: another file) followed by a torn append
    could leave the size as it was, but not the file or the time."""
    try:
        st = path.stat()
    except FileNotFoundError:
        return ()
    return st.st_size, st.st_ino, st.st_mtime_ns
