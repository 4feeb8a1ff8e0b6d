"""``TrackingOptions.joint_rounds``: one round by default (joint tracking: every bone from its
prediction, its neighbours subtracted at theirs), an integer >= 1 named in the error otherwise, and
``joint_restart`` (which acts on the rounds after the first) refused with one round, naming both;
one round is one lockstep registration per frame (CPU device, 128² views of talus and calcaneus)."""

from __future__ import annotations

import pytest

from core.tracking.trial import TrackingOptions
from tests.core.tracking.test_frame_step import _run
from tests.core.tracking.test_frame_step import two_bones as two_bones


def test_one_round_by_default_and_checked():
    assert TrackingOptions().joint_rounds == 1
    assert TrackingOptions(joint_rounds=3).joint_rounds == 3
    for bad in (0, -1, 1.5, True, "2", None):
        with pytest.raises(ValueError, match=r"^joint_rounds: expected an integer >= 1.*got"):
            TrackingOptions(joint_rounds=bad)
    with pytest.raises(ValueError, match=r"joint_restart: .*joint_rounds=1 has none"):
        TrackingOptions(mode="joint", joint_restart=True)
    assert TrackingOptions(mode="joint", joint_restart=True, joint_rounds=2).joint_restart


def test_one_round_registers_each_frame_once(two_bones, monkeypatch):
    _, calls = _run(two_bones, monkeypatch, False, joint_rounds=1)
    assert calls == [False]  # frame 1's bones side by side, once (frame 0 given)
    _, calls = _run(two_bones, monkeypatch, False, joint_rounds=2)
    assert calls == [False, False]
