"""core.studies.tracking.joint_gap: the stored runs' analysis (joint − sequential against the
prediction's offset) on made-up per-frame errors, and the pose rebuilt from an error."""

from __future__ import annotations

import json

import numpy as np
import pytest


def _runs(k: float, n: int = 60, seed: int = 0):
    """Sequential per-frame errors (a smooth walk plus noise) and joint's = sequential's less ``k``
    times the constant-velocity prediction's offset from it (module docs' model), per bone."""
    g = np.random.default_rng(seed)
    S = np.cumsum(g.normal(0, 0.02, (n, 6)), axis=0) + g.normal(0, 0.05, (n, 6))
    J = S.copy()
    J[2:] -= k * ((2 * S[1:-1] - S[:-2]) - S[2:])
    return J, S


def test_stored_recovers_the_share_of_the_start(tmp_path):
    from core.studies.tracking.joint_gap import stored

    J, S = _runs(0.06)
    frames = list(range(len(S)))

    def acc(E):
        return {"tracking": {"tibia": {"frames_with_pose": frames, "per_frame_error": E.tolist()}}}

    p = tmp_path / "acc.json"
    p.write_text(json.dumps({"runs": {"joint": acc(J), "sequential": acc(S)}}))
    seeds = tmp_path / "seeds.json"
    J2, S2 = _runs(0.0, seed=1)
    J2 = J2 + np.random.default_rng(2).normal(0, 0.01, J2.shape)  # unrelated to the prediction
    seeds.write_text(json.dumps({"runs": {"seed_1": {"runs": {
        "joint": {"tibia": {"frames": frames, "per_frame_error": J2.tolist()}},
        "sequential_subtracted": {"tibia": {"frames": frames, "per_frame_error": S2.tolist()}}}}}}))
    out = stored(str(p), str(seeds), held_out=())
    axes = out["bones"]["tibia"]["axes"]
    assert out["bones"]["tibia"]["frames"] == len(S) - 2
    for row in axes:
        assert abs(row["start_share_k"] - 0.06) < 1e-6
        assert row["corr_with_prediction_offset"] < -0.999
    for row in out["seeds"]["seed_1"]["tibia"]["axes"]:
        assert abs(row["start_share_k"]) < 0.05 and abs(row["corr_with_prediction_offset"]) < 0.5


def test_pose_from_an_error_is_the_inverse_of_pose_errors():
    from core.geometry.transforms import pose_from_params
    from core.studies.tracking.acceptance import pose_errors
    from core.studies.tracking.joint_gap import _pose

    c = np.array([10.0, -5.0, 30.0])
    truth = pose_from_params(np.array([1.0, 2.0, 3.0, 0.1, -0.2, 0.3]), center=c)
    e = np.array([0.05, -0.02, 0.03, 0.2, -0.1, 0.4])
    np.testing.assert_allclose(pose_errors(_pose(e, truth, c), truth, c), e, atol=1e-9)


def test_probe_summary_on_made_up_registrations():
    """probe_summary: each case's RMS, the pairs, and the start's share kept (a case halfway between
    the optimum and the start keeps 0.5 of it)."""
    from core.studies.tracking.joint_gap import CASES, PAIRS, probe_summary

    g = np.random.default_rng(3)
    rows = []
    for _ in range(12):
        opt, start = g.normal(0, 0.1, 6), g.normal(0, 0.3, 6)
        errs = {c: opt + 0.01 * g.normal(size=6) for c in CASES}
        errs["opt"] = opt
        errs["S"] = opt + 0.5 * (start - opt)
        rows.append({"errors": {c: [e.tolist()] for c, e in errs.items()}, "start_errors": [start.tolist()]})
    s = probe_summary(rows, ["tibia"])["tibia"]
    assert s["S"]["start_kept_rotation"] == 0.5
    assert abs(s["J1"]["start_kept_rotation"]) < 0.1
    assert s["J1"]["vs_S_deg"]["verdict"] == "better"  # at the (smaller) optimum, not halfway to the start
    assert set(s["pairs"]) == {f"{a}-{b}" for a, b, _ in PAIRS}
    assert len(s["opt"]["rms_deg_per_axis"]) == 3


def test_pool_stretches_pairs_every_stretch_frame():
    from core.studies.tracking.joint_gap import pool_stretches

    g = np.random.default_rng(4)

    def one(n):
        S = g.normal(0, 0.1, (n, 6))
        runs = {"joint": S * 1.1, "sequential": S}
        return {"frames": list(range(n)), "paired": {"joint_vs_sequential": {}},
                "runs": {k: {"s": 1.0, "tibia": {"per_frame_error": E.tolist()}} for k, E in runs.items()}}

    out = pool_stretches([one(8), one(12)])
    assert out["frames"] == 20
    p = out["paired"]["joint_vs_sequential"]["tibia"]["deg"]
    assert p["verdict"] == "worse" and p["rms_difference"] > 0
    assert abs(out["rms"]["joint"]["tibia"]["deg"] / out["rms"]["sequential"]["tibia"]["deg"] - 1.1) < 1e-3


def test_acceptance_restart_runs_each_variant_on_one_scene(monkeypatch):
    """acceptance_restart: every run on the same scene, with its switch and rounds (both restored
    after), and the comparisons named after the runs (the study itself replaced: a GPU's work)."""
    import core.studies.tracking.acceptance as acc
    import core.tracking.frame_step as fs
    from core.studies.tracking.joint_gap import acceptance_restart

    scene = object()
    seen = []

    def fake_run(*, mode, ts, quick=True, **k):
        o = acc.study_options(mode)
        seen.append((mode, ts is scene, fs.RESTART_FROM_PREDICTION, o.joint_rounds))
        assert quick is False  # the runs say the scene's size (acc.run's own default is quick)
        return {"config": {"frames": 1}, "tracking": {}}

    monkeypatch.setattr(acc, "tracking_scene", lambda **k: scene)
    monkeypatch.setattr(acc, "run", fake_run)
    out = acceptance_restart(quick=False)
    assert seen == [("joint", True, False, 2), ("joint", True, True, 2), ("joint", True, False, 1),
                    ("sequential", True, False, 1)]  # joint as it was measured: two rounds, pinned
    assert not fs.RESTART_FROM_PREDICTION and acc.study_options("joint").joint_rounds == 1  # the default
    assert set(out) >= {"joint_vs_sequential", "joint_restart_vs_sequential", "joint_restart_vs_joint",
                        "joint_one_round_vs_sequential", "joint_one_round_vs_joint"}


def test_paired_by_frame_resamples_a_frames_draws_together():
    """Two draws of each frame that share the frame's offset (its start and scene): resampled as
    independent registrations the interval is too narrow; by frame it is that of the frames' means."""
    from core.studies.tracking.hard_trial_stats import paired_comparison
    from core.studies.tracking.joint_gap import paired_by_frame

    g = np.random.default_rng(5)
    n = 10
    seq = np.abs(g.normal(1.0, 0.1, 2 * n))
    shared = np.repeat(g.normal(0.0, 0.05, n), 2)  # joint - sequential, the same for both draws
    joint = seq + 0.01 + shared
    frames = np.repeat(np.arange(n), 2)
    by_frame = paired_by_frame(seq, joint, frames)
    alone = paired_by_frame(seq, joint, np.arange(2 * n))
    assert by_frame["n_frames"] == n and alone["n_frames"] == 2 * n
    assert by_frame["rms_difference"] == alone["rms_difference"]
    w = np.diff(by_frame["interval95"])[0]
    assert w > 1.25 * np.diff(alone["interval95"])[0]
    # one registration a frame: the frames' bootstrap is paired_comparison's with blocks of one
    one = paired_comparison(seq[::2], joint[::2], margin=0.0, block=1)
    mine = paired_by_frame(seq[::2], joint[::2], np.arange(n))
    assert mine["rms_difference"] == one["rms_difference"]
    assert np.allclose(mine["interval95"], one["interval95"], atol=0.3 * np.diff(one["interval95"])[0])
    # a NaN registration is left out with its pair
    j = joint.copy()
    j[0] = np.nan
    assert paired_by_frame(seq, j, frames)["n_frames"] == n


def test_probe_history_is_the_seeds_own_run():
    """The probe starts from the stored run of its own scene seed: seed 3 and 4 no longer from
    seed 0's history; another seed's known run is refused (main too)."""
    from core.studies.tracking import joint_gap as jg

    assert jg.history_for(0) == jg.ACCEPTANCE_JSON
    # seed 3: today's synthesis
    assert jg.history_for(3).endswith("tracking_joint_restart_acceptance_seed3_h100.json")
    assert jg.history_for(4) == jg.HELD_OUT_JSONS[1]
    assert jg.history_for(3, jg.HELD_OUT_JSONS[0]) == jg.HELD_OUT_JSONS[0]  # 56350ae's seed 3, asked for
    with pytest.raises(ValueError, match="seed 3's run"):
        jg.history_for(4, jg.HELD_OUT_JSONS[0])
    with pytest.raises(ValueError, match="seed 0's run"):  # the same file written another way
        jg.history_for(4, "./" + jg.ACCEPTANCE_JSON.replace("benchmarks/", "benchmarks//"))
    # the stored runs the probe can start from hold per-frame joint errors by frame
    for seed in (3, 4):
        with open(jg.history_for(seed)) as fh:
            d = json.load(fh)
        assert len(jg._per_frame(d, "joint", "tibia")) == 100
    assert jg.history_for(4, "mine.json") == "mine.json"  # an unknown file: the caller's word
    with pytest.raises(ValueError, match="seed 0's run"):
        jg.history_for(3, jg.ACCEPTANCE_JSON)
    with pytest.raises(ValueError, match="no stored run"):
        jg.history_for(7)
    with pytest.raises(SystemExit):
        jg.main(["--seed", "4", "--stored", jg.ACCEPTANCE_JSON])
