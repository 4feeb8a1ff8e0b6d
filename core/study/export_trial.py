"""Export a study trial's poses in the peers' and downstream formats.

:func:`export_trial` writes the trial's ``T_lab_from_bone`` journal poses (NaN where a bone has
no pose) as one of

* ``tra`` — Autoscoper ``.tra`` in Autoscoper's volume frame (:mod:`core.io.autoscoper_pose`;
  one 16-value block per bone, row order, commas), for the bones' TIFF stacks;
* ``xromm-csv`` — XMALab's rigid-body transformation CSV (Maya's XROMM import), body = bone
  frame (the CT's physical frame);
* ``tfm`` — one ITK ``.tfm`` per bone (``<bone>.tfm`` in the ``out`` folder) of one frame, the
  lab taken as Slicer's world (RAS) and the pose as the bone's "to parent" transform;
* ``jts`` — one JointTrack ``<bone>.jts`` per bone in the camera frame of ``camera``;
* ``c3d`` — C3D with the bones' 4x4 rotations and axis points (needs ezc3d);
* ``mot`` — OpenSim coordinates of every bone (Z-X-Y angles, metres);
* ``trc`` — OpenSim markers: each bone's origin and points 10 mm along its axes;
* ``jcs`` — Grood–Suntay angles of the default joints (:func:`core.tracking.jcs.default_joints`)
  with principal-axes anatomical frames of the bones' voxels above 200 HU.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

__all__ = ["FORMATS", "export_trial"]

FORMATS = ("tra", "xromm-csv", "tfm", "jts", "c3d", "mot", "trc", "jcs")


def _volume_flip(study, bone: str):
    imp = study.settings.get("imported_from") or {}
    return tuple(imp.get("volumes", {}).get(bone, {}).get("flip", (0, 0, 0)))


def export_trial(study, trial: str, fmt: str, out: str | os.PathLike, *, bones=None, rate: float = 100.0,
                 frame: int | None = None, camera: int = 0, poses=None) -> list[Path]:
    """Write ``trial``'s poses as ``fmt`` to ``out`` (a file, or a folder for ``tfm``/``jts``).

    ``poses``: bone -> ``(n_frames, 4, 4)`` written instead of the recorded ones (e.g. the smoothed
    poses of :func:`core.tracking.smoothing_trial.smoothed_poses`). Returns the paths written.
    """
    if fmt not in FORMATS:
        raise ValueError(f"fmt: expected one of {', '.join(FORMATS)}, got {fmt!r}")
    if not rate > 0:
        raise ValueError(f"rate: expected a positive frame rate, got {rate!r}")
    tr = study.trial(trial)
    names = tuple(bones) if bones else tr.bones
    if not names:
        raise ValueError(f"bones: trial {trial!r} has no bones")
    P = np.stack([tr.poses(b) if poses is None else np.asarray(poses[b], float) for b in names],
                 axis=1)  # (n, nb, 4, 4)
    n = len(P)
    out = Path(out)
    frames = np.arange(n) + tr.frame_offset
    if fmt in ("tfm", "jts"):
        out.mkdir(parents=True, exist_ok=True)
    if fmt == "tra":
        from ..io.autoscoper_pose import tra_from_lab_from_bone
        from ..io.autoscoper_tra import write_tra

        T = np.stack([tra_from_lab_from_bone(P[:, k], study.bone_volume(b), _volume_flip(study, b))
                      for k, b in enumerate(names)], axis=1)
        write_tra(out, T)
        return [out]
    if fmt == "xromm-csv":
        from ..io.rigid_body_csv import write_rigid_body_csv

        write_rigid_body_csv(out, names, P, frames=frames + 1)
        return [out]
    if fmt == "tfm":
        from ..io.slicer_tfm import write_slicer_tfm

        tracked = np.flatnonzero(~np.isnan(P).any(axis=(1, 2, 3)))
        f = int(tracked[0]) if frame is None and len(tracked) else frame
        if f is None or not 0 <= f < n:
            raise ValueError(f"frame: expected a frame in [0, {n}) where every bone has a pose, got {f}")
        paths = []
        for k, b in enumerate(names):
            if np.isnan(P[f, k]).any():
                raise ValueError(f"frame: bone {b!r} has no pose at frame {f}")
            p = out / f"{b}.tfm"
            write_slicer_tfm(p, P[f, k])
            paths.append(p)
        return paths
    if fmt == "jts":
        from ..io.jointtrack import lab_to_jts, write_jts

        rig = tr.rig()
        if not 0 <= camera < len(rig):
            raise ValueError(f"camera: expected 0..{len(rig) - 1}, got {camera}")
        paths = []
        for k, b in enumerate(names):
            p = out / f"{b}.jts"
            write_jts(p, lab_to_jts(P[:, k], rig[camera]))
            paths.append(p)
        return paths
    if fmt == "c3d":
        from ..io.c3d import write_c3d

        write_c3d(out, names, P, rate=rate)
        return [out]
    if fmt == "mot":
        from ..io.opensim import bone_kinematics_table, write_mot

        write_mot(out, bone_kinematics_table(names, P, (frames - frames[0]) / rate, name=trial))
        return [out]
    if fmt == "trc":
        from ..io.opensim import MarkerTable, bone_markers, write_trc

        pts = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 10]], float)
        X = np.concatenate([bone_markers(P[:, k], pts) for k in range(len(names))], axis=1)
        labels = tuple(f"{b}_{s}" for b in names for s in "OXYZ")
        write_trc(out, MarkerTable(labels, X, rate, "mm", frames + 1))
        return [out]
    # jcs
    from ..io.jcs_csv import jcs_table, write_jcs_csv
    from ..tracking.jcs import anatomical_frames, default_joints

    joints = default_joints(names)
    if not joints:
        raise ValueError("bones: the JCS needs at least two bones")
    pts = {}
    for b in names:
        vol = study.bone_volume(b)
        k, j, i = np.nonzero(vol.data >= 200.0)
        step = max(1, len(k) // 20000)
        pts[b] = vol.index_to_physical(np.stack([i, j, k], 1)[::step].astype(float))
    table = jcs_table({b: P[:, x] for x, b in enumerate(names)}, joints, frames=frames, rate=rate,
                      anatomical=anatomical_frames(pts))
    write_jcs_csv(out, table)
    return [out]

