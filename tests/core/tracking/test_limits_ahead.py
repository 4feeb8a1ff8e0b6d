"""The motion check's limits computed while the device works on joint registration's steps
(core.tracking.attempt.limits_ahead, frame_step's lockstep rounds): those the checks compute after
the registration, kept for them."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.mark.parametrize("prediction", [False, True])
def test_limits_ahead_are_the_checks(prediction):
    from core.tracking import checks
    from core.tracking.attempt import limits_ahead
    from core.tracking.options import TrackingOptions

    rng = np.random.default_rng(3)
    c = np.array([1.0, -2.0, 3.0])
    history = []
    for f in range(9):
        P = np.eye(4)
        P[:3, 3] = [0.3 * f + 0.01 * rng.normal(), 0.1 * f, -0.2 * f]
        history.append((f, P))
    o = TrackingOptions()
    pred = checks._predict(*history[-2], *history[-1], 9, c) if prediction else None
    pose = pred if pred is not None else history[-1][1]
    checks._BOUNDS.clear()
    fresh = checks.motion_miss(pose, history, 9, c, n=o.history, limit=o.motion_limit, floor=o.motion_floor,
                               prediction=pred)
    checks._BOUNDS.clear()
    idle = limits_ahead([(history, c, pred), ([], c, None)], o, 9)
    idle()
    assert id(history) in checks._BOUNDS
    idle()  # (the bone without a history: nothing; then nothing left)
    assert checks.motion_miss(pose, history, 9, c, n=o.history, limit=o.motion_limit, floor=o.motion_floor,
                              prediction=pred) == fresh
    assert limits_ahead([([], c, None)], o, 9) is None
