"""File formats: fluoro sequences, CT volumes, meshes, Autoscoper/XMALab interop, crash-safe writing.

Readers validate what they read and raise :class:`~core.io.errors.FileError` (a ``ValueError``)
naming the file and what was expected, whatever the third-party parser underneath raised (its
exception is chained); writers write atomically (:mod:`core.io.atomic`).
"""

from .atomic import FileLock, LockedError, atomic_open, atomic_path, atomic_write, atomic_write_json
from .autoscoper import (
    AutoscoperFilter,
    AutoscoperTrial,
    AutoscoperViewSettings,
    AutoscoperVolume,
    matrix_to_xyzypr,
    read_autoscoper_cfg,
    read_tra,
    read_vie,
    write_autoscoper_cfg,
    write_tra,
    xyzypr_to_matrix,
)
from .calibration_session import CalibrationSession, read_session
from .cine import CineInfo, CineSequence, read_cine_info
from .cine_writer import write_cine
from .ct import DicomSeriesInfo, inspect_dicom_folder, read_ct, split_labels
from .errors import FileError
from .meshes import Mesh, read_mesh, write_mesh
from .paired import TwoViewSequence
from .sequences import (
    FrameSequence,
    MultipageTiffSequence,
    TiffFolderSequence,
    VideoSequence,
    open_sequence,
)
from .tiff_volume import read_tiff_volume
from .xmalab import (
    dlt_csv_from_rig,
    read_dlt_csv,
    read_points_2d,
    read_points_3d,
    rig_from_dlt_csv,
    write_dlt_csv,
    write_points_2d,
    write_points_3d,
)

__all__ = [
    "AutoscoperFilter",
    "AutoscoperTrial",
    "AutoscoperViewSettings",
    "AutoscoperVolume",
    "CalibrationSession",
    "CineInfo",
    "CineSequence",
    "DicomSeriesInfo",
    "FileError",
    "FileLock",
    "FrameSequence",
    "LockedError",
    "Mesh",
    "MultipageTiffSequence",
    "TiffFolderSequence",
    "TwoViewSequence",
    "VideoSequence",
    "atomic_open",
    "atomic_path",
    "atomic_write",
    "atomic_write_json",
    "dlt_csv_from_rig",
    "inspect_dicom_folder",
    "matrix_to_xyzypr",
    "open_sequence",
    "read_autoscoper_cfg",
    "read_cine_info",
    "read_ct",
    "read_dlt_csv",
    "read_mesh",
    "read_points_2d",
    "read_points_3d",
    "read_session",
    "read_tiff_volume",
    "read_tra",
    "read_vie",
    "rig_from_dlt_csv",
    "split_labels",
    "write_autoscoper_cfg",
    "write_cine",
    "write_dlt_csv",
    "write_mesh",
    "write_points_2d",
    "write_points_3d",
    "write_tra",
    "xyzypr_to_matrix",
]
