"""The static cube of a 256² session (the demo's rig at 256 px, seed 0) is detected and labelled.

``talus demo --pixels 256`` could not label its cube frame ("no pair of labellings is
epipolar-consistent"): the beads were searched in the whole corrected frame, the dark corners
outside the intensifier's round field included (the flatfield's fluence surface is positive
there, a fraction of a percent of the field's, so ``Flatfield.valid`` held every pixel), and the
normalised dark noise there gave 25 blobs of the beads' 2-6 px sizes that outranked real beads:
40 detections per view, a bead lost and the size scale fitted on noise. The field is now where
the surface exceeds a fraction of its 99th percentile (``_session_frames.FIELD_GAIN``).

Only the session's correction and the cube's labelling run here (the spiral is one frame, the
epipolar geometry the generator's rig); the whole calibration at 256² is the demo's.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import core.calibration.session as cs
from core.calibration import _session_frames as frames
from core.calibration.matching import label_sequence
from core.geometry.camera import Camera, Rig


@pytest.fixture(scope="module")
def corrected(tmp_path_factory):
    from core.io.calibration_session import read_session
    from core.synthetic.session import write_calibration_session

    out = tmp_path_factory.mktemp("session256") / "session"
    write_calibration_session(out, pixels=256, seed=0, n_spiral=1, n_grid=1, n_lattice=0, n_dark=2,
                              n_flat=3, n_glare=0)
    setup = cs.prepare(read_session(out))
    dist = cs.distortion_step(setup, cs.flatfield_step(setup))
    truth = json.loads((out / "truth" / "truth.json").read_text())
    rig = Rig(tuple(Camera(np.array(c["K"]), np.array(c["R"]), np.array(c["t"]), c["width"], c["height"],
                           c["pixel_size_mm"]) for c in truth["cameras"]))
    ideal = np.load(out / "truth" / "truth.npz")["cube_ideal_uv"]
    return setup, dist, rig, ideal


def test_the_field_mask_leaves_out_the_corners(corrected):
    _, dist, _, _ = corrected
    for c in dist.cameras:
        mask = frames._field_mask(c)
        rows, cols = np.nonzero(mask)
        r = np.hypot(cols - 127.5, rows - 127.5)
        assert r.max() < 120 and mask[88:168, 88:168].all()  # the field's radius is about 128 px


def test_the_cube_is_detected_and_labelled_at_256(corrected):
    setup, dist, rig, ideal = corrected
    _, dets = frames._beads(setup.reader, setup.cameras, dist.cameras, "cube", setup.static,
                            lambda *a: None)
    for v, d in enumerate(dets[0]):
        assert len(d) == len(setup.static) == 15
        near = np.linalg.norm(ideal[v][:, None] - d.uv[None], axis=2).min(axis=1)
        assert near.max() < 0.6, near  # every bead found, where the generator put it
    labelled, _, _ = label_sequence(setup.static, dets, rig=rig)
    assert labelled[0].ok, labelled[0].reason
    assert [lab.n_labelled for lab in labelled[0].labellings] == [15, 15]
