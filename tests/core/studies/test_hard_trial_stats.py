"""hard_trial's summary statistics: σ coverage with what a correct σ gives, the paired joint vs
sequential comparison, bias against spread, and several seeds joined."""

import numpy as np
import pytest

from core.studies.tracking import hard_trial as ht


def test_coverage_of_a_correct_sigma_matches_its_expected_values():
    g = np.random.default_rng(1)
    sig = np.tile([0.02, 0.03, 0.05, 0.1, 0.2, 0.3], (20000, 1))
    E = g.normal(size=sig.shape) * sig
    c = ht.coverage(E, sig)
    assert c["per_axis"]["expected"] == pytest.approx(0.9545, abs=1e-4)
    for k in ("all", "translation", "rotation"):
        assert c["per_axis"][k]["observed"] == pytest.approx(0.9545, abs=0.005)
    assert c["all_six"]["observed"] == pytest.approx(c["all_six"]["expected_independent"], abs=0.01)
    assert c["all_six"]["expected_independent"] == pytest.approx(0.9545 ** 6, abs=1e-3)
    assert c["chi2"]["covariance"] == "diagonal"
    assert c["chi2"]["within_2_sigma"]["observed"] == pytest.approx(0.9545, abs=0.005)
    assert c["chi2"]["within_90"]["observed"] == pytest.approx(0.90, abs=0.01)
    assert all(v == pytest.approx(1.0, abs=0.03) for v in c["z_rms"].values())
    assert c["mean_d2"] == pytest.approx(6.0, abs=0.1)
    assert c["checked_on"] == "per_axis" and c["met"]
    # σ half the true spread: the check fails; a frame without σ (inf or NaN on every axis) is left
    # out and counted apart
    assert not ht.coverage(E, sig / 2)["met"]
    sig2 = sig.copy()
    sig2[0] = np.inf
    sig2[1] = np.nan
    c2 = ht.coverage(E, sig2)
    assert c2["frames_without_sigma"] == 2 and c2["n_frames"] == len(E) - 2


def test_frames_without_sigma_are_left_out_not_covered():
    """As acceptance_goals.sigma_coverage: a run without confidence has no coverage (it met the goal
    at 100 %, every frame within an infinite σ); frames without σ among others are left out, counted
    as frames_without_sigma, in coverage and in merge_runs' per-axis fractions; an axis without σ
    beside others stays covered."""
    g = np.random.default_rng(6)
    sig = np.tile([0.01] * 3 + [0.05] * 3, (50, 1))
    E = 3 * g.choice([-1, 1], size=sig.shape) * sig  # every error 3 σ off
    none = np.full_like(sig, np.inf)
    c = ht.coverage(E, none)
    assert c["n_frames"] == 0 and c["frames_without_sigma"] == 50 and not c["met"]
    part = sig.copy()
    part[:40] = np.inf  # 40 frames without σ: they lifted the coverage to 80 %
    c = ht.coverage(E, part)
    assert c["frames_without_sigma"] == 40 and c["n_frames"] == 10
    assert c["per_axis"]["translation"]["observed"] == 0 and not c["met"]
    axis = sig * 0.1 + np.abs(E)  # covered everywhere ...
    axis[:, 0] = np.inf  # ... and tx unbounded: the frames are kept, covered on tx
    c = ht.coverage(E, axis)
    assert c["n_frames"] == 50 and c["frames_without_sigma"] == 0 and c["per_axis"]["axes"]["tx"] == 1.0
    stored = np.where(np.isfinite(part), part, -1)  # as hard_trial.evaluate stores them
    run = {**_run(E, stored), "per_frame_bound": np.tile([0.01, 0.05], (50, 1)).tolist()}
    merged = ht.merge_runs([{"config": {"seed": 0}, "runs": {"x": {"bones": {"talus": run}}}}])
    m = merged["x"]["bones"]["talus"]
    assert m["coverage"]["frames_without_sigma"] == 40 and m["coverage"]["n_frames"] == 10
    assert m["per_axis_within_2_sigma"] == 0 and m["within_2_sigma"] == 0


def test_correlated_errors_need_the_covariance_for_the_chi2_measure():
    g = np.random.default_rng(2)
    C = np.full((6, 6), 0.8) + 0.2 * np.eye(6)  # unit variances, correlation 0.8
    E = g.multivariate_normal(np.zeros(6), C, size=20000)
    sig = np.ones_like(E)
    diag = ht.coverage(E, sig)
    assert diag["per_axis"]["all"]["observed"] == pytest.approx(0.9545, abs=0.005)  # per axis unaffected
    assert diag["all_six"]["observed"] > 0.85  # between 75.6 % and 95.4 %
    assert diag["chi2"]["within_2_sigma"]["observed"] < 0.92  # diag(σ²) understates the frames inside
    full = ht.coverage(E, sig, [C] * len(E))
    assert full["chi2"]["covariance"] == "full"
    assert full["chi2"]["within_2_sigma"]["observed"] == pytest.approx(0.9545, abs=0.005)


def test_paired_comparison_decides_with_its_interval():
    g = np.random.default_rng(3)
    seq = np.abs(g.normal(0.1, 0.02, 40))
    same = ht.paired_comparison(seq, seq, margin=0.015)
    assert same["rms_difference"] == 0 and same["interval95"] == [0, 0]
    assert same["verdict"] == "not resolved" and same["at_least_as_good"]
    assert same["block"] == 4  # ceil(40^(1/3))
    worse = ht.paired_comparison(seq, seq + 0.03, margin=0.015)
    assert worse["verdict"] == "worse" and not worse["at_least_as_good"]
    slightly = ht.paired_comparison(seq, seq + 0.002 + g.normal(0, 0.001, 40), margin=0.015)
    assert slightly["verdict"] == "worse" and slightly["at_least_as_good"]  # worse, but within the margin
    better = ht.paired_comparison(seq, seq * 0.5, margin=0.015)
    assert better["verdict"] == "better" and better["share_joint_worse"] == 0
    nan = seq.copy()
    nan[0] = np.nan
    assert ht.paired_comparison(nan, seq, margin=0.015)["n_frames"] == 39


def test_error_structure_separates_bias_from_spread():
    g = np.random.default_rng(4)
    E = np.column_stack([np.full(30, 0.04), g.normal(0, 0.01, 30), np.zeros((30, 4))])
    s = ht.error_structure(E, np.full_like(E, 0.05), frames=[3])
    assert s["bias_share"]["tx"] == 1.0 and s["bias_share"]["ty"] < 0.5
    assert s["bias_norm"]["mm"] == pytest.approx(np.hypot(0.04, E[:, 1].mean()), abs=1e-4)
    f = s["frames"]["3"]
    assert f["less_mean"]["tx"] == 0 and f["within_2_sigma"] and f["largest"][0] in ("tx", "ty")


def _run(E, sig, bound=(0.01, 0.05)):
    E = np.asarray(E)
    et, er = np.linalg.norm(E[:, :3], axis=1), np.linalg.norm(E[:, 3:], axis=1)
    return {"rms_error_mm": float(np.sqrt(np.mean(et ** 2))),
            "rms_error_deg": float(np.sqrt(np.mean(er ** 2))),
            "within_2_sigma": 1.0, "per_axis_within_2_sigma": 1.0, "silent_failures": [],
            "per_frame_error": E.tolist(), "per_frame_sigma": np.asarray(sig).tolist(),
            "per_frame_bound": np.tile(bound, (len(E), 1)).tolist()}


def test_goals_use_the_paired_comparison_and_merged_seeds():
    g = np.random.default_rng(5)
    sig = np.tile([0.02] * 3 + [0.06] * 3, (20, 1))
    results = []
    for seed in (0, 1):
        Es = g.normal(size=(20, 6)) * sig
        Ej = Es + g.normal(0, 1e-4, Es.shape)
        results.append({"config": {"seed": seed},
                        "runs": {"c/l/sequential": {"bones": {"talus": _run(Es, sig)}},
                                 "c/l/joint": {"bones": {"talus": _run(Ej, sig)}}}})
    merged = ht.merge_runs(results)
    b = merged["c/l/joint"]["bones"]["talus"]
    assert len(b["per_frame_error"]) == 40 and b["coverage"]["n_frames"] == 40
    assert merged["c/l/joint"]["seeds"] == [0, 1]
    gl = ht.goals(merged)
    t = gl["c/l/joint"]["bones"]["talus"]
    assert t["paired"]["mm"]["n_frames"] == 40 and t["joint_ok"] and t["sigma_ok"]
    assert t["coverage_checked_on"] == "per_axis" and gl["c/l/joint"]["met"]
