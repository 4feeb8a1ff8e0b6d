"""Camera calibration of the biplane X-ray rig (thesis Chapter 5).

* :mod:`~core.calibration.objects`, :mod:`~core.calibration.hardware`,
  :mod:`~core.calibration.microct`: calibration objects (15-bead cube, helical spirals, the
  helix frame), definition files, bead centres from a micro-CT scan.
* :mod:`~core.calibration.detection`, :mod:`~core.calibration.labelling`,
  :mod:`~core.calibration.matching`: beads detected and size-classified with
  :mod:`core.markers`, labelled per view (spiral: PCA axis + string matching, chains of
  neighbours; cube: RANSAC), resolved between views by epipolar geometry (7/8-point F + RANSAC);
  a manual-correction API for the wizard.
* :mod:`~core.calibration.dlt`: single-frame 11-parameter DLT with explicit failure results,
  and a batched form for sensitivity studies.
* :mod:`~core.calibration.bundle`: rigid-rig bundle adjustment over many frames of an object
  moved through the volume (intrinsics, rig, per-frame poses, lab frame from a static frame,
  SID priors), with parameter standard deviations.
* :mod:`~core.calibration.errormap`: reprojection / reconstruction error, error maps over the
  intersection of the X-ray cones.
* :mod:`~core.calibration.sensitivity`: Monte Carlo / Latin-hypercube perturbation of bead
  coordinates and Sobol indices of the DLT camera parameters.
* :mod:`~core.calibration.io`: the versioned Talus calibration file (JSON), MayaCam 1.0/2.0 and
  DLT CSV export/import.

Pixels are ``(u, v) = (column, row)`` with the origin at the centre of the top-left pixel; image
arrays are indexed ``[row, col]``; lengths in mm, angles in radians.
"""

from .bundle import BundleResult, ObjectFrame, bundle_adjust
from .detection import ObjectDetections, classify_sizes, detect_object_beads
from .dlt import DLTCalibration, calibrate_dlt, camera_parameters, dlt_batch
from .errormap import (
    ErrorMap,
    ObjectReconstruction,
    capture_lattice,
    error_map,
    object_reconstruction,
    reconstruction_errors,
)
from .io import (
    CalibrationFile,
    export_rig,
    load_calibration,
    read_dlt_csv_rig,
    read_mayacam_rig,
    save_calibration,
)
from .labelling import Labelling, fit_labels, label_ransac, label_spiral, label_view, propagate_labels
from .matching import (
    FrameLabels,
    FundamentalFit,
    fundamental_7point,
    fundamental_8point,
    label_sequence,
    ransac_fundamental,
    resolve_frame,
    transfer_labels,
)
from .microct import VolumeBeads, extract_beads, target_from_volume
from .objects import CalibrationTarget, builtin_target, cube_target, read_target, spiral_target, write_target
from .sensitivity import PerturbationStudy, SobolResult, perturbation_study, sobol_analysis

__all__ = [
    "BundleResult",
    "CalibrationFile",
    "CalibrationTarget",
    "DLTCalibration",
    "ErrorMap",
    "FrameLabels",
    "FundamentalFit",
    "Labelling",
    "ObjectDetections",
    "ObjectFrame",
    "ObjectReconstruction",
    "PerturbationStudy",
    "SobolResult",
    "VolumeBeads",
    "builtin_target",
    "bundle_adjust",
    "calibrate_dlt",
    "camera_parameters",
    "capture_lattice",
    "classify_sizes",
    "cube_target",
    "detect_object_beads",
    "dlt_batch",
    "error_map",
    "export_rig",
    "extract_beads",
    "fit_labels",
    "fundamental_7point",
    "fundamental_8point",
    "label_ransac",
    "label_sequence",
    "label_spiral",
    "label_view",
    "load_calibration",
    "object_reconstruction",
    "perturbation_study",
    "propagate_labels",
    "ransac_fundamental",
    "read_dlt_csv_rig",
    "read_mayacam_rig",
    "read_target",
    "reconstruction_errors",
    "resolve_frame",
    "save_calibration",
    "sobol_analysis",
    "spiral_target",
    "target_from_volume",
    "transfer_labels",
    "write_target",
]
