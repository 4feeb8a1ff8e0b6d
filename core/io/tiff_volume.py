"""CT sub-volumes stored as multipage TIFF (one page per slice), as Autoscoper uses them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import tifffile

from .._validate import as_float_array
from ..render.volume import CTVolume
from .errors import FileError, reading

__all__ = ["read_tiff_volume"]


def read_tiff_volume(
    path: str | Path,
    spacing,
    *,
    origin=(0.0, 0.0, 0.0),
    direction=None,
    hu_offset: float = 0.0,
    units: str = "HU",
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
    direction : (3, 3) array, optional
        Columns = directions of the i, j, k axes (default identity).
    hu_offset : float
        Added to the stored values to obtain HU (e.g. ``-1024`` for unsigned CT numbers stored
        as HU + 1024).
    units : str
        ``"HU"`` (default) or ``"1/mm"`` for an attenuation volume.
    name : str, optional
        Defaults to the file stem.

    Raises
    ------
    FileError
        (a ``ValueError``) When the file is missing, unreadable, or not a stack of single-channel 2-D slices.
    """
    p = Path(path)
    spacing = as_float_array(spacing, "spacing", shape=(3,))
    with reading(p, "a multipage TIFF stack of single-channel slices"):
        if not p.is_file():
            raise FileError(f"path: no such TIFF volume file: {p}", path=p)
        with tifffile.TiffFile(p) as tif:
            series = tif.series[0]
            spp = tif.pages[0].samplesperpixel
            data = series.asarray()
        if spp != 1:
            raise ValueError(
                f"path: {p} has {spp} samples per pixel (colour?); expected single-channel slices"
            )
        if data.ndim != 3:
            raise ValueError(
                f"path: {p} holds an array of shape {data.shape}; expected a stack of 2-D slices "
                "(pages, rows, columns)"
            )
        if 0 in data.shape:
            raise ValueError(f"path: {p} holds an empty stack {data.shape}; expected slices of voxels")
        if hu_offset:
            data = data.astype(np.float32) + np.float32(hu_offset)
        kw = {} if direction is None else {"direction": direction}
        return CTVolume(data, spacing=spacing, origin=origin, units=units, name=name or p.stem, **kw)
