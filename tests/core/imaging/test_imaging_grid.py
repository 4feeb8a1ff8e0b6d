"""Grid detection and lattice indexing against core.synthetic ground truth (thesis §3.5.2)."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from core.imaging.grid_detection import detect_grid_points
from core.imaging.grid_indexing import index_grid
from core.synthetic import Distortion, ImagingModel, bead_lattice_frame, distortion_grid_frame, foot_rig


def _match(found, truth):
    d, j = cKDTree(truth).query(found)
    return d, j


def test_holes_are_found_at_their_distorted_positions(grid_frame, camera1024):
    pts = detect_grid_points(grid_frame.image, feature_diameter_px=3.0 / camera1024.pixel_size)
    assert pts.polarity == "bright"
    d, j = _match(pts.uv, grid_frame.distorted_uv)
    assert len(np.unique(j)) == len(pts) >= 0.97 * len(grid_frame.distorted_uv)
    assert d.max() < 1.0  # nothing spurious
    assert np.median(d) < 0.25  # single noisy frame: ~0.2 px localisation noise
    # a noise-free frame localises the holes without bias (intensity-weighted centroids)
    clean = detect_grid_points(grid_frame.expected, feature_diameter_px=3.0 / camera1024.pixel_size)
    dc, _ = _match(clean.uv, grid_frame.distorted_uv)
    assert np.median(dc) < 0.08


def test_indexing_matches_the_plate_lattice(grid_frame, camera1024, similarity_residual):
    pts = detect_grid_points(grid_frame.image, feature_diameter_px=3.0 / camera1024.pixel_size)
    gi = index_grid(pts.uv, origin_uv=(511.5, 511.5))
    assert len(gi) == len(pts) and len(gi.unassigned) == 0
    assert len({tuple(c) for c in gi.ij}) == len(gi)
    _, j = _match(gi.uv, grid_frame.distorted_uv)
    # the true ideal positions are an exact similarity of the plate lattice: any wrong index
    # would leave a residual of a whole pitch (~52 px)
    assert similarity_residual(gi.ij, grid_frame.ideal_uv[j]).max() < 1e-6
    assert gi.pitch_px == pytest.approx(52, rel=0.05)
    assert gi.basis[0, 0] > 0.9 * gi.pitch_px and gi.basis[1, 1] > 0.9 * gi.pitch_px  # i ~ +u, j ~ +v


def test_indexing_survives_strong_distortion_missing_points_and_speckle(similarity_residual):
    cam = foot_rig(seed=0, pixels=512)[0]
    d = Distortion.for_camera(cam, k1=0.09, twist_deg=-7.0, center_offset_px=(15.0, -10.0))
    model = ImagingModel.fluoroscope(cam, rng=0, distortion=d, aperture_radius=0.95)
    fr = distortion_grid_frame(cam, model, rng=2, max_angle_deg=10.0)
    assert np.linalg.norm(fr.distorted_uv - fr.ideal_uv, axis=1).max() > 35  # ~1.4 pitches
    pts = detect_grid_points(fr.image, feature_diameter_px=3.0 / cam.pixel_size)
    rng = np.random.default_rng(3)
    keep = rng.random(len(pts)) > 0.1  # lose 10 % of the holes
    junk = rng.uniform(40, 470, size=(40, 2))  # and pick up speckles off the lattice
    junk = junk[cKDTree(fr.distorted_uv).query(junk)[0] > 0.4 * 26][:8]
    uv = np.vstack([pts.uv[keep], junk])
    gi = index_grid(uv)
    real = np.arange(len(uv)) < keep.sum()
    assert real[gi.point_index].all()  # no speckle got a lattice cell
    assert len(gi) >= 0.97 * keep.sum()
    _, j = _match(gi.uv, fr.distorted_uv)
    assert similarity_residual(gi.ij, fr.ideal_uv[j]).max() < 1e-6


def test_bead_lattice_is_dark_and_polarity_is_checked(camera1024, thesis_model):
    fr = bead_lattice_frame(camera1024, thesis_model, rng=4, offset_mm=(10.0, 5.0), angle_rad=0.2)
    dia = 2.0 / camera1024.pixel_size
    pts = detect_grid_points(fr.image, feature_diameter_px=dia)
    assert pts.polarity == "dark" and len(pts) == 36
    assert pts.contrast["dark"] > 10 * pts.contrast["bright"]
    gi = index_grid(pts.uv)
    assert len(gi) == 36 and np.ptp(gi.ij, axis=0).tolist() == [5, 5]
    with pytest.raises(ValueError, match=r"polarity='bright'.*dark beads"):
        detect_grid_points(fr.image, feature_diameter_px=dia, polarity="bright")


def test_hole_plate_refuses_dark_polarity(grid_frame, camera1024):
    with pytest.raises(ValueError, match="bright holes"):
        detect_grid_points(grid_frame.image, feature_diameter_px=3.0 / camera1024.pixel_size,
                           polarity="dark")


def test_bad_input_is_named():
    flat = np.full((64, 64), 1000.0)
    with pytest.raises(ValueError, match="image: no features"):
        detect_grid_points(flat + np.random.default_rng(0).normal(0, 1, flat.shape), feature_diameter_px=5)
    with pytest.raises(ValueError, match="feature_diameter_px"):
        detect_grid_points(flat, feature_diameter_px=0)
    with pytest.raises(ValueError, match="polarity"):
        detect_grid_points(flat, feature_diameter_px=4, polarity="white")
    with pytest.raises(ValueError, match="found 4 grid points"):
        index_grid(np.zeros((4, 2)))
    rng = np.random.default_rng(1)
    with pytest.raises(ValueError, match="lattice"):
        index_grid(rng.uniform(0, 500, size=(40, 2)))


@pytest.mark.realdata
def test_real_wrist_radiograph_beads_but_no_grid(sample_data):
    """The shared data hold no distortion-grid image (the XMALab radiographs are already
    undistorted). The detector still finds the wrist's steel beads (positions read off the
    image by eye, ±1.5 px) and the indexer refuses to make a lattice of them."""
    import cv2

    path = sample_data / "autoscoper_wrist/XMA_UND/xr_data_wrist_cam01/xr_rad_uln_cam01_UND.0002.tif"
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert img is not None and img.dtype == np.uint8
    pts = detect_grid_points(img, feature_diameter_px=6.0, polarity="dark")
    beads = np.array([(860, 1293), (840, 1322), (882, 1320), (837, 1347), (868, 1351), (855, 1373)])
    d, _ = cKDTree(pts.uv).query(beads)
    assert d.max() < 1.5
    with pytest.raises(ValueError, match="lattice"):
        index_grid(pts.uv)
