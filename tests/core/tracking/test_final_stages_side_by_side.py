"""Several bones' final stages side by side (core.tracking.final_stage.final_stages, joint
registration) against each run on its own: the same results to the bit (CPU device, ideal 128²
views of the talus and calcaneus)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from core.geometry.transforms import pose_from_params


def test_side_by_side_stages_are_each_bones_own(talus_calcaneus_128):
    from core.tracking.cost import prepare_frame
    from core.tracking.final_stage import final_stage, final_stages
    from core.tracking.joint import JointJob, register_together
    from core.tracking.register import RegistrationOptions

    sc, models, r, frames = talus_calcaneus_128
    frame = prepare_frame(frames[1])
    o = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")
    truth = sc.poses(1)
    offs = [np.r_[0.6, -0.4, 0.3, np.radians([0.8, -0.5, 0.6])],
            np.r_[-0.5, 0.3, 0.4, np.radians([-0.6, 0.7, 0.4])]]
    jobs = [JointJob(k, pose_from_params(d, center=m.centroid, base=truth[k]), m.centroid, m.outline,
                     (truth[[1 - k]], [1 - k])) for k, (d, m) in enumerate(zip(offs, models, strict=True))]
    regs = register_together(r, frame, jobs, o)
    of = replace(o, final="likelihood", final_highpass_px=2.0)
    calls = [(regs[k], {"bone": k, "initial_pose": job.initial_pose, "center": job.center, "options": of,
                        "views": (0, 1), "others": job.others}) for k, job in enumerate(jobs)]
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
