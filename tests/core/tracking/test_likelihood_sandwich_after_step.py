"""The stage's confidence (the first refinement's sandwich) enqueued after the robust refinement's first
step, on the frame's weights kept before the robust factors (final_stage.SANDWICH_AFTER_STEP): the
stage's pose, covariances and steps the same to the bit as with the sandwich enqueued before the
robust factors (128² ideal talus views, Warp's CPU device; the robust round from the first
refinement's last design, and with its own factor step too)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.core.tracking.stage_helpers import noisy_start


@pytest.mark.parametrize("from_last", [True, False])
def test_sandwich_after_the_robust_step_is_the_same(talus_scene, monkeypatch, from_last):
    import core.tracking.final_stage as fst
    from core.tracking.register import register

    monkeypatch.setattr(fst, "ROBUST_FROM_LAST", from_last)
    model, r = talus_scene["model"], talus_scene["renderer"]
    frame, start, o = noisy_start(talus_scene)
    launched = []
    plain = fst._after_first_launch

    def spy(*a, **k):
        launched.append(True)
        return plain(*a, **k)

    monkeypatch.setattr(fst, "_after_first_launch", spy)
    out = []
    for after in (False, True):
        monkeypatch.setattr(fst, "SANDWICH_AFTER_STEP", after)
        res = register(r, frame, bone=0, initial_pose=start, center=model.centroid, options=o)
        assert res.timing["likelihood_taken"] == 1
        out.append(res)
    assert launched == ([True] if from_last else [])  # (its own factor step: launched before that step)
    a, b = out
    np.testing.assert_array_equal(a.pose, b.pose)
    np.testing.assert_array_equal(np.asarray(a.fit.covariance), np.asarray(b.fit.covariance))
    np.testing.assert_array_equal(np.asarray(a.fit.covariance_independent),
                                  np.asarray(b.fit.covariance_independent))
    assert np.all(np.isfinite(np.asarray(b.fit.covariance)))
    assert a.timing["likelihood_steps"] == b.timing["likelihood_steps"]
