"""The last silent frame and the rule made for it on the stored runs (core.studies.tracking.stage_silent):
seed 4's calcaneus frame 53 at b941103, silent in both modes with the check before the rule, is flagged by
it; and where joint tracking lost to sequential there (core.studies.tracking.joint_sequential_gap)."""

from __future__ import annotations

import json

from core.studies.tracking import joint_sequential_gap, stage_silent
from core.studies.tracking.trajectory_gaps import BENCH
from core.tracking.flags_stage import STAGE_FLAG

SEED4 = {"b941103": [("4", "4", True, "tracking_acceptance_seed4_final_b941103_h100.json")]}


def test_seed_4s_calcaneus_frame_53_is_flagged_by_the_stage_rule():
    rs = list(stage_silent.runs(table=SEED4))
    got = stage_silent.counts(rs)
    assert got["b941103_reproduced"]  # the check before the rule: the run's stored flags
    s = got["per_set"]["b941103"]
    assert s["before"]["silent_frames"] == ["4_joint/calcaneus/53", "4_sequential/calcaneus/53"]
    assert s["after"]["silent"] == 0
    for mode in ("joint", "sequential"):
        new = got["newly_flagged"][f"b941103/4_{mode}/calcaneus"]
        assert new["53"]["over_4x"] and new["53"]["message"].startswith(STAGE_FLAG)
    assert s["after"]["good_flagged"] - s["before"]["good_flagged"] <= 3  # of 412 good ones (1 when written)


def test_seed_4s_calcaneus_joint_loss_sits_in_frames_89_to_96():
    file = "tracking_acceptance_seed4_final_b941103_h100.json"
    got = joint_sequential_gap.gap(json.loads((BENCH / file).read_text()), "calcaneus", draws=2000)
    assert got["frames_carrying_the_sum"] == [89, 90, 91, 95, 96]
    assert got["axis_share_of_squared_diff"][0] > 0.95
    assert got["interval95_iid"][0] < 0 < got["interval95_iid"][1]
    assert got["other_bones"]["talus"]["max_abs_diff_mm_in_carrying_frames"] < 0.02
