"""core.studies.tracking.first_frame_keyframes: its keyframes are the truth moved the asked mm and degrees
(the same draw, the same keyframes), and only a boolean switch of frame_step is taken."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest


def test_keyframes_off_by_the_asked_amount():
    from core.studies.tracking.first_frame_keyframes import keyframes
    from core.tracking.checks import pose_delta

    truth = [np.eye(4), np.eye(4)]
    truth[1][:3, 3] = (10.0, -5.0, 2.0)
    sc = SimpleNamespace(poses=lambda f: truth)
    models = [SimpleNamespace(name="talus", centroid=np.array([1.0, 2.0, 3.0])),
              SimpleNamespace(name="calcaneus", centroid=np.array([10.0, -5.0, 2.0]))]
    got = keyframes(sc, models, 3, 5.0)
    for k, m in enumerate(models):
        d = pose_delta(truth[k], got[m.name][0], m.centroid)
        assert np.linalg.norm(d[:3]) == pytest.approx(5.0)
        assert np.degrees(np.linalg.norm(d[3:])) == pytest.approx(5.0)
    again = keyframes(sc, models, 3, 5.0)
    assert all(np.array_equal(again[m.name][0], got[m.name][0]) for m in models)
    assert not np.allclose(keyframes(sc, models, 4, 5.0)["talus"][0], got["talus"][0])


def test_only_a_boolean_switch():
    from core.studies.tracking.first_frame_keyframes import main

    for bad in ("STAGE_MOVE_LIMIT", "NO_SUCH_SWITCH"):
        with pytest.raises(SystemExit):
            main(["--switch", bad])
