"""core.studies.tracking.stage_one_bone's interleaved runs: the i-th stage call runs under variant
(i + shift) % k (its flags set inside the call only; a confirmation's call, TO_TOL, under the defaults and
not counted), and the summary's per-variant times and within-cycle differences against the first."""

from types import SimpleNamespace

import numpy as np


def test_stage_calls_take_the_variants_in_turn(monkeypatch):
    import core.tracking.final_stage as fst
    import core.tracking.likelihood_solve as ls
    from core.studies.tracking.stage_one_bone import _interleaving
    from core.tracking.engine_likelihood import TO_TOL

    seen = []

    def fake(*a, **k):
        seen.append(ls.LEAN_SOLVES)
        return SimpleNamespace(timing={"likelihood_s": 0.001 * len(seen)})

    monkeypatch.setattr(fst, "final_stage", fake)
    calls: list = []
    with _interleaving(("base", "nolean"), 1, calls):
        for _ in range(3):
            fst.final_stage()
        token = TO_TOL.set(True)
        try:
            fst.final_stage()  # (a confirmation: defaults, not counted)
        finally:
            TO_TOL.reset(token)
    assert fst.final_stage is fake and ls.LEAN_SOLVES is True
    assert seen == [False, True, False, True]
    assert [v for v, _ in calls] == ["nolean", "base", "nolean"]
    np.testing.assert_allclose([t for _, t in calls], [1.0, 2.0, 3.0])


def test_the_summary_pairs_each_cycle():
    from core.studies.tracking.stage_one_bone import _interleaved_summary

    runs = [[("a", 3.0), ("b", 2.5), ("a", 4.0), ("b", 3.0), ("a", 9.0)], [("b", 1.0), ("a", 2.0)]]
    s = _interleaved_summary(("a", "b"), runs)
    assert s["per_variant"]["a"]["calls"] == 4 and s["per_variant"]["b"]["calls"] == 3
    assert s["per_variant"]["a"]["stage_ms_median"] == 3.5
    d = s["cycle_difference_ms_against_a"]["b"]
    assert d["cycles"] == 3 and d["median"] == -1.0  # (-0.5, -1.0, -1.0)
