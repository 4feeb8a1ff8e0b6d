"""Deterministic biplane ground truth: rig, bone phantoms, motion, image formation, calibration.

Everything is seeded (an ``int`` seed or a ``numpy.random.Generator``) and documented with its
physical units and the source of its parameter values. Frames: see :mod:`core.synthetic.rig` (lab)
and :mod:`core.synthetic.phantoms` (anatomical / CT frame of the bones).
"""

from .analytic import (
    attenuation_per_mm,
    bead_line_integrals,
    box_line_integrals,
    cylinder_line_integrals,
    slab_line_integrals,
)
from .distortion import Distortion
from .imaging import ImagingModel
from .motion import stance_trajectories
from .phantoms import (
    BONE_NAMES,
    FOOT_IN_LAB,
    Phantom,
    bone_centroid,
    bone_phantom,
    foot_phantoms,
    soft_tissue_envelope,
)
from .rig import FLOOR_Z_MM, foot_rig
from .voxelize import box_mesh, icosphere, mesh_volume, voxelize_mesh

__all__ = [
    "BONE_NAMES",
    "FLOOR_Z_MM",
    "FOOT_IN_LAB",
    "Distortion",
    "ImagingModel",
    "Phantom",
    "attenuation_per_mm",
    "bead_line_integrals",
    "bone_centroid",
    "bone_phantom",
    "box_line_integrals",
    "box_mesh",
    "cylinder_line_integrals",
    "foot_phantoms",
    "foot_rig",
    "icosphere",
    "mesh_volume",
    "slab_line_integrals",
    "soft_tissue_envelope",
    "stance_trajectories",
    "voxelize_mesh",
]
