"""The pair-rule study (core.studies.tracking.trajectory_pairs) on the stored seed-3 runs: the poses rebuilt
from the kept errors give the runs' stored trajectory flags without the rule, and with it the tibia's
frames 69 and 70 (jointly, frame 70 4.7x its bound and silent at 6c8beab) are flagged."""

from __future__ import annotations

from core.studies.tracking.trajectory_pairs import counts, runs


def test_seed3_stage_runs_rebuilt_and_the_pair_caught():
    rs = [r for r in runs(seeds={"3"}) if r["run"][1] == "stage"]
    got = counts(rs, 1.0, 0.7)
    assert all(row["reproduced"] for run in got["runs"].values() for row in run.values())
    tibia = got["runs"]["3_stage_joint"]["tibia"]
    assert tibia["silent_off"] == [70] and tibia["silent_on"] == []
    assert {"69", "70"} <= set(tibia["newly_flagged"]) and tibia["unflagged"] == []
    assert got["runs"]["3_stage_sequential"]["tibia"]["silent_off"] == []  # flagged there already
