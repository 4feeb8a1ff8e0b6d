"""Real radiographs: the wrist sample's beads lie on the epipolar lines of the real calibration."""

import numpy as np

from core.calibration.epipolar_check import epipolar_check, line_distances
from core.geometry.camera import Rig
from core.markers import fundamental_matrix


def test_wrist_beads_lie_on_the_epipolar_lines(wrist):
    check = epipolar_check(wrist.rig, [wrist.frame(0, 1), wrist.frame(1, 1)])
    s = check.summary()
    assert min(s["detections"]) >= 12 and s["matched"] >= 10
    assert s["median_px"] < 0.6 and s["max_px"] < 2.0  # beads of a 1760² image within ~1 px
    # without any gate, most view-1 beads have a view-2 bead within 1.5 px of their line
    assert np.mean(check.nearest_view2 < 1.5) > 0.8
    assert s["median_reprojection_px"] < 0.5
    # a wrong rig (camera 2 moved by 5 mm) puts the same beads several pixels off their lines
    c2 = wrist.rig[1]
    moved = Rig((wrist.rig[0], c2.with_pose(c2.R, c2.t + np.array([0.0, 5.0, 0.0]))))
    uv1, uv2 = check.uv[0][check.pairs[:, 0]], check.uv[1][check.pairs[:, 1]]
    d2, _ = line_distances(fundamental_matrix(moved[0], moved[1]), uv1, uv2)
    assert np.median(d2) > 5 * s["median_px"]
