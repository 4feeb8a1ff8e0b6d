"""File formats: fluoro sequences, CT volumes, meshes, Autoscoper/XMALab interop, crash-safe writing.

Readers validate what they read and raise :class:`ValueError` naming the file and what was
expected; writers write atomically (:mod:`core.io.atomic`).
"""

from .atomic import FileLock, LockedError, atomic_open, atomic_write, atomic_write_json
from .cine import CineInfo, CineSequence, read_cine_info
from .cine_writer import write_cine
from .ct import DicomSeriesInfo, inspect_dicom_folder, read_ct, split_labels
from .paired import TwoViewSequence
from .sequences import (
    FrameSequence,
    MultipageTiffSequence,
    TiffFolderSequence,
    VideoSequence,
    open_sequence,
)
from .tiff_volume import read_tiff_volume

__all__ = [
    "CineInfo",
    "CineSequence",
    "DicomSeriesInfo",
    "FileLock",
    "FrameSequence",
    "LockedError",
    "MultipageTiffSequence",
    "TiffFolderSequence",
    "TwoViewSequence",
    "VideoSequence",
    "atomic_open",
    "atomic_write",
    "atomic_write_json",
    "inspect_dicom_folder",
    "open_sequence",
    "read_cine_info",
    "read_ct",
    "read_tiff_volume",
    "split_labels",
    "write_cine",
]
