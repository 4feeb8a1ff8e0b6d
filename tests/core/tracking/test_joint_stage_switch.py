"""The switch of core.tracking.joint_stage (frame_step.STAGE_AT_SEARCHED) without rendering: inside
``searched_stages`` this thread's calls of final_stage.final_stages get the searched poses, another
thread's pass unchanged; one wrapper however often (or from how many threads at once) the block is
entered; after an exception inside the block the calls pass unchanged again."""

from __future__ import annotations

import threading
from types import SimpleNamespace

import numpy as np
import pytest


def _calls():
    P0, P1 = np.eye(4), np.eye(4)
    P1[0, 3] = 1.0
    prev = np.eye(4)
    prev[1, 3] = 2.0
    return [(SimpleNamespace(pose=P0), {"bone": 0, "others": (prev[None], [1])}),
            (SimpleNamespace(pose=P1), {"bone": 1, "others": (prev[None], [0])})]


def _neighbour_y(calls) -> list:
    return [float(np.asarray(kw["others"][0])[0][1, 3]) for _, kw in calls]


def test_switch_is_per_thread_single_wrapper_and_reset_after_an_exception(monkeypatch):
    import core.tracking.final_stage as fst
    from core.tracking.joint_stage import searched_stages

    seen: list = []

    def fake(renderer, frame, calls):
        seen.append(_neighbour_y(calls))
        return [res for res, _ in calls]

    monkeypatch.setattr(fst, "final_stages", fake)  # (restored after the test, the wrapper with it)
    fst.final_stages(None, None, _calls())
    assert seen.pop() == [2.0, 2.0]  # not installed yet: unchanged

    barrier = threading.Barrier(4)

    def enter():
        barrier.wait()
        with searched_stages(True):
            pass

    threads = [threading.Thread(target=enter) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    wrapper = fst.final_stages
    assert wrapper is not fake and wrapper._searched_switch
    assert wrapper.__closure__ is not None and fake in [c.cell_contents for c in wrapper.__closure__]

    with searched_stages(True):
        with searched_stages(True):  # re-entered: the same wrapper, the switch still on after the inner block
            pass
        assert fst.final_stages is wrapper
        fst.final_stages(None, None, _calls())
        assert seen.pop() == [0.0, 0.0]  # each neighbour at the other call's searched pose (y 0)
        other: list = []
        t = threading.Thread(target=lambda: other.append(fst.final_stages(None, None, _calls())))
        t.start()
        t.join()
        assert other and seen.pop() == [2.0, 2.0]  # another thread: unchanged

    with pytest.raises(RuntimeError):
        with searched_stages(True):
            raise RuntimeError("inside the block")
    fst.final_stages(None, None, _calls())
    assert seen.pop() == [2.0, 2.0]  # the switch is off again
    with searched_stages(False):
        fst.final_stages(None, None, _calls())
    assert seen.pop() == [2.0, 2.0]
