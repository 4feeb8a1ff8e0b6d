"""The likelihood final stages' calls of a joint registration on the ideal 128² talus-calcaneus scene
(the ``talus_calcaneus_128`` fixture, frame 1: both bones started off the truth, each with the other at
its true pose subtracted), shared by the side-by-side stages' tests and the recorded steps' tests."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from core.geometry.transforms import pose_from_params

__all__ = ["stage_calls"]


def stage_calls(talus_calcaneus_128) -> tuple:
    """``(renderer, frame, calls, options)``: the frame prepared, per bone ``(registration result,
    final_stage kwargs)`` with the stage at a 2 px high-pass, and the stage's registration options."""
    from core.tracking.cost import prepare_frame
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
    return r, frame, calls, of
