"""The study helpers on tiny configurations (the full study: python -m core.studies.calibration.study)."""

import numpy as np

from core.calibration.matching import label_sequence
from core.calibration.objects import spiral_target
from core.studies.calibration.labelling_study import projected_frames, score_frames
from core.studies.calibration.study import bundle_study, dlt_instability, error_maps, independent_object


def test_dlt_is_unstable_and_the_bundle_adjustment_is_not(rig):
    g = np.random.default_rng(0)
    dlt, dlt_rigs, dev = dlt_instability(rig, n_draws=30, noise_px=0.05, rng=g)
    ba, ba_rigs, _ = bundle_study(rig, n_frames=20, n_draws=1, noise_px=0.05, rng=g)
    assert dlt["n_draws"] == 30 and dev["sid"].shape == (30, 2)
    assert min(d["std"] for d in dlt["sid_mm"]) > 1.0  # the DLT's SID wanders by millimetres
    assert ba["n_ok"] == 1 and ba["sid_error_mm"]["max_abs"] < 1.0
    assert ba["source_error_max_mm"] < 1.0 < max(d["max_abs"] for d in dlt["source_error_mm"])
    maps, lattice, errs = error_maps(rig, dlt_rigs[:5], ba_rigs, noise_px=0.05, rng=g)
    assert errs["spiral_ba"].shape == (1, len(lattice)) and maps["n_points"] == len(lattice)
    assert maps["spiral_ba"]["calibration_only"]["rms_mm"] < maps["cube_dlt"]["calibration_only"]["rms_mm"]
    obj = independent_object(rig, ba_rigs, noise_px=0.05, rng=g)
    assert obj["fit_rms_mm"]["max_abs"] < 0.05


def test_labelling_score(rig):
    tg = spiral_target(23)
    g = np.random.default_rng(1)
    dets, truth = projected_frames(tg, rig, 4, rng=g)
    frames, _, _ = label_sequence(tg, dets, rng=0)
    missing = [max(len(tg) - len(d) for d in pair) for pair in dets]
    s = score_frames(frames, truth, tg, missing=missing)
    assert s["frames"] == 4 and s["correct"] + s["wrong"] + s["rejected"] == 4
    assert all(0 <= int(k) <= 3 for k in s["by_missing"])  # 0-3 beads removed per view
    assert sum(f for f, _ in s["by_missing"].values()) == 4
    assert sum(c for _, c in s["by_missing"].values()) == s["correct"]
    assert s["wrong"] == 0 and s["correct"] >= 3
    shuffled = [truth[1], truth[0], truth[3], truth[2]]  # wrong ground truth: nothing is correct
    assert score_frames(frames, shuffled, tg)["correct"] == 0
