"""Open a peer's project as a Talus study that references the original files.

:func:`import_project` dispatches on the project file:

* an Autoscoper trial configuration (``.cfg``, versions 1.0-1.2,
  :func:`core.io.autoscoper.read_autoscoper_cfg`) becomes a study with one calibration (its
  MayaCam files), one volume and one whole-volume bone per ``VolumeFile`` (named after the file,
  e.g. ``rad_dcm_cropped``), and one trial whose views are the ``CameraRootDir`` folders. Poses
  from an Autoscoper ``.tra`` (``tra=``) are converted from Autoscoper's volume frame to
  ``T_lab_from_bone`` (:mod:`core.io.autoscoper_pose`) and recorded as keyframes, so ``talus
  track`` starts from them.

Nothing is copied: the study's manifest points at the project's files (``Study.relocate`` fixes
moved ones). What the study has no place for (render resolution, optimisation offsets, mesh
files, flips) is kept under ``settings["imported_from"]``.

Autoscoper's volumes are unsigned 16-bit stacks with no HU scale; ``hu_offset`` (default -1024:
CT numbers stored as HU + 1024, as in Autoscoper's sample data) converts them.
"""

from __future__ import annotations

import os
from pathlib import Path

from .errors import StudyError
from .study_edit import entry_name

__all__ = ["import_autoscoper", "import_project"]


def import_autoscoper(
    cfg: str | os.PathLike,
    out: str | os.PathLike,
    *,
    name: str | None = None,
    trial: str = "trial",
    tra: str | os.PathLike | None = None,
    hu_offset: float = -1024.0,
):
    """Create a study in ``out`` from the Autoscoper configuration ``cfg`` (see the module docs).

    Returns the open (writable) :class:`~core.study.Study`; close it when done.

    Raises
    ------
    FileError
        The ``.cfg`` or ``.tra`` is malformed (naming the file and line).
    StudyError
        ``out`` already holds a study, a referenced file is missing, the frames don't match the
        cameras, or a flipped volume has poses (its frame is a mirror image of the stack's).
    """
    import numpy as np

    from ..io.autoscoper import read_autoscoper_cfg, read_tra
    from ..io.autoscoper_pose import lab_from_bone_from_tra
    from ..io.sequences import open_sequence
    from .study import Study

    cfg = Path(cfg).absolute()
    t = read_autoscoper_cfg(cfg)
    poses = None
    if tra is not None:
        poses = read_tra(tra, n_volumes=len(t.volumes))
    study = Study.create(out, name=name or cfg.stem)
    try:
        study.add_calibration("autoscoper", list(t.cameras))
        taken: set[str] = set()
        bones = []
        for v in t.volumes:
            b = entry_name(Path(v.path).stem, taken, fallback="volume")
            study.add_volume(b, v.path, voxel_size_mm=v.voxel_size, hu_offset=hu_offset)
            study.add_bone(b, volume=b)
            bones.append(b)
        bits = set()
        for d in t.camera_root_dirs:  # the stored bit depth (8-bit radiographs are common)
            seq = open_sequence(d)
            try:
                bits.add(int(seq.bit_depth))
            finally:
                seq.close()
        study.add_trial(trial, list(t.camera_root_dirs), calibration="autoscoper", bones=bones,
                        bit_depth=bits.pop() if len(bits) == 1 else None)
        meshes = [None if getattr(v, "mesh", None) is None else str(v.mesh) for v in t.volumes]
        study.update_settings(imported_from={
            "format": "autoscoper-cfg",
            "path": str(cfg),
            "version": ".".join(map(str, t.version)),
            "render_resolution": list(t.render_resolution),
            "optimization_offsets": list(t.optimization_offsets),
            "volumes": {b: {"flip": [int(f) for f in v.flip], "mesh": m}
                        for b, v, m in zip(bones, t.volumes, meshes, strict=True)},
        })
        if poses is not None:
            tr = study.trial(trial)
            if len(poses) > tr.n_frames:
                raise StudyError(f"tra: {tra} has {len(poses)} frames, the trial {tr.n_frames}")
            for k, (b, v) in enumerate(zip(bones, t.volumes, strict=True)):
                tracked = ~np.isnan(poses[:, k]).any(axis=(1, 2))
                if not tracked.any():
                    continue
                if any(v.flip):
                    flips = " ".join(str(int(f)) for f in v.flip)
                    raise StudyError(
                        f"tra: volume {v.path} is flipped (VolumeFlip {flips}): its Autoscoper frame "
                        "is a mirror image of the stack and its poses cannot be kept"
                    )
                vol = study.bone_volume(b)
                for f in np.flatnonzero(tracked):
                    T = lab_from_bone_from_tra(poses[f, k], vol, v.flip, v.voxel_size)
                    tr.record_pose(b, int(f), T)
    except BaseException:
        study.close()
        raise
    return study


def import_project(path: str | os.PathLike, out: str | os.PathLike, **options):
    """Create a study in ``out`` from a peer's project file: an Autoscoper ``.cfg`` (see the
    module docs) or an XMALab ``.xma`` (:func:`core.study.import_xma.import_xma`)."""
    p = Path(path)
    if p.suffix.lower() == ".cfg":
        return import_autoscoper(p, out, **options)
    if p.suffix.lower() == ".xma":
        from .import_xma import import_xma

        return import_xma(p, out, **options)
    raise ValueError(f"path: expected an Autoscoper trial configuration (.cfg) or an XMALab project (.xma), "
                     f"got {p}")
