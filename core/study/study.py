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
import re
from collections.abc import Sequence
from pathlib import Path
from types import MappingProxyType
from typing import Any

from ..io.atomic import FileLock, atomic_write, atomic_write_json, remove_stale_temporaries
from .errors import StudyError
from .manifest import new_manifest, read_manifest, resolve_path, store_path, write_manifest
from .schema import MANIFEST_NAME, NAME_RE

__all__ = ["Study"]

LOCK_NAME = ".talus.lock"  # the manifest's
MANIFEST_LOCK_S = 30.0  # how long a manifest update waits for another process's update
STALE_TEMP_S = 600.0  # temporaries of crashed writes older than this are removed on a write open
_TIFF = (".tif", ".tiff")


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


_SECTIONS = ("calibrations", "volumes", "bones", "trials", "settings")


def _merge(base: dict, mine: dict, theirs: dict) -> dict:
    """``theirs`` (the manifest on disk now) with the changes from ``base`` to ``mine`` (this
    handle's edits) applied entry by entry: an added, replaced or removed calibration, volume,
    bone, trial or setting, or a changed top-level value. Another process's edits of other
    entries are kept; for one entry edited by both, the later save wins."""
    out = copy.deepcopy(theirs)
    for key in set(base) | set(mine):
        if key == "modified":
            continue
        b, m = base.get(key), mine.get(key)
        if key in _SECTIONS and isinstance(m, dict) and isinstance(out.get(key), dict):
            b = b if isinstance(b, dict) else {}
            for k in set(b) | set(m):
                if k not in m:
                    out[key].pop(k, None)
                elif k not in b or b[k] != m[k]:
                    out[key][k] = copy.deepcopy(m[k])
        elif key not in mine:
            out.pop(key, None)
        elif key not in base or b != m:
            out[key] = copy.deepcopy(m)
    return out


def _check_name(name: str, what: str) -> str:
    if not isinstance(name, str) or not NAME_RE.fullmatch(name):
        raise ValueError(
            f"{what}: expected 1-64 letters, digits, '_', '-', '.' starting with a letter or digit, "
            f"got {name!r}"
        )
    return name


class Study:
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
        for lock in locks.values():
            lock.release()
        self._mode = "closed"

    def lock_journal(self, trial: str, bone: str) -> None:
        """Lock the pose journal of ``bone`` in ``trial`` for this handle until :meth:`close`
        (idempotent). The first write to a journal does it too; trackers call it before they
        start, so a second writer of that bone is refused at once.

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
        if path in self._journal_locks:
            return
        path.parent.mkdir(parents=True, exist_ok=True)
        lock = FileLock(path.with_name(f".{bone}.lock"),
                        purpose=f"bone {bone!r} of trial {trial!r} in study {self._folder}")
        self._journal_locks[path] = lock.acquire()

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

    def relocate(self, missing: str | os.PathLike, new_path: str | os.PathLike) -> int:
        """Point every reference to the file ``missing`` (as reported by
        :meth:`missing_files`) at ``new_path`` instead (which must exist); returns how many
        references changed. The manifest is saved atomically."""
        self._require_write()
        old = Path(missing).expanduser().absolute()
        new = self._existing(new_path, "new_path")
        doc = copy.deepcopy(self._doc)
        count = 0

        def swap(stored: str) -> str:
            nonlocal count
            if self.path(stored).absolute() == old:
                count += 1
                return new
            return stored

        for c in doc["calibrations"].values():
            c["cameras"] = [swap(p) for p in c["cameras"]]
        for v in doc["volumes"].values():
            v["path"] = swap(v["path"])
            if v.get("labels"):
                v["labels"] = swap(v["labels"])
        for t in doc["trials"].values():
            for view in t["views"]:
                view["path"] = swap(view["path"])
        if count == 0:
            raise StudyError(f"missing: {old} is not referenced by this study")
        self._commit(doc)
        self._volume_cache.clear()
        return count

    # ------------------------------------------------------------------ editing
    def _require_write(self) -> None:
        if self._mode != "w":
            state = "read-only" if self._mode == "r" else "no more"
            raise StudyError(f'{self._folder}: study is open {state}; open it with mode="w" to change it')

    def _commit(self, doc: dict) -> None:
        """Save ``doc`` (this handle's manifest with its edits) as one read-modify-write under
        the manifest's short lock: the edits are merged into the manifest on disk, which other
        processes may have changed since (:func:`_merge`)."""
        with self._manifest_lock(self._folder):
            theirs, _ = read_manifest(self._folder)
            merged = _merge(self._doc, doc, theirs)
            write_manifest(self._folder, merged)
        self._doc = merged

    def _existing(self, path, what: str) -> str:
        p = Path(path).expanduser()
        if not p.is_absolute():
            p = Path.cwd() / p
        if not p.exists():
            raise StudyError(f"{what}: referenced file {p} does not exist")
        return store_path(self._folder, p)

    def add_calibration(
        self, name: str, cameras: Sequence[str | os.PathLike], *, pixel_size_mm: float | None = None
    ) -> None:
        """Reference one MayaCam (1.0/2.0) file per camera under ``name`` (files are read to check them)."""
        from ..geometry.mayacam import read_mayacam

        self._require_write()
        _check_name(name, "name")
        if isinstance(cameras, str | os.PathLike) or len(cameras) < 1:
            raise ValueError(f"cameras: expected a sequence of camera file paths, got {cameras!r}")
        stored = [self._existing(p, f"cameras[{i}]") for i, p in enumerate(cameras)]
        for s in stored:
            read_mayacam(self.path(s), pixel_size=pixel_size_mm)
        doc = copy.deepcopy(self._doc)
        doc["calibrations"][name] = {"format": "mayacam", "cameras": stored, "pixel_size_mm": pixel_size_mm}
        self._commit(doc)

    def add_volume(
        self,
        name: str,
        path: str | os.PathLike,
        *,
        voxel_size_mm: Sequence[float] | None = None,
        hu_offset: float = 0.0,
        labels: str | os.PathLike | None = None,
    ) -> None:
        """Reference a CT (DICOM folder, NIfTI, NRRD, MHA, or TIFF stack + ``voxel_size_mm``)."""
        self._require_write()
        _check_name(name, "name")
        stored = self._existing(path, "path")
        if Path(stored).suffix.lower() in _TIFF and voxel_size_mm is None:
            raise ValueError(
                f"voxel_size_mm: required for the TIFF volume {path} (TIFF stores no voxel size)"
            )
        entry = {
            "path": stored,
            "voxel_size_mm": None if voxel_size_mm is None else [float(v) for v in voxel_size_mm],
            "hu_offset": float(hu_offset),
            "labels": None if labels is None else self._existing(labels, "labels"),
        }
        doc = copy.deepcopy(self._doc)
        doc["volumes"][name] = entry
        self._commit(doc)

    def add_bone(self, name: str, *, volume: str, label: int | None = None, margin_mm: float = 5.0) -> None:
        """A bone: the whole ``volume`` (``label=None``) or its label-map region plus ``margin_mm``."""
        self._require_write()
        _check_name(name, "name")
        vol = self._doc["volumes"].get(volume)
        if vol is None:
            raise StudyError(f"volume: no volume named {volume!r} (have {list(self._doc['volumes'])})")
        if label is not None and not vol.get("labels"):
            raise StudyError(f"label: volume {volume!r} has no label map; add it with labels=...")
        doc = copy.deepcopy(self._doc)
        doc["bones"][name] = {"volume": volume, "label": label, "margin_mm": float(margin_mm)}
        self._commit(doc)
        self._volume_cache.pop(name, None)

    def add_trial(
        self,
        name: str,
        views: Sequence[str | os.PathLike],
        *,
        calibration: str,
        frame_offset: int = 0,
        bones: Sequence[str] = (),
        bit_depth: int | None = None,
    ) -> None:
        """Reference one fluoro sequence per camera of ``calibration``.

        The sequences are opened to check them: each must be readable, match its camera's image
        size, and the views must hold the same number of frames (see
        :class:`core.io.TwoViewSequence`).
        """
        from ..io.paired import TwoViewSequence
        from ..io.sequences import open_sequence

        self._require_write()
        _check_name(name, "name")
        cal = self._calibration_entry(calibration)
        if isinstance(views, str | os.PathLike) or len(views) != len(cal["cameras"]):
            n = len(cal["cameras"])
            raise ValueError(f"views: expected {n} sequence paths (one per camera), got {views!r}")
        for b in bones:
            if b not in self._doc["bones"]:
                raise StudyError(f"bones: no bone named {b!r} (have {list(self.bones)})")
        stored = [self._existing(p, f"views[{i}]") for i, p in enumerate(views)]
        rig = self.rig(calibration)
        seqs = [open_sequence(self.path(s), bit_depth=bit_depth) for s in stored]
        try:
            for i, (seq, cam) in enumerate(zip(seqs, rig, strict=True)):
                if seq.frame_shape != cam.image_shape:
                    raise StudyError(
                        f"views[{i}]: {seq.path} has frames of {seq.frame_shape[1]}x{seq.frame_shape[0]} "
                        f"pixels but camera {cam.name!r} expects {cam.width}x{cam.height}"
                    )
            if len(seqs) == 2:
                TwoViewSequence(seqs[0], seqs[1], offset=frame_offset)
        finally:
            for s in seqs:
                s.close()
        doc = copy.deepcopy(self._doc)
        doc["trials"][name] = {
            "calibration": calibration,
            "views": [{"path": s, "bit_depth": bit_depth} for s in stored],
            "frame_offset": int(frame_offset),
            "bones": list(bones),
        }
        self._commit(doc)

    def update_settings(self, **values: Any) -> None:
        """Merge ``values`` (JSON-serialisable) into the settings object."""
        self._require_write()
        doc = copy.deepcopy(self._doc)
        doc["settings"].update(values)
        self._commit(doc)

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

    # ------------------------------------------------------------------ reports
    def _report_path(self, kind: str, name: str) -> Path:
        _check_name(kind, "kind")
        _check_name(name, "name")
        p = self._folder / "results" / "reports" / kind / f"{name}.json"
        return self.inside(p)

    def inside(self, path: str | os.PathLike) -> Path:
        """``path`` if it (following any symbolic links) lies inside the study folder, else
        :class:`StudyError`; writers of study files check their destination with it."""
        p = Path(path)
        p = p if p.is_absolute() else self._folder / p
        root = self._folder.resolve()
        if not p.resolve().is_relative_to(root):
            raise StudyError(
                f"{p}: leads to {p.resolve()}, outside the study folder {root} (a symbolic link?); "
                "expected a path inside the study", path=p, expected="a path inside the study",
            )
        return p

    def write_report(self, kind: str, name: str, data: dict) -> Path:
        """Save a JSON report (e.g. ``kind="calibration"``) atomically; NaN must be given as None."""
        self._require_write()
        if not isinstance(data, dict):
            raise ValueError(f"data: expected a dict, got {type(data).__name__}")
        p = self._report_path(kind, name)
        p.parent.mkdir(parents=True, exist_ok=True)
        lock = FileLock(p.with_name(f".{name}.lock"), purpose=f"report {p}")
        with lock.acquire(timeout=MANIFEST_LOCK_S):
            atomic_write_json(p, data)
        return p

    def read_report(self, kind: str, name: str) -> dict:
        """A report written by :meth:`write_report`."""
        import json

        p = self._report_path(kind, name)
        if not p.is_file():
            raise StudyError(f"{p}: no {kind!r} report named {name!r}")
        try:
            return json.loads(p.read_text(encoding="utf-8"))
        except (ValueError, UnicodeDecodeError) as exc:
            raise StudyError(f"{p}: expected a JSON report ({exc})") from None

    def report_names(self, kind: str) -> tuple[str, ...]:
        folder = self._folder / "results" / "reports" / _check_name(kind, "kind")
        return tuple(sorted(p.stem for p in folder.glob("*.json") if not re.match(r"^\.", p.name)))
