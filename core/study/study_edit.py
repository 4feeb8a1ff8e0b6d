"""Editing a study's manifest (:class:`~core.study.Study`): references to calibrations, volumes,
bones and trials, settings, and relocating moved files. Each edit is validated, then saved as one
read-modify-write under the manifest's short lock, merged entry by entry with what other processes
saved meanwhile (:func:`_merge`)."""

from __future__ import annotations

import copy
import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from .errors import StudyError
from .manifest import read_manifest, store_path, write_manifest
from .schema import NAME_RE

_TIFF = (".tif", ".tiff")
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


def entry_name(text: str, taken: set[str], *, fallback: str) -> str:
    """A valid entry name made of ``text`` (other characters become ``_``, at most 60 kept;
    ``fallback`` when nothing is left), with ``-2``, ``-3``, ... appended until it is not in
    ``taken``; it is added to ``taken``. Importers name what they find with it."""
    base = re.sub(r"[^A-Za-z0-9_.-]", "_", text).lstrip("_.-")[:60] or fallback
    name, k = base, 2
    while name in taken:
        name, k = f"{base}-{k}", k + 1
    taken.add(name)
    return name


class StudyEdits:
    """The editing methods of :class:`~core.study.Study` (which holds the folder, the manifest
    ``_doc``, the mode and the manifest's lock)."""

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
