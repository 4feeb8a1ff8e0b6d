"""The silent frames' study (core.studies.tracking.trajectory_silent) on the stored b797131 runs: the check
without the two rules made for them gives the runs' stored flags; with them seed 4's joint tibia frames 0
and 7 are flagged and the calcaneus's frame 53 is left, in both modes."""

from __future__ import annotations

from core.studies.tracking import trajectory_silent as ts


def test_the_b797131_runs_before_and_after_the_rules():
    rs = list(ts.runs(sets=["b797131"]))
    assert len(rs) == 18
    got = ts.counts(rs)
    assert all(row["reproduced"] for r in got["runs"].values() for row in r.values())
    s = got["per_set"]["b797131"]
    assert (s["over"], s["silent_before"], s["silent_after"]) == (17, 4, 2)
    assert (s["good"], s["good_flagged_before"], s["good_flagged_after"]) == (1385, 65, 87)
    assert s["silent_frames_after"] == ["4_joint/calcaneus/53", "4_sequential/calcaneus/53"]
    new = got["runs"]["b797131/4_joint"]["tibia"]["newly_flagged"]
    assert new["7"]["message"].startswith("off the trajectory next to flagged frame 8, the same way")
    assert new["0"]["message"].startswith("off the trajectory not ruled out (trajectory unchecked")
