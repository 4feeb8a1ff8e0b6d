"""flag_study's classification and the check it compares with (no tracking)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from core.studies.tracking.flag_study import classify, legacy_failures, main
from core.tracking.checks import failures
from core.tracking.options import TrackingOptions


def test_classify_large_over_4x_and_good():
    assert classify(1.2, 0.1, (0.05, 0.2)) == "large"
    assert classify(0.1, 2.5, None) == "large"
    assert classify(float("nan"), 0.1, None) == "large"
    assert classify(0.25, 0.1, (0.05, 0.2)) == "over_4x"
    assert classify(0.15, 0.7, (0.05, 0.2)) == "good"
    assert classify(0.5, 1.5, None) == "good"


def test_the_fixed_floor_flags_what_the_history_check_verifies():
    o = TrackingOptions()
    res = SimpleNamespace(score=0.38, converged=True, reason="", pose=np.eye(4))
    history = [0.58, *[0.40] * 10]  # a confirmed frame below the floor (0.406) is among them
    old = legacy_failures(res, np.eye(4), np.zeros(3), history, o, start_score=0.58)
    assert any(f.startswith("score below the start") for f in old)
    assert failures(res, np.eye(4), np.zeros(3), history, o, start_score=0.58) == []


def test_main_rejects_an_unknown_scene():
    with pytest.raises(SystemExit):
        main(["--scene", "knee"])


def test_features_and_separation_from_rows():
    from core.studies.tracking.flag_study import _features, separation

    rows = []
    for f in range(12):
        pose = np.eye(4)
        pose[0, 3] = 0.5 * f + (3.0 if f == 11 else 0.0)  # frame 11: 3 mm off a steady motion
        rows.append({"frame": f, "score": 0.5, "sigma": [0.1, 0.1, 0.1, 0.5, 0.5, 0.5], "flags": [],
                     "kind": "large" if f == 11 else "good",
                     "pose": [float(v) for v in pose[:3].ravel()]})
    _features(rows, np.zeros(3), 10)
    assert rows[11]["features"]["motion_rel"] > 1 and rows[10]["features"]["motion_rel"] < 0.5
    assert rows[11]["features"]["score_drop"] == 0.0
    sep = separation(rows)
    assert sep["motion_rel"]["auc"] == 1.0 and sep["motion_rel"]["good_flagged_to_catch_all"] == 0.0
    assert sep["sigma_deg"]["auc"] == 0.5


def test_the_previous_check_has_no_motion_check():
    from core.studies.tracking.flag_study import previous_failures

    o = TrackingOptions()
    hist = []
    for f in range(10):
        p = np.eye(4)
        p[0, 3] = 0.5 * f
        hist.append((f, p))
    off = np.eye(4)
    off[0, 3] = 0.5 * 10 + 3.0
    res = SimpleNamespace(score=0.5, converged=True, reason="", pose=off)
    kw = {"start_score": 0.5, "history": hist, "frame": 10}
    assert previous_failures(res, off, np.zeros(3), [0.5] * 10, o, **kw) == []
    assert failures(res, off, np.zeros(3), [0.5] * 10, o, **kw)
