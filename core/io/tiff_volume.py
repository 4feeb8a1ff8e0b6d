"""CT sub-volumes stored as multipage TIFF (one page per slice), as Autoscoper uses them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import tifffile

from .._validate import as_float_array
from ..render.volume import CTVolume

__all__ = ["read_tiff_volume"]


def read_tiff_volume(
    path: str | Path,
    spacing,
    *,
    origin=(0.0, 0.0, 0.0),
    hu_offset: float = 0.0,
    name: str | None = None,
) -> CTVolume:
    """Read a multipage TIFF volume (pages = slices, k) into a :class:`CTVolume` in HU.

    Parameters
    ----------
    path : str or Path
        Multipage TIFF; page ``k`` is slice ``k``, each page ``[row j, column i]``.
    spacing : (3,) sequence
        Voxel size (x = column, y = row, z = slice) in mm; TIFF files carry none, so it must be
        given (e.g. from an Autoscoper ``.cfg`` ``VoxelSize`` line).
    origin : (3,) sequence
        Physical position (mm) of the centre of voxel (0, 0, 0).
    hu_offset : float
        Added to the stored values to obtain HU (e.g. ``-1024`` for unsigned CT numbers stored
        as HU + 1024).
    name : str, optional
        Defaults to the file stem.

    Raises
    ------
    ValueError
        When the file is missing, unreadable, or not a 3-D scalar stack.
    """
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"path: no such TIFF volume file: {p}")
    spacing = as_float_array(spacing, "spacing", shape=(3,))
    try:
        data = tifffile.imread(p)
    except Exception as exc:  # tifffile raises many types for broken files
        raise ValueError(f"path: cannot read {p} as a TIFF stack ({exc})") from exc
    if data.ndim != 3:
        raise ValueError(
            f"path: {p} holds an array of shape {data.shape}; expected a stack of 2-D slices "
            "(pages, rows, columns)"
        )
    if hu_offset:
        data = data.astype(np.float32) + np.float32(hu_offset)
    return CTVolume(data, spacing=spacing, origin=origin, units="HU", name=name or p.stem)
