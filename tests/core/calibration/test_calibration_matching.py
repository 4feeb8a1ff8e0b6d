"""Epipolar geometry: 7/8-point fundamental matrices, RANSAC, two-view label resolution."""

from dataclasses import replace

import numpy as np
import pytest

from core.calibration.detection import ObjectDetections
from core.calibration.labelling import label_view
from core.calibration.matching import (
    fundamental_7point,
    fundamental_8point,
    label_sequence,
    ransac_fundamental,
    resolve_frame,
    sampson_distance,
    transfer_labels,
)
from core.calibration.objects import spiral_target
from core.markers import fundamental_matrix
from core.synthetic.capture import capture_centre, capture_poses


def _same_F(A, B):
    A, B = A / np.linalg.norm(A), B / np.linalg.norm(B)
    return min(np.abs(A - B).max(), np.abs(A + B).max())


@pytest.fixture(scope="module")
def points(rig):
    g = np.random.default_rng(0)
    X = capture_centre(rig) + g.uniform(-60, 60, (40, 3))
    return rig[0].project(X), rig[1].project(X)


def test_eight_and_seven_point_match_the_rig(rig, points):
    x1, x2 = points
    F = fundamental_matrix(rig[0], rig[1])
    F8 = fundamental_8point(x1, x2)
    assert _same_F(F8, F) < 1e-6
    assert np.linalg.matrix_rank(F8, tol=1e-10) == 2
    sols = fundamental_7point(x1[:7], x2[:7])
    assert 1 <= len(sols) <= 3
    assert min(_same_F(S, F) for S in sols) < 1e-5
    assert sampson_distance(F8, x1, x2).max() < 1e-6
    with pytest.raises(ValueError, match="8"):
        fundamental_8point(x1[:5], x2[:5])


def test_ransac_rejects_outliers(rig, points):
    x1, x2 = points
    g = np.random.default_rng(1)
    x2n = x2 + g.normal(0, 0.1, x2.shape)
    bad = g.choice(len(x1), 12, replace=False)
    x2n[bad] = g.uniform(100, 900, (12, 2))
    for method in ("7point", "8point"):
        fit = ransac_fundamental(x1, x2n, method=method, threshold_px=1.0, iterations=300, rng=2)
        assert not fit.inliers[bad].any()
        assert fit.inliers.sum() >= len(x1) - 12 - 1
        assert _same_F(fit.F, fundamental_matrix(rig[0], rig[1])) < 2e-3


def _fake(rig, v, tg, T, g, drop=0):
    uv = rig[v].project(tg.centers_lab(T))
    keep = g.permutation(len(uv))[: len(uv) - drop]
    return ObjectDetections(uv[keep] + g.normal(0, 0.05, (len(keep), 2)), np.zeros((len(keep), 2)),
                            tg.diameters[keep] * 4.5, tg.size_classes[1][keep], 4.5,
                            tg.size_classes[0], np.ones(len(keep))), keep


def test_resolution_picks_consistent_labellings_and_transfers_labels(rig):
    tg = spiral_target(23)
    assert len(tg.symmetries) == 2  # odd alternating helix: its two ends look alike
    T = capture_poses(rig, tg, 1, rng=8)[0]
    g = np.random.default_rng(3)
    d1, d2 = _fake(rig, 0, tg, T, g)[0], _fake(rig, 1, tg, T, g)[0]
    F = fundamental_matrix(rig[0], rig[1])
    l1, l2 = label_view(tg, d1), label_view(tg, d2)
    # force opposite members of the symmetric pair: only one pairing is epipolar-consistent
    l2 = replace(l2, labels=l2.alternatives[0], alternatives=(l2.labels,))
    fr = resolve_frame((l1, l2), F, target=tg)
    assert fr.ok and fr.distance_px < 0.2
    o1, o2 = (lab.observed() for lab in fr.labellings)
    k = np.all(np.isfinite(o1), axis=1) & np.all(np.isfinite(o2), axis=1)
    assert k.sum() >= 15 and sampson_distance(F, o1[k], o2[k]).max() < 0.5
    # view 2 labelled from view 1 alone
    moved = transfer_labels(fr.labellings[0], d2, F, tg, source_view=0)
    assert moved.ok and moved.n_labelled >= 18
    same = fr.labellings[1].labels
    assert np.array_equal(moved.labels[(moved.labels >= 0) & (same >= 0)],
                          same[(moved.labels >= 0) & (same >= 0)])
    # a view without a labelling makes the frame fail with the reason
    bad = resolve_frame((l1, label_view(tg, _fake(rig, 1, tg, T, g, drop=19)[0])), F)
    assert not bad.ok and "no labelling" in bad.reason


def test_sequence_with_estimated_F_matches_the_rig(rig):
    tg = spiral_target(23)
    poses = capture_poses(rig, tg, 6, rng=9)
    g = np.random.default_rng(4)
    dets, truth = [], []
    for T in poses:
        pair = [_fake(rig, v, tg, T, g, drop=int(g.integers(0, 3))) for v in range(2)]
        dets.append(tuple(p[0] for p in pair))
        truth.append([p[1] for p in pair])
    frames, obs, F = label_sequence(tg, dets)
    assert _same_F(F, fundamental_matrix(rig[0], rig[1])) < 5e-3
    assert sum(fr.ok for fr in frames) >= 5 and len(obs) == sum(fr.ok for fr in frames)
    for fr, kk in zip(frames, truth, strict=True):
        if fr.ok:
            assert any(all(np.array_equal(p[kk[v]][lab.labels >= 0], lab.labels[lab.labels >= 0])
                           for v, lab in enumerate(fr.labellings)) for p in tg.symmetries)
    with pytest.raises(ValueError, match="detections"):
        label_sequence(tg, [dets[0][0]])


def test_inconsistent_labels_are_removed_and_a_bad_pairing_is_rejected(rig):
    tg = spiral_target(23)
    T = capture_poses(rig, tg, 1, rng=8)[0]
    g = np.random.default_rng(5)
    d1, d2 = _fake(rig, 0, tg, T, g)[0], _fake(rig, 1, tg, T, g)[0]
    F = fundamental_matrix(rig[0], rig[1])
    l1, l2 = label_view(tg, d1), label_view(tg, d2)
    fr = resolve_frame((l1, l2), F, target=tg)
    assert fr.ok
    good = fr.labellings[1].labels
    i, j = np.flatnonzero(good >= 0)[:2]
    swapped = good.copy()
    swapped[[i, j]] = good[[j, i]]  # two labels swapped by hand in view 2
    fr2 = resolve_frame((fr.labellings[0], replace(l2, labels=swapped, alternatives=())), F, target=tg)
    assert fr2.ok and fr2.labellings[1].labels[i] == -1 and fr2.labellings[1].labels[j] == -1
    # half the labels of view 2 shuffled: no consistent pair
    bad = good.copy()
    idx = np.flatnonzero(good >= 0)[::2]
    bad[idx] = np.roll(good[idx], 1)
    fr3 = resolve_frame((fr.labellings[0], replace(l2, labels=bad, alternatives=())), F, target=tg)
    assert not fr3.ok and "consistent" in fr3.reason


def test_unambiguous_views_with_few_common_beads(rig):
    """The cube has no symmetry: two single-answer labellings sharing only 5 beads are checked on
    those (all on their lines), not refused; a wrong label among them, or 3 common beads, is."""
    from core.calibration.labelling import fit_labels
    from core.calibration.objects import cube_target

    tg = cube_target()
    T = capture_poses(rig, tg, 1, rng=4)[0]
    F = fundamental_matrix(rig[0], rig[1])
    g = np.random.default_rng(2)

    def view(v, beads):
        uv = rig[v].project(tg.centers_lab(T))[beads] + g.normal(0, 0.05, (len(beads), 2))
        det = ObjectDetections(uv, np.zeros((len(beads), 2)), tg.diameters[beads] * 4.5,
                               tg.size_classes[1][beads], 4.5, tg.size_classes[0], np.ones(len(beads)))
        lab = fit_labels(tg, det, np.asarray(beads), overlap=0)
        assert lab.ok and np.array_equal(lab.labels, beads)
        return lab

    l1, l2 = view(0, np.arange(8)), view(1, np.arange(3, 15))  # beads 3-7 in both views
    fr = resolve_frame((l1, l2), F, target=tg)
    assert fr.ok and fr.labellings[0].n_labelled == 8 and fr.labellings[1].n_labelled == 12
    wrong = l2.labels.copy()
    wrong[[0, 4]] = wrong[[4, 0]]  # beads 3 and 7 swapped in view 2
    fr = resolve_frame((l1, replace(l2, labels=wrong)), F, target=tg)
    assert not fr.ok and "consistent" in fr.reason
    fr = resolve_frame((l1, view(1, np.arange(5, 15))), F, target=tg)  # beads 5-7 only
    assert not fr.ok and "fewer than 4" in fr.reason
