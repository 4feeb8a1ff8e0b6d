"""The §4.3 harness at small sizes: it runs, writes its figures and meets the acceptance bars."""

import json

import numpy as np

from core.studies.markers.study import StudyConfig, convergence, drift_and_distances, initial_guesses


def test_initial_guesses_come_from_the_temporal_mean(lattice, lattice_frames):
    g = initial_guesses(lattice, lattice_frames)
    assert np.all(np.isfinite(g)) and np.abs(g - lattice.uv).max() < 0.3


def test_drift_and_intermarker_tables(lattice, lattice_frames):
    drift, dist = drift_and_distances(lattice, lattice_frames, methods=("intensity_centroid", "robust"))
    json.dumps([drift, dist])
    rob = drift["robust"]
    assert rob["rms"] <= 0.05 and rob["failed_fraction"] == 0.0
    assert 0.75 < rob["scatter_over_predicted"] < 1.33
    assert dist["robust"]["sigma"] <= 0.035 and abs(dist["robust"]["mu"]) < 0.01
    assert dist["robust"]["n"] == 30 * 24
    # the plain centre of gravity is the least stable (thesis Table 4.1 ordering)
    assert drift["intensity_centroid"]["rms"] > 2 * rob["rms"]


def test_convergence_from_perturbed_guesses(lattice, lattice_frames):
    cfg = StudyConfig(n_frames=30, n_mc=30, levels_percent=(0.0, 300.0))
    conv = convergence(lattice, lattice_frames, cfg, methods=("robust", "gaussian_centroid"))
    rob = conv["robust"]
    assert [c["level_percent"] for c in rob] == [0.0, 300.0]
    assert max(c["mean"] for c in rob) < 0.1 and rob[-1]["failed_fraction"] == 0.0
    assert conv["gaussian_centroid"][-1]["mean"] > 1.0


def test_benchmark_smoke_run_reports_json():
    from core.studies.markers.benchmark import bead_grid_frames, run_benchmark

    frames, _, dia = bead_grid_frames(6, 2)
    assert frames.shape == (2, 128, 128)
    np.testing.assert_allclose(sorted(set(np.round(dia, 2))), [6.16, 9.24], atol=0.01)
    res = run_benchmark(n_beads=6, n_frames=3, repeats=1)
    json.dumps(res)
    rob = res["robust"]["threads"]
    assert rob["localisations"] == 18 and rob["ok_fraction"] == 1.0 and rob["rms_error_px"] < 0.1
    assert set(res["other_methods"]) == {"intensity_centroid", "gaussian_centroid", "iterative_gaussian",
                                         "iterative_sigmoid", "template_gaussian", "template_sigmoid"}
