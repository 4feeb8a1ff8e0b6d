"""Radiopaque marker beads: detection, sub-pixel localisation, tracking and marker-based pose.

Thesis Chapter 4 in code: the six localizers of §4.2 and a recommended one that is both robust
to poor initial guesses and precise under quantum noise (:func:`localize`, :data:`METHODS`),
scale-space bead detection (:func:`detect_beads`), 2-D tracking with gap filling
(:func:`track_beads`), epipolar matching, triangulation and rigid-body pose from beads
(:mod:`core.markers.pose`), and the §4.3 study on synthetic lattices (:mod:`core.studies.markers.study`,
``python -m core.studies.markers.study``; speed: ``python -m core.studies.markers.benchmark``).

Pixels are ``(u, v) = (column, row)`` with the origin at the centre of the top-left pixel; image
arrays are indexed ``[row, col]``; lab coordinates are in mm.
"""

from .batch import METHODS, RECOMMENDED, localize
from .detect import BeadDetections, detect_beads
from .pose import (
    EpipolarMatches,
    RigidFit,
    epipolar_distance,
    fundamental_matrix,
    match_epipolar,
    rigid_fit,
    triangulate_beads,
)
from .results import STATUS, STATUS_NAMES, Localization
from .track import FILLED, LOST, TRACKED, BeadTracks, track_beads

__all__ = [
    "FILLED",
    "LOST",
    "METHODS",
    "RECOMMENDED",
    "STATUS",
    "STATUS_NAMES",
    "TRACKED",
    "BeadDetections",
    "BeadTracks",
    "EpipolarMatches",
    "Localization",
    "RigidFit",
    "detect_beads",
    "epipolar_distance",
    "fundamental_matrix",
    "localize",
    "match_epipolar",
    "rigid_fit",
    "track_beads",
    "triangulate_beads",
]
