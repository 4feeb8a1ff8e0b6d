"""Camera calibration of the biplane X-ray rig (thesis Chapter 5).

* :mod:`~core.calibration.objects`: calibration objects (15-bead cube, helical spirals),
  definition files, bead centres from a micro-CT scan.
* :mod:`~core.calibration.dlt`: single-frame 11-parameter DLT with explicit failure results,
  and a batched form for sensitivity studies.
* :mod:`~core.calibration.bundle`: rigid-rig bundle adjustment over many frames of an object
  moved through the volume (intrinsics, rig, per-frame poses, lab frame from a static frame,
  SID priors), with parameter standard deviations.
* :mod:`~core.calibration.errormap`: reprojection / reconstruction error, error maps over the
  intersection of the X-ray cones.
* :mod:`~core.calibration.simulate`: synthetic calibration sequences (ground truth).

Pixels are ``(u, v) = (column, row)`` with the origin at the centre of the top-left pixel; image
arrays are indexed ``[row, col]``; lengths in mm, angles in radians.
"""

from .bundle import BundleResult, ObjectFrame, bundle_adjust
from .dlt import DLTCalibration, calibrate_dlt, camera_parameters, dlt_batch
from .errormap import (
    ErrorMap,
    ObjectReconstruction,
    capture_lattice,
    error_map,
    object_reconstruction,
    reconstruction_errors,
)
from .objects import (
    CalibrationTarget,
    VolumeBeads,
    builtin_target,
    cube_target,
    extract_beads,
    read_target,
    spiral_target,
    target_from_volume,
    write_target,
)

__all__ = [
    "BundleResult",
    "CalibrationTarget",
    "DLTCalibration",
    "ErrorMap",
    "ObjectFrame",
    "ObjectReconstruction",
    "VolumeBeads",
    "builtin_target",
    "bundle_adjust",
    "calibrate_dlt",
    "camera_parameters",
    "capture_lattice",
    "cube_target",
    "dlt_batch",
    "error_map",
    "extract_beads",
    "object_reconstruction",
    "read_target",
    "reconstruction_errors",
    "spiral_target",
    "target_from_volume",
    "write_target",
]
