"""Final-stage moves taken back from results written before a frame's timing held the kept
registration's stage outcome (core.tracking.frame_state)."""

from __future__ import annotations

import numpy as np


def test_summed_stage_moves_of_older_results_are_left_out():
    from core.tracking.frame_state import _BoneState
    from core.tracking.results import FrameResult

    st = _BoneState()
    pose = np.eye(4)
    st.add(0, FrameResult("b", 0, pose, 0.9, 1, 0.0, True,
                          timing={"likelihood_taken": 1, "likelihood_move_mm": 0.02}))
    # three joint rounds' stages summed (taken 3, their moves added): not one stage's move
    st.add(1, FrameResult("b", 1, pose, 0.9, 1, 0.0, True,
                          timing={"likelihood_taken": 3, "likelihood_move_mm": 0.09}))
    assert st.moves == [0.02] and len(st.history) == 2
