"""Camera geometry: pinhole X-ray cameras, format conversions, rigid transforms, triangulation."""

from .camera import Camera, Rig, make_K
from .conversions import (
    DLTFit,
    P_from_dlt,
    camera_from_dlt,
    camera_from_P,
    compose_P,
    decompose_P,
    dlt_from_correspondences,
    dlt_from_P,
)
from .mayacam import read_mayacam, rig_from_mayacam, write_mayacam
from .transforms import (
    apply_rigid,
    compose_rigid,
    euler_to_matrix,
    invert_rigid,
    make_rigid,
    matrix_to_euler,
    matrix_to_quat,
    matrix_to_rotvec,
    params_from_pose,
    pose_from_params,
    quat_to_matrix,
    random_perturbation,
    rotvec_to_matrix,
)
from .triangulate import Triangulation, triangulate

__all__ = [
    "Camera",
    "DLTFit",
    "P_from_dlt",
    "Rig",
    "Triangulation",
    "apply_rigid",
    "camera_from_P",
    "camera_from_dlt",
    "compose_P",
    "compose_rigid",
    "decompose_P",
    "dlt_from_P",
    "dlt_from_correspondences",
    "euler_to_matrix",
    "invert_rigid",
    "make_K",
    "make_rigid",
    "matrix_to_euler",
    "matrix_to_quat",
    "matrix_to_rotvec",
    "params_from_pose",
    "pose_from_params",
    "quat_to_matrix",
    "random_perturbation",
    "read_mayacam",
    "rig_from_mayacam",
    "rotvec_to_matrix",
    "triangulate",
    "write_mayacam",
]
