"""Bead detection on the synthetic lattice, on confounders, and on the real wrist radiographs."""

import numpy as np
import pytest

from core.markers import detect_beads, match_epipolar, triangulate_beads
from core.markers.detect import field_mask


def test_lattice_beads_are_all_found_with_sizes_and_subpixel_centres(lattice, lattice_frames):
    det = detect_beads(lattice_frames[0], diameter_px=8.0)
    assert len(det) == 21
    d = np.linalg.norm(det.uv[:, None] - lattice.uv[None], axis=2)
    j = np.argmin(d, axis=1)
    assert len(set(j)) == 21 and d.min(axis=1).max() < 0.15
    big = lattice.diameter_px[j] > 8
    assert det.radius[big].min() > det.radius[~big].max()  # 3 mm beads look bigger than 2 mm
    assert np.all(det.contrast > 0.3) and np.all(det.circularity > 0.8)
    assert np.all(np.isfinite(det.sigma)) and det.sigma.max() < 0.1


def test_flat_images_ridges_and_large_blobs_are_not_beads():
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:200, 0:200].astype(float)
    img = 0.8 + rng.normal(0, 0.01, (200, 200))
    assert len(detect_beads(img, diameter_px=8.0)) == 0
    ridge = img - 0.4 * np.exp(-((xx - 0.3 * yy - 60) ** 2) / (2 * 1.5**2))  # a dark line (edge, wire)
    big = img - 0.4 * (np.hypot(xx - 140, yy - 100) < 20)  # a large faint disc
    bead = img - 0.5 * np.exp(-((xx - 150.3) ** 2 + (yy - 40.7) ** 2) / (2 * 2.2**2))
    det = detect_beads(ridge + big + bead - 2 * img, diameter_px=6.0)
    assert len(det) == 1 and np.linalg.norm(det.uv[0] - [150.3, 40.7]) < 0.1


def test_arguments_are_validated():
    with pytest.raises(ValueError, match="diameter_px"):
        detect_beads(np.zeros((32, 32)), diameter_px=0.5)
    with pytest.raises(ValueError, match="image"):
        detect_beads(np.zeros((4, 32, 32)), diameter_px=8)
    with pytest.raises(ValueError, match="size_range"):
        detect_beads(np.zeros((32, 32)), diameter_px=8, size_range=(1.2, 2.0))
    with pytest.raises(ValueError, match="mask"):
        detect_beads(np.ones((32, 32)), diameter_px=8, mask=np.ones((3, 3), bool))


WRIST = {"diameter_px": 7.0, "min_snr": 10.0}


def test_wrist_detections_are_steel_beads_seen_in_both_views(wrist):
    dets = []
    for v in range(2):
        img = wrist.frame(v, 1)
        dets.append(detect_beads(img, mask=field_mask(img), **WRIST))
    for det in dets:
        # ~5 beads in the radius, ~6 in the ulna (close pairs), ~5 in the metacarpals per view
        assert 12 <= len(det) <= 24, len(det)
        assert np.mean(det.circularity >= 0.6) > 0.75
        assert np.all((det.radius > 2.0) & (det.radius < 4.5))  # small dots, not the ~17 px circles
        assert np.median(det.contrast) > 30 and det.contrast.min() > 15  # dark steel: 8-bit DN
    cams = wrist.rig
    m = match_epipolar(cams[0], cams[1], dets[0].uv, dets[1].uv, max_distance=3.0)
    assert len(m.pairs) >= 0.7 * min(len(d) for d in dets)
    assert np.median(m.distance) < 1.0  # the matched beads lie on each other's epipolar lines
    uv = np.stack([dets[0].uv[m.pairs[:, 0]], dets[1].uv[m.pairs[:, 1]]])
    tri = triangulate_beads(cams, uv)
    assert np.median(tri.rms_error) < 1.0
    # and they are in the forearm: within 12 cm of the radius' hand-found position
    from core.samples import WRIST_RADIUS_POSE

    d = np.linalg.norm(tri.points - WRIST_RADIUS_POSE[:3, 3], axis=1)
    assert np.median(d) < 120.0
