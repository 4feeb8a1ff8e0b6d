"""Joint registration's side-by-side final stages with the neighbours at their searched poses
(core.tracking.joint_stage, frame_step.STAGE_AT_SEARCHED): inside the switch each stage gets its
neighbour at the pose that neighbour's search found, outside it the pose the round began with
(CPU device, ideal 128² views of the talus and calcaneus)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from core.geometry.transforms import pose_from_params


def test_stages_take_the_neighbours_searched_poses(talus_calcaneus_128, monkeypatch):
    import core.tracking.final_stage as fst
    from core.tracking.cost import prepare_frame
    from core.tracking.joint import JointJob, register_together
    from core.tracking.joint_stage import searched_stages
    from core.tracking.register import RegistrationOptions

    sc, models, r, frames = talus_calcaneus_128
    frame = prepare_frame(frames[1])
    truth = sc.poses(1)
    offs = [np.r_[0.6, -0.4, 0.3, np.radians([0.8, -0.5, 0.6])],
            np.r_[-0.5, 0.3, 0.4, np.radians([-0.6, 0.7, 0.4])]]
    starts = [pose_from_params(d, center=m.centroid, base=truth[k])
              for k, (d, m) in enumerate(zip(offs, models, strict=True))]
    # each bone's neighbour subtracted at its start (a prediction 0.5-0.7 mm / 0.8-1.0 deg off)
    o = replace(RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton"), final="likelihood",
                final_highpass_px=2.0)
    seen: list = []
    plain = fst.final_stages

    def spy(renderer, frame, calls):
        seen.append([(np.asarray(res.pose), kw["others"]) for res, kw in calls])
        return plain(renderer, frame, calls)

    monkeypatch.setattr(fst, "final_stages", spy)  # (restored after the test, the switch's wrapper with it)

    def jobs():
        return [JointJob(k, starts[k], m.centroid, m.outline, (starts[1 - k][None], [1 - k]))
                for k, m in enumerate(models)]

    with searched_stages(True):
        on = register_together(r, frame, jobs(), o)
    off = register_together(r, frame, jobs(), o)  # outside the block: as before
    with searched_stages(False):
        again = register_together(r, frame, jobs(), o)
    assert len(seen) == 3 and all(len(c) == 2 for c in seen)
    for k in range(2):
        searched, (P, ids) = seen[0][k][0], seen[0][1 - k][1]
        assert ids == [k]
        np.testing.assert_array_equal(P[0], searched)  # bone 1-k's stage got bone k's searched pose
        np.testing.assert_array_equal(seen[1][1 - k][1][0][0], starts[k])  # off: its start
        np.testing.assert_array_equal(seen[2][1 - k][1][0][0], starts[k])
        np.testing.assert_array_equal(seen[1][k][0], searched)  # the same searches either way
        assert on[k].timing["likelihood_taken"] == off[k].timing["likelihood_taken"] == 1
        np.testing.assert_array_equal(off[k].pose, again[k].pose)
    # the stages moved with their neighbours' poses
    assert not np.array_equal(on[0].pose, off[0].pose)
