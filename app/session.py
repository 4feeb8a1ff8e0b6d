"""An open study in the window: a :class:`core.study.Study` trial as a :class:`ViewerModel`.

* Every pose edit (drag, nudge, undo, tracking result) is appended to the trial's pose journal
  at once (``Trial.record_pose``: fsync-ed appends), so closing, a crash or a power cut loses
  nothing; there is no separate "save".
* A marker file ``results/<trial>/.session-open`` is written while a window edits the trial;
  finding one at open time means the window that last edited the trial ended without closing (the
  window reports that what was recorded up to then has been restored). It is per trial, as the
  window lock is: a second window on another trial of the study neither finds the first one's
  marker nor removes it (a study-wide marker made it report a crash that was not one). The
  study-wide ``results/.session-open`` of older versions still counts as a crash once (removed),
  unless an older window is open on another trial (its window lock or journals held elsewhere).
* Frames are read lazily from the trial's sequences and cached.
* Bones start at their recorded poses; frames without one take the nearest recorded frame's
  pose (or the identity), and recorded frames are the keyframes.
* The window holds no bone's journal it is not writing: a hand edit takes the journal's lock for
  its append only (:meth:`StudySession.hand_edit`, :mod:`app.hand_edits`), waiting for it up to
  :data:`~app.hand_edits.HAND_EDIT_WAIT_S` off the GUI thread's way — for the trajectory check of
  a batch (the window's, :mod:`app.batch_panel`, or ``talus batch`` run beside it), which holds a
  trial's journals while it reads them and rewrites their flags (:mod:`core.tracking.batch_journal`),
  or a range task's append — and the window's own tracking job holds its bones' journals while it
  runs (:meth:`StudySession.let_go` after it). So a ``talus batch`` of range tasks on the trial
  keeps writing while the window is open: the window held every bone's journal from opening, taken
  between two of the batch's writes, and the batch's next task waited 60 s for it and failed. A
  writer that still holds a journal (a task tracking the bone holds it to its end) refuses the
  edit, and the window's messages say who holds it (from the lock's holder line) and that the
  edit is not saved.
* At opening the window checks that no other program writes a bone of the trial (each journal's
  lock taken and let go at once) and takes the trial's window lock
  (``results/<trial>/.window.lock``, held while it is open): where either is held elsewhere — a
  ``talus track`` of a bone, or another window editing the trial — it opens the study read-only
  and says why (:class:`core.study.LockedError`).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from core.study import Study

from .hand_edits import HAND_EDIT_WAIT_S, REFUSED_QUIET_S, HandEdits
from .model import ViewerModel

__all__ = ["HAND_EDIT_WAIT_S", "REFUSED_QUIET_S", "MissingFilesError", "StudySession", "open_study"]

MARKER = ".session-open"  # results/<trial>/: a window edits the trial (results/: older versions')
WINDOW_LOCK = ".window.lock"  # results/<trial>/: held by the window that edits the trial


class MissingFilesError(ValueError):
    """The study references files that are not there (``missing``: (what, path) pairs)."""

    def __init__(self, folder: Path, missing: list[tuple[str, Path]]):
        self.folder = folder
        self.missing = missing
        lines = "\n".join(f"  {what}: {path}" for what, path in missing[:10])
        super().__init__(f"{folder}: {len(missing)} referenced file(s) are missing:\n{lines}")


def _fill(poses: np.ndarray) -> tuple[np.ndarray, set[int]]:
    """Fill NaN frames from the nearest recorded frame; returns (poses, recorded frames)."""
    known = np.flatnonzero(np.isfinite(poses).all(axis=(1, 2)))
    out = np.tile(np.eye(4), (len(poses), 1, 1))
    if known.size:
        nearest = known[np.abs(np.arange(len(poses))[:, None] - known[None, :]).argmin(axis=1)]
        out = poses[nearest]
    return out, set(int(k) for k in known)


@dataclass
class StudySession:
    study: Study
    trial_name: str
    model: ViewerModel
    recovered: bool = False
    writable: bool = True
    recording: bool = True  # False while applying poses read back from the journal
    read_only_reason: str | None = None  # why a study is open read-only (another writer holds it)
    #: where a hand edit that could not be saved is said (the window's messages: ``notify(text,
    #: tag)``, a message with the tag of the last one updating it); None: the edit waits blocking,
    #: and a refusal is raised
    notify: Callable[[str, str | None], None] | None = None
    #: called with (bone, frame, pose) once a pose edit of the model is journaled (the frame table)
    saved: Callable[[str, int, np.ndarray], None] | None = None
    _closed: bool = field(default=False, repr=False)
    edits: HandEdits = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self.edits = HandEdits(self)

    def let_go(self, bones) -> None:
        """Release the journals of ``bones`` this window holds but no longer writes (its tracking
        job's, once it ends): a batch beside it may take them."""
        for b in bones:
            self.study.unlock_journal(self.trial_name, b)

    def unsaved(self, bone: str) -> bool:
        """Whether ``bone``'s last hand edit is not in the journal (refused, or waiting for the
        journal): the frame table keeps the journal's status of the frame rather than showing it
        edited until :attr:`saved` says it is."""
        return self.edits.unsaved(bone)

    def hand_edit(self, bone: str, write: Callable[[], None], *, key=None,
                  done: Callable[[], None] | None = None) -> str:
        """Run ``write``, a hand edit's append to ``bone``'s journal (see the module notes and
        :mod:`app.hand_edits`): at once where the window holds the journal or it is free, else
        once its lock comes, within :data:`HAND_EDIT_WAIT_S` (not waited for within
        :data:`REFUSED_QUIET_S` of a refusal); ``done`` runs once it is written. Returns
        ``"saved"``, ``"waiting"`` or ``"refused"`` (said through :attr:`notify`).

        Raises
        ------
        core.study.LockedError
            With no :attr:`notify`: another writer still holds the journal after the wait; the
            message says who and that the edit is not saved.
        """
        return self.edits.submit(bone, write, key=key, done=done)

    def require_writable(self, what: str) -> None:
        """Raise ``ValueError`` naming ``what`` needs writing and why the study is read-only (the
        other program holding it, from the lock it found), so the user knows what to close."""
        if self.writable:
            return
        why = self.read_only_reason or "it was opened read-only"
        raise ValueError(f"study: {what} needs the study open for writing, but {why.rstrip('.')}. "
                         "When that is over, open the study again (File → Open recent).")

    @property
    def folder(self) -> Path:
        return self.study.folder

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self.edits.close()  # edits waiting for a journal: journaled, or refused and said
        finally:
            if self.writable:
                with contextlib.suppress(OSError):
                    (self.study.folder / "results" / self.trial_name / MARKER).unlink()
            self.study.close()  # and the trial's window lock


def _older_window_open(st: Study, trial: str) -> bool:
    """Whether another program holds a lock of the study's other trials — their window locks, or
    (older versions held them while open) their bones' journals: the study-wide marker of an older
    version may then be that window's, open, not a crash (not reported, left for a later opening;
    a tracker holding a journal delays the report too, rather than making a false one)."""
    from core.io.atomic import FileLock
    from core.study import LockedError

    results = st.folder / "results"
    for other in st.trials:
        if other == trial:  # this trial's locks: ours, or checked already
            continue
        paths = [results / other / WINDOW_LOCK, *(results / other / "poses").glob(".*.lock")]
        for path in paths:
            if not path.is_file():  # never taken: no one holds it (and no file is made here)
                continue
            try:
                FileLock(path).acquire().release()
            except LockedError:
                return True
    return False


def open_study(folder: str | Path, *, trial: str | None = None,
               read_only: bool = False) -> StudySession:
    """Open a study folder for the window.

    Raises
    ------
    MissingFilesError
        When referenced files are missing (the caller can offer to relocate them).
    core.study.LockedError
        When another process writes a bone of the trial, or another window edits it (retry with
        ``read_only``). No bone's journal stays locked (see the module notes).
    ValueError / core.study.StudyError
        For a folder that is not a valid study.
    """
    folder = Path(folder).expanduser()
    st = Study.open(folder, mode="r" if read_only else "w", check_files=False)
    try:
        missing = st.missing_files()
        if missing:
            raise MissingFilesError(folder, list(missing))
        if not st.trials:
            raise ValueError(f"{folder}: the study has no trial to show")
        name = trial or st.trials[0]
        tr = st.trial(name)
        if not read_only:  # another window on the trial, or a writer of one of its bones: read-only
            st.hold_lock(f"results/{name}/{WINDOW_LOCK}",
                         purpose=f"trial {name!r} of study {folder} (edited in another window)")
            for bone in tr.bones:  # free now; not kept: a batch's tasks take it between our edits
                st.lock_journal(name, bone)
                st.unlock_journal(name, bone)
        rig = tr.rig()

        @lru_cache(maxsize=64)
        def frame(view: int, t: int):
            """One view's image of trial frame ``t``: a damaged file in one view leaves the other's
            readable (read in pairs, one bad TIFF failed both panes)."""
            seq = tr.sequences()
            return seq.views[view][seq.view_frames(t)[view]]

        model = ViewerModel(rig, tr.n_frames, frame_source=frame)
        for bone in tr.bones:
            poses, recorded = _fill(tr.poses(bone))
            i = model.add_bone(bone, st.bone_volume(bone), poses)
            model.layers[i].keyframes = recorded
        model.dirty = False
        recovered = False
        if not read_only:  # the trial's window lock is ours: so is its marker
            results = folder / "results"
            (results / name).mkdir(parents=True, exist_ok=True)
            marker = results / name / MARKER
            recovered = marker.exists()
            legacy = results / MARKER  # an older version's study-wide marker: a crash, said once
            if legacy.exists() and not _older_window_open(st, name):
                recovered = True
                with contextlib.suppress(OSError):
                    legacy.unlink()
            marker.write_text("open\n", encoding="utf-8")

            session_ref: list[StudySession] = []

            def record(bone: int, frame: int) -> None:
                if session_ref and not session_ref[0].recording:
                    return
                s, frame = session_ref[0], int(frame)
                name, pose = model.layers[bone].name, model.pose(bone, frame)

                def done() -> None:
                    if s.saved is not None:
                        s.saved(name, frame, pose)

                s.hand_edit(name, lambda: tr.record_pose(name, frame, pose), key=("pose", frame), done=done)

            def record_all(bone: int) -> None:
                if session_ref and not session_ref[0].recording:
                    return
                layer = model.layers[bone]

                def write() -> None:
                    for f in range(model.n_frames):
                        tr.record_pose(layer.name, f, layer.poses[f])

                session_ref[0].hand_edit(layer.name, write, key=("all",))

            model.pose_changed.connect(record)
            model.trajectory_changed.connect(record_all)
            session = StudySession(st, name, model, recovered=recovered, writable=True)
            session_ref.append(session)
            return session
        return StudySession(st, name, model, recovered=False, writable=False)
    except BaseException:
        st.close()
        raise
