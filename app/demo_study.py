"""Open a study folder written by ``talus demo`` as a :class:`~app.model.ViewerModel`.

The folder's ``summary.json`` lists its files: MayaCam camera files (``rig/``), bone volumes as
TIFF + JSON geometry (``volumes/``), 12-bit frames per camera (``frames/camXX/``) and the
ground-truth poses (``poses/all.npy``). Frames are read lazily, one at a time, and cached.
Each bone starts at its true pose of frame 0 for every frame (a tracking starting point); the
ground truth stays available as :attr:`DemoStudy.truth` for comparisons.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import tifffile

from core.geometry.camera import Rig
from core.geometry.mayacam import rig_from_mayacam
from core.io import read_tiff_volume

from .model import ViewerModel

__all__ = ["DemoStudy", "open_demo_study"]

_SOFT_TISSUE = ("soft_foot", "soft_shank")


@dataclass
class DemoStudy:
    folder: Path
    model: ViewerModel
    truth: np.ndarray  # (n_bones, n_frames, 4, 4) T_lab_from_bone
    flatfields: list[np.ndarray | None]


def _summary(folder: Path) -> dict:
    path = folder / "summary.json"
    if not path.is_file():
        raise ValueError(f"folder: {folder} has no summary.json (expected a `talus demo` study)")
    try:
        s = json.loads(path.read_text(encoding="utf-8"))
    except ValueError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from exc
    if s.get("format") != "talus-synthetic-study":
        raise ValueError(f"{path}: format {s.get('format')!r}, expected 'talus-synthetic-study'")
    return s


def open_demo_study(folder: str | Path) -> DemoStudy:
    """Load a demo study folder; raises ``ValueError`` naming any missing or invalid file."""
    folder = Path(folder).expanduser()
    s = _summary(folder)
    files = s.get("files", {})
    missing = [p for group in ("rig", "volumes", "poses") for p in files.get(group, [])
               if not (folder / p).is_file()]
    frames = {cam: [folder / p for p in paths] for cam, paths in sorted(files["frames"].items())}
    missing += [str(p.relative_to(folder)) for paths in frames.values() for p in paths
                if not p.is_file()]
    if missing:
        raise ValueError(f"folder: {folder} is missing {len(missing)} file(s): {missing[:5]}")
    cams = sorted(folder / p for p in files["rig"] if p.endswith(".txt"))
    rig: Rig = rig_from_mayacam(cams)
    rig_json = folder / "rig" / "rig.json"
    if rig_json.is_file():  # MayaCam files carry no pixel size; the demo's rig.json does
        sizes = {c.get("name"): c.get("pixel_size_mm")
                 for c in json.loads(rig_json.read_text(encoding="utf-8")).get("cameras", [])}
        if all(sizes.get(c.name) for c in rig):
            rig = Rig(tuple(c.__class__(c.K, c.R, c.t, c.width, c.height,
                                        pixel_size=sizes[c.name], name=c.name) for c in rig))
    names = [n for n in s["bones"] if n not in _SOFT_TISSUE]
    n_frames = int(s.get("frames_written", s["n_frames"]))
    if n_frames < 1:
        raise ValueError(f"folder: {folder} holds no frames")
    views = [frames[c.name] for c in rig]

    @lru_cache(maxsize=64)
    def frame(view: int, index: int) -> np.ndarray:
        return tifffile.imread(views[view][index])

    model = ViewerModel(rig, n_frames, frame_source=frame)
    truth = np.load(folder / "poses" / "all.npy")
    all_names = list(s["bones"])
    kept = []
    for name in names:
        meta = json.loads((folder / "volumes" / f"{name}.json").read_text(encoding="utf-8"))
        vol = read_tiff_volume(folder / "volumes" / f"{name}.tif", meta["spacing"],
                               origin=meta["origin"], direction=meta["direction"],
                               units=meta.get("units", "HU"), name=name)
        k = all_names.index(name)
        kept.append(truth[k, :n_frames])
        model.add_bone(name, vol, np.repeat(truth[k, :1], n_frames, axis=0))
    model.dirty = False
    flats = []
    for cam in rig:
        p = folder / "imaging" / f"flatfield_{cam.name}.tif"
        flats.append(tifffile.imread(p).astype(np.float32) if p.is_file() else None)
    return DemoStudy(folder, model, np.stack(kept), flats)
