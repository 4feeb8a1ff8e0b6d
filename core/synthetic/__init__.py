"""Deterministic biplane ground truth: rig, bone phantoms, motion, image formation, calibration.

Everything is seeded (an ``int`` seed or a ``numpy.random.Generator``) and documented with its
physical units and the source of its parameter values. Frames: see :mod:`core.synthetic.rig` (lab)
and :mod:`core.synthetic.phantoms` (anatomical / CT frame of the bones).

Modules: ``rig`` (walkway biplane cameras), ``sdf`` + ``phantoms`` (HU bone phantoms, soft
tissue), ``voxelize`` (meshes → HU volumes), ``analytic`` (exact chords through beads, plates,
boxes, cylinders; NIST attenuation), ``distortion`` + ``imaging`` (intensifier image chain),
``motion`` (stance-phase poses), ``calib_objects`` + ``calibration`` (cube, spirals, grid, lattice,
pinholes, flatfields), ``capture`` (calibration objects moved through a rig's capture volume:
poses, noisy projections, rendered frames), ``lattice`` (the §4.3 bead lattice on an
intensifier), ``scene`` (a whole trial) and ``demo`` (a study folder on disk).

The generator sits on top of the library: the cube, spirals and helix frame are
:mod:`core.calibration.hardware`'s and the attenuation table :mod:`core.render.attenuation`'s,
re-exported here. Only tests and :mod:`core.studies` import this package; nothing a user runs
does (an import contract).

Example::

    from core.synthetic import make_foot_scene
    scene = make_foot_scene(n_frames=20, pixels=512, seed=0)
    frames = scene.render_frame(5)              # (2, 512, 512) uint16, 12-bit
    poses = scene.poses(5)                      # (n_bones, 4, 4) T_lab_from_bone
    uv = scene.bead_uv(5)                       # (2, n_beads, 2) distorted bead centres
    flat = scene.imaging[0].to_float(frames[0])  # flatfield-normalised [0, 1]
"""

from .analytic import (
    attenuation_per_mm,
    bead_line_integrals,
    box_line_integrals,
    cylinder_line_integrals,
    slab_line_integrals,
)
from .calib_objects import (
    CalibrationObject,
    FacePlate,
    bead_lattice,
    calibration_cube,
    distortion_grid,
    helical_spiral,
    helix_frame_from_beads,
    pinhole_bar,
)
from .calibration import (
    CalibrationFrame,
    bead_lattice_frame,
    distortion_grid_frame,
    flatfield_frames,
    object_frames,
    pinhole_frames,
)
from .demo import make_demo_study, write_volume
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
from .scene import BeadSet, BiplaneScene, SceneRenderer, excess_transfer, make_foot_scene
from .voxelize import box_mesh, icosphere, mesh_volume, voxelize_mesh

__all__ = [
    "BONE_NAMES",
    "FLOOR_Z_MM",
    "FOOT_IN_LAB",
    "BeadSet",
    "BiplaneScene",
    "CalibrationFrame",
    "CalibrationObject",
    "Distortion",
    "FacePlate",
    "ImagingModel",
    "Phantom",
    "SceneRenderer",
    "attenuation_per_mm",
    "bead_lattice",
    "bead_lattice_frame",
    "bead_line_integrals",
    "bone_centroid",
    "bone_phantom",
    "box_line_integrals",
    "box_mesh",
    "calibration_cube",
    "cylinder_line_integrals",
    "distortion_grid",
    "distortion_grid_frame",
    "excess_transfer",
    "flatfield_frames",
    "foot_phantoms",
    "foot_rig",
    "helical_spiral",
    "helix_frame_from_beads",
    "icosphere",
    "make_demo_study",
    "make_foot_scene",
    "mesh_volume",
    "object_frames",
    "pinhole_bar",
    "pinhole_frames",
    "slab_line_integrals",
    "soft_tissue_envelope",
    "stance_trajectories",
    "voxelize_mesh",
    "write_volume",
]
