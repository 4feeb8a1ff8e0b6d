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
