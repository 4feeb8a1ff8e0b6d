"""Several bones' final stages side by side (core.tracking.final_stage.final_stages, joint
registration) against each run on its own: the same results to the bit (CPU device, ideal 128²
views of the talus and calcaneus)."""

from __future__ import annotations

import numpy as np

from tests.core.tracking.stage_helpers import stage_calls


def test_side_by_side_stages_are_each_bones_own(talus_calcaneus_128):
    from core.tracking.final_stage import final_stage, final_stages

    r, frame, calls, _ = stage_calls(talus_calcaneus_128)
    alone = [final_stage(r, frame, res, **kw) for res, kw in calls]
    together = final_stages(r, frame, calls)
    for a, t in zip(alone, together, strict=True):
        assert a.timing["likelihood_taken"] == t.timing["likelihood_taken"] == 1
        assert a.timing["likelihood_steps"] == t.timing["likelihood_steps"] > 0
        assert a.evaluations == t.evaluations
        np.testing.assert_array_equal(a.pose, t.pose)
        np.testing.assert_array_equal(a.fit.covariance, t.fit.covariance)
        assert t.timing["likelihood_s"] >= t.timing["likelihood_setup_s"] > 0
    # (the engines kept their own images while side by side; alone again they take the renderer's)
    again = final_stage(r, frame, calls[0][0], **calls[0][1])
    np.testing.assert_array_equal(again.pose, alone[0].pose)
