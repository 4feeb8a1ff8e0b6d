"""The trial's ends study (core.studies.tracking.trajectory_ends) on the stored d262386 runs: the check
before flags_ends gives their stored flags; with it, frames over 4x left silent 5 -> 3 of 21 and good
frames flagged 70 -> 53 of 1373, of which the shifted windows alone (the bone's median as before) 5 -> 4
and 70 -> 64 (flags_ends' docs)."""

from __future__ import annotations

from core.studies.tracking import trajectory_ends as te
from core.studies.tracking.trajectory_silent import runs


def test_the_d262386_runs_before_and_after():
    rs = list(runs(sets=["d262386"], table=te.TABLE))
    assert len(rs) == 18
    got = te.counts(rs)
    assert got["d262386_reproduced"]
    b, a = got["per_set"]["d262386"]["before"], got["per_set"]["d262386"]["after"]
    assert (b["over"], b["silent"], a["silent"]) == (21, 5, 3)
    assert (b["good"], b["good_flagged"], a["good_flagged"]) == (1373, 70, 53)
    assert (b["ends_silent"], a["ends_silent"]) == (1, 0)
    assert "4_sequential/tibia/0" in b["silent_frames"] and "4_sequential/tibia/0" not in a["silent_frames"]
    split = te.scale_split(rs)
    for name, want in (("windows_only", (4, 64)), ("with_scale", (3, 53))):
        assert (split[name]["d262386"]["silent"], split[name]["d262386"]["good_flagged"]) == want
    from core.tracking import flags_ends

    assert flags_ends.SCALE_WITHOUT_ENDS  # put back
