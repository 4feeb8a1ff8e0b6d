"""core.studies.tracking.first_frame_keyframes's main sets the frame_step switch off, then on, for every
draw, and leaves it as it found it (an off-by-default switch was left on), also when a run fails
(the scene and the runs replaced: no rendering)."""

from __future__ import annotations

from types import SimpleNamespace

import pytest


def test_main_restores_the_switch(monkeypatch):
    import core.studies.tracking.first_frame_keyframes as study
    import core.tracking.frame_step as fs

    models = [SimpleNamespace(name="talus")]
    monkeypatch.setattr(study, "scene", lambda names: (None, models, None, None))
    monkeypatch.setattr(study, "keyframes", lambda sc, m, draw, off: {})
    states: list = []

    def first_frame(built, keys, *, mode, restarts):
        states.append(fs.FIRST_FRAME_CHECK_FROM_ROUND0)
        return {"talus": {"mm": 0.0, "deg": 0.0, "evaluations": 1, "flags": []}}

    monkeypatch.setattr(study, "first_frame", first_frame)
    monkeypatch.setattr(fs, "FIRST_FRAME_CHECK_FROM_ROUND0", False)
    assert study.main(["--switch", "FIRST_FRAME_CHECK_FROM_ROUND0", "--draws", "0,1"]) == 0
    assert states == [False, True, False, True]
    assert fs.FIRST_FRAME_CHECK_FROM_ROUND0 is False

    def fails(*a, **k):
        if fs.FIRST_FRAME_CHECK_FROM_ROUND0:
            raise RuntimeError("a run failed")
        return first_frame(*a, **k)

    monkeypatch.setattr(study, "first_frame", fails)
    with pytest.raises(RuntimeError):
        study.main(["--switch", "FIRST_FRAME_CHECK_FROM_ROUND0", "--draws", "0"])
    assert fs.FIRST_FRAME_CHECK_FROM_ROUND0 is False
