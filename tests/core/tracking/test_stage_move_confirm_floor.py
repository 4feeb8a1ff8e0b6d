"""The move confirmation's translation floor (core.tracking.frame_step.CONFIRM_FLOOR_MM): a stage move
of little translation whose second run (from the far side) lands within the floor of its pose, and
within half the move, is confirmed where core.tracking.final_stage.confirm_move's test, a fraction of
the move alone, is not met (the figures: two moves on noisy 128² views, CPU)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest


def _confirm(monkeypatch, c: dict, move_mm: float, move_deg: float) -> tuple[list, tuple]:
    import core.tracking.final_stage as fst
    import core.tracking.frame_step as fs

    monkeypatch.setattr(fst, "confirm_move", lambda *a, **k: {**c, "evaluations": 5, "time_s": 0.1})
    run = SimpleNamespace(renderer=None, bones=[SimpleNamespace(centroid=np.zeros(3))],
                          options=SimpleNamespace(registration=None))
    result = SimpleNamespace(timing={"likelihood_taken": 1, "likelihood_move_mm": move_mm,
                                     "likelihood_move_deg": move_deg})
    a = SimpleNamespace(result=result, notes=())
    w = fs._Work()
    got = fs._confirmed(run, SimpleNamespace(n_views=2), 0, a, None, w, ["uncertain (moved)"])
    assert w.evaluations == 5
    return got, a.notes


@pytest.mark.parametrize(("c", "move", "kept"), [
    ({"mm": 0.0056, "deg": 0.0862}, (0.016, 0.7743), True),  # measured: the talus, frame 5
    ({"mm": 0.0102, "deg": 0.0379}, (0.033, 0.76), True),  # frame 6
    ({"mm": 0.009, "deg": 0.0862}, (0.016, 0.7743), False),  # more than half the move
    ({"mm": 0.0056, "deg": 0.25}, (0.016, 0.7743), False),  # the rotation not confirmed
    ({"mm": 0.025, "deg": 0.01}, (0.2, 0.5), False),  # over the floor and 0.25 x the move
])
def test_floor(monkeypatch, c, move, kept):
    got, notes = _confirm(monkeypatch, {**c, "confirmed": False}, *move)
    assert (got == [], len(notes) == 1) == (kept, kept)
    if kept:
        assert notes[0].startswith(f"final stage's move {move[0]:.3f} mm kept")


def test_no_floor_as_before(monkeypatch):
    import core.tracking.frame_step as fs

    monkeypatch.setattr(fs, "CONFIRM_FLOOR_MM", 0.0)
    got, _ = _confirm(monkeypatch, {"mm": 0.0056, "deg": 0.0862, "confirmed": False}, 0.016, 0.7743)
    assert got == ["uncertain (moved)"]
    got, _ = _confirm(monkeypatch, {"mm": 0.1, "deg": 0.5, "confirmed": True}, 0.2, 0.5)
    assert got == []  # confirm_move's own verdict stands
