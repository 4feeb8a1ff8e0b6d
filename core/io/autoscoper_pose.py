r"""Autoscoper's volume frame: ``.tra`` poses converted to and from Talus's ``T_lab_from_bone``.

An Autoscoper ``.tra`` line holds, per volume, the matrix ``CoordFrame::from_xyzypr(curve)`` that
maps Autoscoper's *volume frame* to its world frame. The world frame is the MayaCam world (the
cameras' frame), which is Talus's lab frame (:mod:`core.geometry.mayacam`). The volume frame is
not the TIFF stack's plain index grid scaled by the voxel size; it was settled from Autoscoper's
source (BrownBiomechanics/Autoscoper, commit 203b7213) as follows.

1. **The saved pose is the rendered pose, without the pivot.** ``save_tracking_results`` writes
   ``CoordFrame::from_xyzypr(xyzypr).to_matrix(m)`` of the curve values
   (``autoscoper/src/ui/AutoscoperMainWindow.cpp`` line 800, row order at line 809), and the DRR
   is rendered with ``modelview = camera.coord_frame().inverse() * from_xyzypr(xyzypr)``
   (``libautoscoper/src/Tracker.cpp`` lines 601 and 606). The pivot ("center pivot",
   ``getVolumeMatrix(i)->translate(transCenter)``, ``Tracker.cpp`` line 288, computed at
   ``VolumeDescription.cpp`` lines 241-243) only enters the interactive manipulator
   (``xcframe * volumeMatrix^-1 * manip * volumeMatrix``, ``Tracker.cpp`` line 481); it is not in
   the file. So a ``.tra`` matrix maps volume-frame mm to world mm.
2. **Flips act on voxel indices first.** ``flipVolume`` maps column ``j`` to ``W-1-j`` when
   ``VolumeFlip`` x is 1, row ``i`` to ``H-1-i`` for y and slice ``k`` to ``D-1-k`` for z
   (``VolumeDescription.cpp`` lines 66-68), before anything else.
3. **The volume box.** The ray caster intersects the box ``[0,1] x [0,1] x [-1,0]``
   (``gpu/opencl/kernel/RayCaster.cl`` lines 36-37; CUDA ``RayCaster_kernels.cu`` 171-172) in
   coordinates ``t = invScale * p + invTrans`` of the volume-frame point ``p`` (the inverse
   model-view is pre-multiplied by them in ``gpu/opencl/RayCaster.cpp`` lines 103-126), with
   ``invScale = 1 / (voxel size * cropped dim)`` and ``invTrans = (-min_x / dim_x,
   -(H - max_y - 1) / dim_y, min_z / dim_z)`` (``VolumeDescription.cpp`` lines 246-252; ``min``,
   ``max``: the non-zero bounding box of the flipped stack, ``cropVolume``), and samples the
   cropped texture at ``(t_x, 1 - t_y, -t_z)`` (``RayCaster.cl`` line 64; ``RayCaster_kernels.cu``
   line 189) with normalised coordinates, so texel ``n`` of an axis is at ``(n + 0.5) / dim``.

Solving 3 for the centre of flipped voxel (column ``j'``, row ``i'``, slice ``k'``) gives, for
any crop::

    x = sx (j' + 0.5),    y = sy (H - i' - 0.5),    z = -sz (k' + 0.5)

i.e. x along the columns, y up the rows from the stack's last row, z *against* the slice order —
a right-handed frame rotated 180° about x from the TIFF's index grid when nothing is flipped, and
a mirror of it when one or three axes are flipped. The crop and the pivot cancel out; the test
``tests/core/io/test_io_autoscoper_pose.py`` checks this closed form against a literal
transcription of the lines above on a cropped volume with every flip.

Talus reads the same TIFF as a :class:`~core.render.volume.CTVolume` whose physical frame is its
own (``T_physical_from_index``); :func:`T_autoscoper_from_ct` is the affine map between the two,
and ``T_lab_from_bone = T_tra @ T_autoscoper_from_ct``. With a mirrored volume frame this map is
not rigid: read the TIFF with :func:`autoscoper_volume_geometry`'s origin and direction instead
(a CT frame that *is* Autoscoper's volume frame, so ``T_lab_from_bone = T_tra``).
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "T_autoscoper_from_ct",
    "T_autoscoper_from_index",
    "autoscoper_volume_geometry",
    "lab_from_bone_from_tra",
    "tra_from_lab_from_bone",
]


def _flags(flip) -> tuple[bool, bool, bool]:
    f = tuple(bool(v) for v in flip)
    if len(f) != 3:
        raise ValueError(f"flip: expected three 0/1 values (x y z), got {flip!r}")
    return f  # type: ignore[return-value]


def T_autoscoper_from_index(shape_ijk, voxel_size, flip=(False, False, False)) -> np.ndarray:
    """4x4 affine from TIFF voxel indices ``(i = column, j = row, k = slice, 1)`` to Autoscoper's
    volume frame (mm), per the module docs.

    Parameters
    ----------
    shape_ijk : (3,) ints
        Columns, rows and slices (W, H, D) of the stack.
    voxel_size : (3,) floats
        ``VoxelSize`` (mm) along columns, rows, slices.
    flip : (3,) bools
        ``VolumeFlip`` x y z.
    """
    W, H, D = (int(n) for n in shape_ijk)
    if min(W, H, D) < 1:
        raise ValueError(f"shape_ijk: expected three positive sizes, got {shape_ijk!r}")
    sx, sy, sz = (float(s) for s in voxel_size)
    if not min(sx, sy, sz) > 0:
        raise ValueError(f"voxel_size: expected three positive sizes in mm, got {voxel_size!r}")
    fx, fy, fz = _flags(flip)
    T = np.eye(4)
    # x = sx (j' + 0.5), j' = W-1-i when flipped
    T[0, 0], T[0, 3] = (-sx, sx * (W - 0.5)) if fx else (sx, 0.5 * sx)
    # y = sy (H - i' - 0.5), i' = H-1-j when flipped
    T[1, 1], T[1, 3] = (sy, 0.5 * sy) if fy else (-sy, sy * (H - 0.5))
    # z = -sz (k' + 0.5), k' = D-1-k when flipped
    T[2, 2], T[2, 3] = (sz, -sz * (D - 0.5)) if fz else (-sz, -0.5 * sz)
    return T


def autoscoper_volume_geometry(shape_ijk, voxel_size, flip=(False, False, False)):
    """``(origin, direction)`` for a :class:`CTVolume` of the stack whose physical frame is
    Autoscoper's volume frame (``spacing`` = ``voxel_size``); ``direction`` has determinant -1
    when one or three axes are flipped."""
    T = T_autoscoper_from_index(shape_ijk, voxel_size, flip)
    s = np.asarray(voxel_size, dtype=float)
    return T[:3, 3].copy(), T[:3, :3] / s[None, :]


def T_autoscoper_from_ct(volume, flip=(False, False, False), voxel_size=None) -> np.ndarray:
    """4x4 map from ``volume``'s physical frame (Talus's bone frame) to Autoscoper's volume frame.

    Parameters
    ----------
    volume : CTVolume
        The stack as Talus reads it (same voxel grid as Autoscoper's ``VolumeFile``).
    flip : (3,) bools
        The ``.cfg``'s ``VolumeFlip``.
    voxel_size : (3,) floats, optional
        The ``.cfg``'s ``VoxelSize``; defaults to ``volume.spacing``.
    """
    vs = volume.spacing if voxel_size is None else voxel_size
    return T_autoscoper_from_index(volume.shape_ijk, vs, flip) @ volume.T_index_from_physical


def _rigid(T: np.ndarray, what: str) -> np.ndarray:
    R = T[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise ValueError(
            f"{what}: the volume's physical frame and Autoscoper's volume frame differ by a "
            "mirror or a scale (VolumeFlip, voxel size); read the volume with "
            "autoscoper_volume_geometry(...)'s origin and direction so that the pose stays rigid"
        )
    return T


def lab_from_bone_from_tra(T_tra, volume, flip=(False, False, False), voxel_size=None) -> np.ndarray:
    """``T_lab_from_bone`` (``(..., 4, 4)``; NaN stays NaN) from ``.tra`` matrices of ``volume``."""
    M = _rigid(T_autoscoper_from_ct(volume, flip, voxel_size), "volume")
    return np.asarray(T_tra, dtype=float) @ M


def tra_from_lab_from_bone(
    T_lab_from_bone, volume, flip=(False, False, False), voxel_size=None
) -> np.ndarray:
    """Inverse of :func:`lab_from_bone_from_tra`: the ``.tra`` matrices of ``T_lab_from_bone``."""
    M = _rigid(T_autoscoper_from_ct(volume, flip, voxel_size), "volume")
    return np.asarray(T_lab_from_bone, dtype=float) @ np.linalg.inv(M)
