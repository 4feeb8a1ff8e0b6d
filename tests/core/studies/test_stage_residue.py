"""core.studies.tracking.stage_residue on a tiny scene: the stage from a pose, the move check over a
stretch, the stopping rules' and the confirmation's parts, and the flag study on a stored run."""

import json

import numpy as np
import pytest

from core.studies.tracking import stage_residue as sr


@pytest.fixture(scope="module")
def scene():
    from core.studies.tracking.acceptance import TrackingScene

    return TrackingScene(n_frames=3, pixels=64, spacing=2.0, seed=4, device="cpu", correction="exact",
                         phase=(0.0, 0.018))


def test_move_verdicts_follow_the_tracker_check():
    rows = [{"move_mm": 0.01, "sigma_move": [0.01, 0.0, 0.0]} for _ in range(6)]
    rows.append({"move_mm": 0.2, "sigma_move": [0.2, 0.0, 0.0]})  # 20x the median, over half its σ
    rows.append({"move_mm": 0.2, "sigma_move": [0.5, 0.0, 0.0]})  # within half its σ
    v = sr.move_verdicts(rows)
    assert v[:6] == [None] * 6 and v[6].startswith("uncertain (the final stage moved") and v[7] is None
    assert sr.move_verdicts(rows[:4] + rows[6:7]) == [None] * 5  # too few frames before it


def test_exact_steps_restores_the_rule():
    import core.tracking.engine_likelihood as el
    import core.tracking.final_stage as fst

    before = (el.STOP_PRED, fst.ROBUST_FROM_LAST)
    with sr.exact_steps():
        assert (el.STOP_PRED, fst.ROBUST_FROM_LAST) == (0.0, False)
    assert (el.STOP_PRED, fst.ROBUST_FROM_LAST) == before


def test_stage_parts(scene, tmp_path):
    stored = tmp_path / "run.json"
    zero = {"per_frame_error": np.zeros((3, 6)).tolist(), "frames_with_pose": [0, 1, 2]}
    stored.write_text(json.dumps({"runs": {"joint": {"config": {"frames": 3}, "tracking": {
        "talus": zero, "calcaneus": zero}}}}))
    out = sr.run(ts=scene, parts=("start", "confirm"), calcaneus=(1,), confirm=(1,), talus=(),
                 runs={"run": str(stored)})
    rows = out["start"]
    assert [(r["bone"], r["rule"]) for r in rows] == [("calcaneus", k) for k in sr.STOP_RULES] + [
        ("talus", k) for k in sr.STOP_RULES]
    for r in rows:  # the stored pose is the truth here: both starts the same, the same result
        assert r["spread"] == [0.0] * 6 and len(r["truth"]["error"]) == 6 and r["truth"]["steps"] >= 1
        assert r["truth"]["start"] == [0.0] * 6
    (c,) = out["confirm"]
    assert c["frame"] == 1 and c["start"] == "run" and isinstance(c["confirmed"], bool)
    assert c["apart_mm"] >= 0 and "pose" not in c["first"]


def test_highpass_part(scene):
    out = sr.run(ts=scene, parts=("highpass",), highpass_frames=(1,), talus=(), runs={})
    (row,) = out["highpass"]["rows"]
    assert set(row) == {"frame"} | {f"{k}_hp{h:g}" for k in ("noisy", "noise_free") for h in sr.HIGHPASS_1024}
    s = out["highpass"]["summary"]["noisy_hp4"]
    assert s["n"] == 1 and np.allclose(s["rms"], np.abs(row["noisy_hp4"]), atol=1e-4)


def test_flag_study(tmp_path):
    E = np.zeros((10, 6))
    E[8, 0] = 0.5  # 10x the bound: silent
    E[9, 0] = 0.5  # flagged
    sig = [[0.05, 0.05, 0.05, 0.1, 0.1, 0.1]] * 10
    t = {"per_frame_error": E.tolist(), "frames_with_pose": list(range(10)), "per_frame_sigma": sig,
         "cramer_rao": {"rms_mm": 0.05, "rms_deg": 0.1}, "flagged_frames": [9]}
    p = tmp_path / "run.json"
    p.write_text(json.dumps({"runs": {"joint": {"config": {"frames": 10}, "tracking": {"talus": t}}}}))
    out = sr.flag_study([str(p)])
    (d,) = out.values()
    assert [x["frame"] for x in d["silent"]] == [8]
    assert d["silent"][0]["error_over_sigma"] == 10.0 and d["silent"][0]["sigma_ratio"] == 1.0
    assert d["within_2_sigma_silent"] == 0 and d["good_frames"] == 8
    assert d["rules_silent_good"]["sigma_mm>0.1"] == [0, 0]
