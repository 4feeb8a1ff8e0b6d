"""Bead detection, size classes and automatic / manual labelling against rendered ground truth."""

import numpy as np
import pytest

from core.calibration import labelling
from core.calibration.detection import ObjectDetections, classify_sizes, detect_object_beads
from core.calibration.labelling import fit_labels, label_ransac, label_view, near_symmetries, propagate_labels
from core.calibration.matching import label_sequence
from core.calibration.objects import cube_target, spiral_target
from core.geometry.transforms import make_rigid
from core.synthetic import ImagingModel, foot_rig
from core.synthetic.capture import capture_centre, capture_poses, render


def _ppm(rig, v):
    return rig[v].fx / np.linalg.norm(capture_centre(rig) - rig[v].source)


def _correct(labels, truth, target):
    """Labels agree with the true bead index (up to the object's symmetry)."""
    k = labels >= 0
    return any(np.array_equal(p[truth[k]], labels[k]) for p in target.symmetries)


def _fake(rig, v, target, T, g, drop=0, noise=0.05):
    """Detections from exact projections (shuffled, some dropped)."""
    uv = rig[v].project(target.centers_lab(T))
    keep = g.permutation(len(uv))[: len(uv) - drop]
    ppm = _ppm(rig, v)
    det = ObjectDetections(uv[keep] + g.normal(0, noise, (len(keep), 2)), np.zeros((len(keep), 2)),
                           target.diameters[keep] * ppm, target.size_classes[1][keep], ppm,
                           target.size_classes[0], np.ones(len(keep)))
    return det, keep


@pytest.fixture(scope="module")
def rendered_spiral():
    """Four rendered frames of the 23-bead spiral (256 px, realistic noise/blur, no distortion)."""
    rig = foot_rig(seed=0, pixels=256)
    tg = spiral_target(23)
    poses = capture_poses(rig, tg, 4, rng=2, margin_px=4)
    ims = [ImagingModel.fluoroscope(c, distortion=None) for c in rig]
    dets, truth = [], []
    for f, T in enumerate(poses):
        fr = render(rig, tg, T, rng=f, imaging=ims)
        dets.append(tuple(detect_object_beads(ims[v].to_float(fr.image[v]), tg.size_classes[0],
                                              px_per_mm=_ppm(rig, v)) for v in range(2)))
        truth.append(fr.ideal_uv)
    return rig, tg, dets, truth


def test_detection_localises_and_sizes_the_spiral_beads(rendered_spiral):
    rig, tg, dets, truth = rendered_spiral
    for pair, uv in zip(dets, truth, strict=True):
        for v, det in enumerate(pair):
            assert len(det) >= 20
            d = np.linalg.norm(det.uv[:, None] - uv[v][None], axis=2)
            j = d.argmin(axis=1)
            assert np.median(d.min(axis=1)) < 0.1
            assert np.mean(det.size_class == tg.size_classes[1][j]) > 0.95  # 3 vs 5 mm told apart
            assert det.px_per_mm == pytest.approx(_ppm(rig, v), rel=0.3)


def test_rendered_sequence_is_labelled_correctly_without_a_rig(rendered_spiral):
    _, tg, dets, truth = rendered_spiral
    frames, obs, _ = label_sequence(tg, dets)
    assert all(fr.ok for fr in frames) and len(obs) == 4
    for fr, uv in zip(frames, truth, strict=True):
        for v, lab in enumerate(fr.labellings):
            assert lab.n_labelled >= 15
            o = lab.observed()
            err = min(np.nanmax(np.linalg.norm(o[p] - uv[v], axis=1)) for p in tg.symmetries)
            assert err < 1.0  # every label is right (a wrong one is a bead spacing, > 10 px, away)
        # both views use the same member of the symmetric pair
        o1, o2 = (lab.observed() for lab in fr.labellings)
        k = np.all(np.isfinite(o1), axis=1) & np.all(np.isfinite(o2), axis=1)
        assert k.sum() >= 10


def test_oblique_views_and_missing_beads(rig):
    tg = spiral_target(33)
    g = np.random.default_rng(11)
    poses = capture_poses(rig, tg, 8, rng=5, axis_tilt_deg=35)
    n_ok = 0
    for T in poses:
        for v in range(2):
            det, keep = _fake(rig, v, tg, T, g, drop=int(g.integers(0, 4)))
            lab = label_view(tg, det)
            if lab.ok:
                opts = [lab.labels, *lab.alternatives]
                assert any(_correct(o, keep, tg) for o in opts)  # the right one is offered
                n_ok += _correct(lab.labels, keep, tg)
    assert n_ok >= 14  # of 16 views


def test_cube_by_ransac_on_a_rendered_frame():
    rig = foot_rig(seed=0, pixels=512)
    tg = cube_target()
    from scipy.spatial.transform import Rotation

    T = make_rigid(Rotation.from_rotvec([0.3, 0.5, 0.2]).as_matrix(), capture_centre(rig))
    ims = [ImagingModel.fluoroscope(c, distortion=None) for c in rig]
    fr = render(rig, tg, T, rng=0, imaging=ims)
    for v in range(2):
        det = detect_object_beads(ims[v].to_float(fr.image[v]), tg.size_classes[0], px_per_mm=_ppm(rig, v))
        lab = label_ransac(tg, det, rng=1)
        assert lab.ok and lab.n_labelled >= 11, lab.reason
        o = lab.observed()
        k = np.all(np.isfinite(o), axis=1)
        assert np.max(np.linalg.norm(o[k] - fr.ideal_uv[v][k], axis=1)) < 0.5


def test_cube_near_symmetries_are_its_squares_turned_about_the_axis():
    tg = cube_target()
    maps = near_symmetries(tg)
    assert len(maps) == 3  # 90, 180, 270 degrees: the corners map onto corners, the fifth beads nowhere
    for p in maps:
        assert np.array_equal(np.flatnonzero(p < 0), [4, 9, 14])
        k = p >= 0
        assert np.array_equal(tg.diameters[p[k]], tg.diameters[k]) and len(set(p[k])) == 12


def test_cube_labelling_turned_by_90_degrees_is_corrected(rig, monkeypatch):
    """A RANSAC hypothesis that is the right labelling with the squares turned by 90° explains the
    corners and sometimes spurious detections: the fifth beads of the planes decide."""
    from scipy.spatial.transform import Rotation

    tg = cube_target()
    T = make_rigid(Rotation.from_rotvec([0.3, 0.5, 0.2]).as_matrix(), capture_centre(rig))
    g = np.random.default_rng(4)
    det, keep = _fake(rig, 0, tg, T, g)
    turn = near_symmetries(tg)[0]
    wrong = fit_labels(tg, det, np.where(turn[keep] >= 0, turn[keep], -1))
    assert wrong.ok and wrong.n_labelled >= 10 and not _correct(wrong.labels, keep, tg)
    monkeypatch.setattr(labelling, "_refine", lambda *a, **k: [wrong])
    lab = label_ransac(tg, det, samples=100, rounds=1)
    assert lab.ok and lab.n_explained == 15 and lab.n_labelled > wrong.n_labelled
    assert _correct(lab.labels, keep, tg)


def test_manual_correction_api(rig):
    tg = spiral_target(23)
    T = capture_poses(rig, tg, 1, rng=3)[0]
    g = np.random.default_rng(0)
    det, keep = _fake(rig, 0, tg, T, g)
    hints = {i: tg.bead_ids[keep[i]] for i in range(6)}
    lab = propagate_labels(tg, det, hints)
    assert lab.ok and lab.manual and lab.n_labelled >= 20
    assert np.array_equal(lab.labels[lab.labels >= 0], keep[lab.labels >= 0])
    # the user moves a label and removes another
    edited = lab.assign(0, int(keep[1])).unassign(2)
    assert edited.labels[0] == keep[1] and edited.labels[1] == -1 and edited.labels[2] == -1
    assert lab.labels[0] == keep[0]  # frozen: the original is unchanged
    with pytest.raises(ValueError, match="bead"):
        lab.assign(0, 99)
    with pytest.raises(ValueError, match="detection"):
        lab.unassign(-1)
    with pytest.raises(ValueError, match="two detections"):
        propagate_labels(tg, det, {0: "B01", 1: "B01"})
    few = propagate_labels(tg, det, {0: int(keep[0]), 1: int(keep[1])})
    assert not few.ok and "hints" in few.reason


def test_degenerate_views_fail_with_reasons(rig):
    tg = spiral_target(23)
    T = capture_poses(rig, tg, 1, rng=3)[0]
    g = np.random.default_rng(0)
    det, _ = _fake(rig, 0, tg, T, g, drop=18)
    lab = label_view(tg, det)
    assert not lab.ok and "only 5" in lab.reason and lab.n_labelled == 0
    empty = ObjectDetections(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), np.zeros(0, int), 4.0,
                             np.array([3.0, 5.0]), np.zeros(0))
    for t in (tg, cube_target()):  # a view with no detections
        lab = label_view(t, empty)
        assert not lab.ok and "only 0 detection" in lab.reason and lab.n_labelled == 0
    # all detections on one line (sizes and count of a real view): refused, not a 6-bead labelling
    det, _ = _fake(rig, 0, tg, T, g)
    s = np.linspace(0, 1, len(det))[:, None]
    line = ObjectDetections(np.array([100.0, 200.0]) + s * [800.0, 400.0], det.sigma, det.size_px,
                            det.size_class, det.px_per_mm, det.nominal_mm, det.snr)
    for t in (tg, cube_target()):
        lab = label_view(t, line)
        assert not lab.ok and "on a line" in lab.reason and lab.n_labelled == 0
    lab = fit_labels(tg, line, np.r_[np.arange(8), np.full(len(line) - 8, -1)])
    assert not lab.ok and lab.n_labelled == 0
    # a frame with an empty view fails with the reason; the other frames are labelled
    pair = [_fake(rig, v, tg, T, g, drop=2)[0] for v in range(2)]
    frames, _, _ = label_sequence(tg, [tuple(pair), (pair[0], empty)], rig=rig)
    assert frames[0].ok and not frames[1].ok and "only 0 detection" in frames[1].reason
    det, keep = _fake(rig, 0, tg, T, g)
    wrong = fit_labels(tg, det, g.permutation(keep))  # nonsense labels: no consistent camera
    assert not wrong.ok or wrong.n_labelled < 10
    with pytest.raises(ValueError, match="target"):
        label_view("spiral", det)


def test_size_classes():
    cls, scale = classify_sizes([8.1, 13.4, 7.9, 13.6, 30.0, np.nan], [3.0, 5.0])
    assert cls.tolist() == [0, 1, 0, 1, -1, -1] and scale == pytest.approx(2.7, rel=0.03)
    cls, _ = classify_sizes([4.0, 7.1, 10.6, 4.2], [1.78, 3.17, 4.76])
    assert cls.tolist() == [0, 1, 2, 0]
