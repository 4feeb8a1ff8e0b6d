"""The excess-over-the-bound decomposition of stored acceptance runs
(core.studies.tracking.excess_decomposition)."""

import json

import numpy as np

from core.studies.tracking.excess_decomposition import decompose, main

SIGMA = np.array([0.01, 0.02, 0.01, 0.1, 0.1, 0.2])


def _record(E, flagged=()):
    return {"per_frame_error": np.asarray(E).tolist(), "frames_with_pose": list(range(len(E))),
            "flagged_frames": list(flagged),
            "cramer_rao": {"sigma": SIGMA.tolist(), "rms_mm": float(np.sqrt(np.sum(SIGMA[:3] ** 2))),
                           "rms_deg": float(np.sqrt(np.sum(SIGMA[3:] ** 2)))}}


def test_efficient_errors_have_no_excess():
    E = np.random.default_rng(0).standard_normal((4000, 6)) * SIGMA
    d = decompose(_record(E))
    for u in ("mm", "deg"):
        x = d[u]
        assert abs(x["ratio"] - 1) < 0.03 and abs(x["parts"]["white"] - 1) < 0.06
        assert x["parts"]["bias"] < 0.01 and abs(x["parts"]["slow"]) < 0.06
        p = x["parts"]
        assert abs(p["bias"] + p["slow"] + p["white"] - 1 - p["excess"]) < 1e-3
        got, want = x["per_frame_ratio"], x["per_frame_ratio_if_efficient"]
        assert abs(got["q50"] - want["q50"]) < 0.05 and abs(got["q90"] - want["q90"]) < 0.08
        assert all(abs(a["lag1"]) < 0.06 for a in x["axes"].values())


def test_bias_drift_and_outliers_are_told_apart():
    g = np.random.default_rng(1)
    n = 100
    white = g.standard_normal((n, 6)) * SIGMA
    bias = white + 1.0 * SIGMA  # one σ on every axis, every frame: bias part 1, white part 1
    d = decompose(_record(bias))["mm"]
    assert 0.8 < d["parts"]["bias"] < 1.2 and d["ratio_without_bias"] < 1.2
    assert d["axes"]["tx"]["mean_t"] > 4
    drift = white + np.outer(2 * np.sin(np.linspace(0, 2 * np.pi, n)), SIGMA)  # slow runs of biased frames
    d = decompose(_record(drift))["deg"]
    assert 1.5 < d["parts"]["slow"] < 2.5 and d["parts"]["bias"] < 0.1
    assert abs(d["parts"]["white"] - 1) < 0.35 and d["axes"]["rz"]["lag1"] > 0.5
    few = white.copy()
    few[[10, 50, 90]] += 10 * SIGMA  # three frames far off: carried by few frames
    d = decompose(_record(few, flagged=[10, 50]))["mm"]
    assert d["ratio"] > 1.5 and d["ratio_without_largest"]["3"] < 1.2
    assert sorted(d["largest_frames"][:3]) == [10, 50, 90]
    assert d["per_frame_ratio"]["q50"] < 1.1 * d["per_frame_ratio_if_efficient"]["q50"]
    assert d["ratio_unflagged"] < d["ratio"] and d["per_frame_ratio"]["top5_share"] > 0.5


def test_main_reads_stored_runs(tmp_path, capsys):
    E = np.random.default_rng(2).standard_normal((30, 6)) * SIGMA
    run = {"config": {"mode": "joint", "seed": 4},
           "tracking": {"talus": _record(E), "tibia": {"per_frame_error": []}}}
    p = tmp_path / "a.json"
    p.write_text(json.dumps({"seed": 4, "runs": {"joint": run}}))
    out = tmp_path / "o.json"
    assert main([str(p), "--out", str(out)]) == 0
    d = json.loads(out.read_text())
    assert list(d["seeds"]["4"]["runs"]["joint"]) == ["talus"]  # a bone without a bound is left out
    assert d["seeds"]["4"]["runs"]["joint"]["talus"]["frames"] == 30
    assert "searched" not in d["seeds"]["4"]["runs"]["joint"]["talus"]  # no signals kept


def test_the_searched_poses_are_decomposed_where_kept():
    from core.studies.tracking.excess_decomposition import searched

    E = np.random.default_rng(3).standard_normal((20, 6)) * SIGMA
    t = _record(E)
    assert searched(t) is None
    t["per_frame_signals"] = {"search_error": [None] * 19 + [(E[19] + 1).tolist()]}
    s = searched(t)
    assert np.array_equal(s["per_frame_error"][:19], t["per_frame_error"][:19])
    assert s["per_frame_error"][19] == (E[19] + 1).tolist() and t["per_frame_error"][19] == E[19].tolist()
