"""The command line's progress lines: the ETA of a job in stages runs from the stage's start."""

import io

from app.commands import _shared
from app.commands._shared import Progress


def test_eta_restarts_with_each_stage(monkeypatch):
    clock = [0.0]
    monkeypatch.setattr(_shared.time, "perf_counter", lambda: clock[0])
    out = io.StringIO()
    p = Progress("demo", "frame", stream=out, in_place=False)
    for i in range(1, 11):  # a slow first stage: 10 s a step
        clock[0] += 10.0
        p(i, 10)
    for i in range(1, 3):  # then a fast one counted afresh: 1 s a step
        clock[0] += 1.0
        p(i, 60, "calibration session")
    assert p.eta(2 / 60) == 58.0  # 58 steps left at 1 s, not at the first stage's pace
    lines = out.getvalue().splitlines()
    assert "frame 2/60 calibration session" in lines[-1] and "ETA 58" in lines[-1]
    for i in range(3, 5):  # a message changing on every step (tracking) is one stage
        clock[0] += 1.0
        p(i, 60, f"score 0.{i}")
    assert p.eta(4 / 60) == 56.0
