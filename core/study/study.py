"""The :class:`Study` façade: one folder holding a lab session's references and results.

Layout of a study folder::

    study.json                        manifest (schema: core.study.schema), written atomically
    .talus.lock                       lock file of the manifest (held for one update)
    results/<trial>/poses/<bone>.jsonl  tracking results, appended frame by frame
    results/<trial>/poses/.<bone>.lock  lock file of that journal (held by its writer)
    results/reports/<kind>/<name>.json  calibration reports and other summaries (atomic)

Raw data (fluoro sequences, camera files, CT) is *referenced*, not copied.

Writers lock what they write, not the whole study, so several processes may have one study open
for writing (e.g. ``talus batch`` tracking different trials or bones of it side by side):

* a bone's pose journal is locked by the first write to it (or :meth:`Study.lock_journal`,
  which :func:`core.tracking.from_study.track_study` calls before it starts) and stays locked
  until the study is closed; a second process writing that bone gets
  :class:`~core.io.atomic.LockedError` naming the bone and its holder;
* the manifest is changed under a short lock as one read-modify-write: the file is read again,
  this handle's changes (the entries it added, replaced or removed) are merged into it and it is
  saved atomically, so edits of two processes do not overwrite each other;
* a report is written under its own short lock (atomic rename).

Read-only opens need no lock (every write is an atomic rename or a checksummed append, so
readers never see half-written files).

The editing methods (and the merge of concurrent edits) live in :mod:`core.study.study_edit`, the
reports in :mod:`core.study.study_reports`; :class:`Study` inherits both.

Example
-------
>>> with Study.create("subject07") as st:                       # doctest: +SKIP
...     st.add_calibration("day1", ["calib/cam1.txt", "calib/cam2.txt"])
...     st.add_volume("foot", "ct/foot.nii.gz", labels="ct/labels.nii.gz")
...     st.add_bone("talus", volume="foot", label=3)
...     st.add_trial("walk01", ["raw/c1.cine", "raw/c2.cine"], calibration="day1", bones=["talus"])
...     st.trial("walk01").record_pose("talus", 0, T, score=0.8)
"""

from __future__ import annotations

import copy
import os
from pathlib import Path
from types import MappingProxyType
from typing import Any

from ..io.atomic import FileLock, atomic_write, remove_stale_temporaries
from .errors import StudyError
from .manifest import new_manifest, read_manifest, resolve_path, write_manifest
from .schema import MANIFEST_NAME
from .study_edit import StudyEdits
from .study_reports import StudyReports

__all__ = ["Study"]

LOCK_NAME = ".talus.lock"  # the manifest's
MANIFEST_LOCK_S = 30.0  # how long a manifest update waits for another process's update
STALE_TEMP_S = 600.0  # temporaries of crashed writes older than this are removed on a write open


def _check_no_escape(folder: Path) -> None:
    """Refuse a study whose ``results/`` (or anything below it) is a symbolic link leading out
    of the study folder: results would be written, and read, somewhere else."""
    root = folder.resolve()
    results = folder / "results"
    if not results.is_symlink() and not results.exists():
        return
    todo = [results]
    while todo:
        p = todo.pop()
        if p.is_symlink():
            target = p.resolve()
            if not target.is_relative_to(root):
                raise StudyError(
                    f"{p}: is a symbolic link to {target}, outside the study folder {root}; expected "
                    "the study's results inside it (replace the link by a folder, or move the study)",
                    path=p, expected="a folder inside the study",
                )
        if p.is_dir() and not p.is_symlink():
            todo.extend(p.iterdir())


class Study(StudyEdits, StudyReports):
    """A study folder opened read-only (``mode="r"``) or for writing (``mode="w"``).

    Use :meth:`create` or :meth:`open`; close it (or use ``with``) to release the journal locks
    it holds. Every editing method validates and saves the manifest atomically (merged with
    other writers' changes under the manifest's short lock) before returning.
    """

    def __init__(self, folder: Path, doc: dict, mode: str, lock: FileLock | None, from_version: int):
        self._folder = folder
        self._doc = doc
        self._mode = mode
        self._lock = lock  # unused (no study-wide lock); kept for the constructor's signature
        self._journal_locks: dict[Path, FileLock] = {}
        self._held_locks: list[FileLock] = []  # hold_lock's
        self._from_version = from_version
        self._trials: dict[str, Any] = {}
        self._volume_cache: dict[str, Any] = {}

    # ------------------------------------------------------------------ opening
    @classmethod
    def create(cls, folder: str | os.PathLike, *, name: str | None = None) -> Study:
        """Create a new, empty study in ``folder`` (created if needed) and open it for writing.

        Raises
        ------
        StudyError
            If ``folder`` already holds a study.
        """
        folder = Path(folder).absolute()
        if (folder / MANIFEST_NAME).exists():
            raise StudyError(f"{folder}: already holds a study ({MANIFEST_NAME}); use Study.open")
        folder.mkdir(parents=True, exist_ok=True)
        with cls._manifest_lock(folder):
            if (folder / MANIFEST_NAME).exists():  # created meanwhile by another process
                raise StudyError(f"{folder}: already holds a study ({MANIFEST_NAME}); use Study.open")
            _check_no_escape(folder)
            doc = new_manifest(name or folder.name)
            write_manifest(folder, doc, touch=False)
        return cls(folder, doc, "w", None, doc["schema_version"])

    @staticmethod
    def _manifest_lock(folder: Path) -> FileLock:
        """The manifest's short lock (taken with a wait of up to :data:`MANIFEST_LOCK_S`)."""
        lock = FileLock(folder / LOCK_NAME, purpose=f"the manifest of study {folder}")
        return lock.acquire(timeout=MANIFEST_LOCK_S)

    @classmethod
    def open(cls, folder: str | os.PathLike, *, mode: str = "r", check_files: bool = True) -> Study:
        """Open an existing study.

        Parameters
        ----------
        folder : str or os.PathLike
            The study folder (holding ``study.json``).
        mode : {"r", "w"}
            Read-only, or for writing (several processes may; each locks the bone journals it
            writes, see the module notes). A manifest of an older
            schema version is migrated; in ``"w"`` mode the migrated manifest is saved (the old
            one is kept as ``study.json.v<N>.bak``).
        check_files : bool
            Verify that every referenced file exists (else :class:`StudyError` naming it).

        Raises
        ------
        StudyError
            Not a study, corrupt or future-version manifest, or a missing referenced file.
        LockedError
            ``mode="w"`` and another process held the manifest's short lock for
            :data:`MANIFEST_LOCK_S` seconds (an older manifest is being migrated).

        Notes
        -----
        Opening for writing removes temporary files of crashed atomic writes
        (``.study.json.*.tmp`` and the like) older than :data:`STALE_TEMP_S` seconds. A study
        whose ``results/`` (or a folder or file below it) is a symbolic link to outside the study
        folder is refused.
        """
        if mode not in ("r", "w"):
            raise ValueError(f'mode: expected "r" or "w", got {mode!r}')
        folder = Path(folder).absolute()
        if not folder.is_dir():
            what = "is not a folder" if folder.exists() else "does not exist"
            raise StudyError(f"{folder}: study folder {what}", path=folder, expected="a Talus study folder")
        if not (folder / MANIFEST_NAME).is_file():
            raise StudyError(
                f"{folder}: not a Talus study folder (expected a manifest file {folder / MANIFEST_NAME})",
                path=folder, expected="a Talus study folder",
            )
        _check_no_escape(folder)
        if mode == "w":  # only temporaries older than any live write: safe beside other writers
            remove_stale_temporaries(folder, older_than_s=STALE_TEMP_S)
        doc, version = read_manifest(folder)
        study = cls(folder, doc, mode, None, version)
        if check_files:
            missing = study.missing_files()
            if missing:
                where, path = missing[0]
                more = f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""
                raise StudyError(
                    f"{folder / MANIFEST_NAME}: {where}: referenced file {path} does not exist{more}"
                )
        if mode == "w" and version < doc["schema_version"]:
            with cls._manifest_lock(folder):
                doc, version = read_manifest(folder)  # another writer may have migrated it
                if version < doc["schema_version"]:
                    old = (folder / MANIFEST_NAME).read_bytes()
                    atomic_write(folder / f"{MANIFEST_NAME}.v{version}.bak", old)
                    write_manifest(folder, doc)
                study._doc = doc
        return study

    def close(self) -> None:
        """Close open sequences and release the journal locks (idempotent)."""
        for t in self._trials.values():
            t._close()
        self._trials.clear()
        locks, self._journal_locks = self._journal_locks, {}
        for lock in [*locks.values(), *self._held_locks]:
            lock.release()
        self._held_locks = []
        self._mode = "closed"

    def hold_lock(self, relpath: str, *, purpose: str) -> None:
        """Take the lock file ``relpath`` (inside the study folder, e.g. ``results/<trial>/.window.lock``:
        the window that edits a trial) for this handle until :meth:`close`.

        Raises
        ------
        LockedError
            Another handle or process holds it (the message names ``purpose`` and the holder).
        StudyError
            The study is not open for writing.
        """
        self._require_write()
        path = self._folder / relpath
        path.parent.mkdir(parents=True, exist_ok=True)
        self._held_locks.append(FileLock(path, purpose=purpose).acquire())

    def lock_journal(self, trial: str, bone: str, *, timeout: float = 0.0, by: str = "") -> None:
        """Lock the pose journal of ``bone`` in ``trial`` for this handle until :meth:`close`
        (idempotent). The first write to a journal does it too; trackers call it before they
        start, so a second writer of that bone is refused at once (``timeout``: after waiting that
        many seconds for it, e.g. for ``talus batch``'s trajectory check, which holds a trial's
        journals for the moment it reads and rewrites them; ``by``: what holds it, recorded in the
        lock file's holder line, e.g. the window's hand edit).

        On a handle that already holds the lock, a ``by`` other than the recorded one names the
        current holder: the holder line is rewritten (``since`` now; the lock is kept), so a writer
        refused later names what writes the bone now — e.g. ``talus track`` after a script's first
        :meth:`~core.study.Trial.record_pose` took the lock unnamed — not what took it first. An empty ``by``
        (a write taking the lock on its own) keeps the recorded name.

        Raises
        ------
        LockedError
            Another process (or another handle) writes that bone; the message names the bone,
            the trial, the study and the holder.
        StudyError
            The study is not open for writing, or the trial has no such bone.
        """
        self._require_write()
        path = self.trial(trial)._journal(bone)
        held = self._journal_locks.get(path)
        if held is not None:
            if by and by != held.by:
                held.relabel(by)
            return
        path.parent.mkdir(parents=True, exist_ok=True)
        lock = FileLock(path.with_name(f".{bone}.lock"),
                        purpose=f"bone {bone!r} of trial {trial!r} in study {self._folder}", by=by)
        self._journal_locks[path] = lock.acquire(timeout=timeout)

    def unlock_journal(self, trial: str, bone: str) -> None:
        """Release this handle's lock of ``bone``'s journal in ``trial`` (idempotent), e.g. to
        let ``talus batch`` workers track that bone; this handle's next write locks it again."""
        path = self.trial(trial)._journal(bone)
        lock = self._journal_locks.pop(path, None)
        if lock is not None:
            lock.release()
        self.trial(trial)._repaired.discard(bone)  # the next write repairs the tail again

    def journal_locked(self, trial: str, bone: str) -> bool:
        """True while this handle holds the lock of ``bone``'s journal in ``trial``."""
        return self.trial(trial)._journal(bone) in self._journal_locks

    def __enter__(self) -> Study:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"Study({str(self._folder)!r}, mode={self._mode!r}, trials={list(self._doc['trials'])})"

    # ------------------------------------------------------------------ properties
    @property
    def folder(self) -> Path:
        return self._folder

    @property
    def name(self) -> str:
        return self._doc["name"]

    @property
    def mode(self) -> str:
        """``"r"``, ``"w"`` or ``"closed"``."""
        return self._mode

    @property
    def migrated_from(self) -> int:
        """Schema version of the manifest as found on disk."""
        return self._from_version

    @property
    def manifest(self) -> MappingProxyType:
        """A read-only deep copy of the manifest."""
        return MappingProxyType(copy.deepcopy(self._doc))

    @property
    def calibrations(self) -> tuple[str, ...]:
        return tuple(self._doc["calibrations"])

    @property
    def volumes(self) -> tuple[str, ...]:
        return tuple(self._doc["volumes"])

    @property
    def bones(self) -> tuple[str, ...]:
        return tuple(self._doc["bones"])

    @property
    def trials(self) -> tuple[str, ...]:
        return tuple(self._doc["trials"])

    @property
    def settings(self) -> dict:
        """A copy of the free-form settings object."""
        return copy.deepcopy(self._doc["settings"])

    def path(self, stored: str) -> Path:
        """Absolute path of a reference as stored in the manifest."""
        return resolve_path(self._folder, stored)

    def missing_files(self) -> list[tuple[str, Path]]:
        """``(manifest location, path)`` of every referenced file that does not exist."""
        out = []
        d = self._doc
        for n, c in d["calibrations"].items():
            out += [(f"calibrations[{n!r}].cameras[{i}]", p) for i, p in enumerate(c["cameras"])]
        for n, v in d["volumes"].items():
            out.append((f"volumes[{n!r}].path", v["path"]))
            if v.get("labels"):
                out.append((f"volumes[{n!r}].labels", v["labels"]))
        for n, t in d["trials"].items():
            out += [(f"trials[{n!r}].views[{i}].path", v["path"]) for i, v in enumerate(t["views"])]
        return [(w, self.path(p)) for w, p in out if not self.path(p).exists()]

    # ------------------------------------------------------------------ loading
    def _calibration_entry(self, calibration: str) -> dict:
        cal = self._doc["calibrations"].get(calibration)
        if cal is None:
            have = list(self.calibrations)
            raise StudyError(f"calibration: no calibration named {calibration!r} (have {have})")
        return cal

    def rig(self, calibration: str):
        """The :class:`~core.geometry.Rig` of a calibration."""
        from ..geometry.mayacam import rig_from_mayacam

        cal = self._calibration_entry(calibration)
        return rig_from_mayacam([self.path(p) for p in cal["cameras"]], pixel_size=cal.get("pixel_size_mm"))

    def bone_volume(self, bone: str):
        """The bone's :class:`~core.render.CTVolume` in HU (label region + margin when labelled)."""
        from ..io.ct import read_ct, split_labels

        if bone in self._volume_cache:
            return self._volume_cache[bone]
        b = self._doc["bones"].get(bone)
        if b is None:
            raise StudyError(f"bone: no bone named {bone!r} (have {list(self.bones)})")
        v = self._doc["volumes"][b["volume"]]
        vox = v.get("voxel_size_mm")
        ct = read_ct(self.path(v["path"]), voxel_size=vox, hu_offset=v.get("hu_offset", 0.0))
        if b.get("label") is None:
            vol = ct
        else:
            labels = read_ct(self.path(v["labels"]), voxel_size=v.get("voxel_size_mm"), units="label")
            vol = split_labels(ct, labels, {bone: b["label"]}, margin_mm=b.get("margin_mm", 5.0))[bone]
        self._volume_cache[bone] = vol
        return vol

    def trial(self, name: str):
        """The :class:`~core.study.Trial` called ``name``."""
        from .trial import Trial

        if name not in self._doc["trials"]:
            raise StudyError(f"trial: no trial named {name!r} (have {list(self.trials)})")
        if name not in self._trials:
            self._trials[name] = Trial(self, name)
        return self._trials[name]

    def repair(self, *, dry_run: bool = False) -> dict:
        """Salvage damaged pose journals, keeping every intact record (see :mod:`core.study.repair`)."""
        from .repair import repair_study

        return repair_study(self, dry_run=dry_run)
