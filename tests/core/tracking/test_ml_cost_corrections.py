"""ml_cost --final --correction: one correction or several in turn on the same frames (the exact
correction, a study-only oracle, beside the grid fit)."""

import argparse

import pytest

from core.studies.tracking import ml_cost


def test_corrections_are_parsed_and_checked():
    assert ml_cost._corrections("grid") == ("grid",)
    assert ml_cost._corrections("grid, exact") == ("grid", "exact")
    for bad in ("", "truth", "grid,grid", "grid,model,truth"):
        with pytest.raises(argparse.ArgumentTypeError):
            ml_cost._corrections(bad)


def test_main_passes_one_correction_as_a_name_and_several_as_a_tuple(monkeypatch):
    import core.io.atomic

    seen = {}
    monkeypatch.setattr(ml_cost, "run_final", lambda **kw: seen.update(kw) or {})
    monkeypatch.setattr(core.io.atomic, "print_json", lambda *a, **k: None)
    ml_cost.main(["--final", "--correction", "exact"])
    assert seen["correction"] == "exact"
    ml_cost.main(["--final", "--correction", "grid,exact", "--cases", "tibia,three"])
    assert seen["correction"] == ("grid", "exact") and seen["cases"] == ["tibia", "three"]
    assert seen["erode_px"] is None
    ml_cost.main(["--final", "--erode-px", "12"])
    assert seen["erode_px"] == 12
    with pytest.raises(SystemExit):
        ml_cost.main(["--final", "--correction", "truth"])
