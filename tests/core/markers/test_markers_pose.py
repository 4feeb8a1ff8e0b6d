"""Epipolar geometry, matching, rigid fits and marker-based pose of a moving synthetic bone."""

import numpy as np
import pytest

from core.geometry import make_rigid, rotvec_to_matrix
from core.markers import epipolar_distance, fundamental_matrix, match_epipolar, rigid_fit
from core.studies.markers.motion_study import moving_bone_study
from core.synthetic import foot_rig


@pytest.fixture(scope="module")
def rig():
    return foot_rig(seed=3, pixels=512)


def test_fundamental_matrix_puts_projections_on_epipolar_lines(rig):
    X = np.random.default_rng(0).uniform(-60, 60, (30, 3))
    a, b = rig[0].project(X), rig[1].project(X)
    F = fundamental_matrix(rig[0], rig[1])
    D = epipolar_distance(F, a, b)
    assert np.abs(np.diag(D)).max() < 1e-6
    assert np.median(D[~np.eye(30, dtype=bool)]) > 5.0  # other points are far from the lines


def test_match_epipolar_recovers_a_shuffled_correspondence(rig):
    g = np.random.default_rng(1)
    X = g.uniform(-50, 50, (12, 3))
    a = rig[0].project(X) + g.normal(0, 0.2, (12, 2))
    perm = g.permutation(12)
    b = rig[1].project(X)[perm] + g.normal(0, 0.2, (12, 2))
    m = match_epipolar(rig[0], rig[1], a, b, max_distance=1.5)
    found = dict(m.pairs.tolist())
    correct = sum(perm[found[i]] == i for i in found)
    assert correct >= 10 and correct >= len(found) - np.sum(m.ambiguous)
    with pytest.raises(ValueError, match="max_distance"):
        match_epipolar(rig[0], rig[1], a, b, max_distance=-1)


def test_rigid_fit_kabsch_umeyama_and_missing_points():
    g = np.random.default_rng(2)
    X = g.uniform(-30, 30, (6, 3))
    T = make_rigid(rotvec_to_matrix([0.3, -0.2, 0.5]), [10.0, -4.0, 7.0])
    Y = X @ T[:3, :3].T + T[:3, 3]
    fit = rigid_fit(X, Y)
    np.testing.assert_allclose(fit.T, T, atol=1e-9)
    assert fit.rms < 1e-9 and fit.n_used == 6
    sim = rigid_fit(X, 1.5 * Y, scale=True)
    assert sim.scale == pytest.approx(1.5) and sim.rms < 1e-9
    Yn = np.stack([Y, Y.copy()])
    Yn[1, :4] = np.nan  # only two points left in frame 1
    Yn[0, 0] += [0.0, 0.0, 1.0]  # one displaced point shows in the residuals
    fits = rigid_fit(X, Yn)
    assert fits.n_used.tolist() == [6, 2] and np.all(np.isnan(fits.T[1]))
    assert np.argmax(fits.residuals[0]) == 0 and np.all(np.isnan(fits.residuals[1, :4]))
    with pytest.raises(ValueError, match="observed"):
        rigid_fit(X, Y[:4])


def test_pose_of_a_moving_bone_from_its_beads():
    res = moving_bone_study(n_frames=8, rotation_deg=12.0, translation_mm=15.0, seed=1)
    assert res["frames_without_pose"] == 0 and res["tracked_fraction"] == 1.0
    assert res["reprojection_rms_px"] < 0.3
    assert res["rotation_error_deg"]["rms"] <= 0.05
    assert res["position_error_mm"]["rms"] <= 0.05
