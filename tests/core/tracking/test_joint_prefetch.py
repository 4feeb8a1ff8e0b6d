"""Joint registration's stages from rows prefetched while the side-by-side searches run
(joint._prefetching, register.STAGE_PREFETCH): each bone's final-stage fluence rows go up in the
searches' idle slot, the stages take them, and the poses and scores are the same to the bit as
without (ideal 128² talus-calcaneus views, frame 1, both bones started off the truth; Warp's CPU
device)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from core.geometry.transforms import pose_from_params


def test_joint_stages_take_rows_prefetched_during_the_searches(talus_calcaneus_128, monkeypatch,
                                                                prefetch_used):
    import core.tracking.register as reg
    from core.tracking.cost import prepare_frame
    from core.tracking.joint import JointJob, register_together
    from core.tracking.register import RegistrationOptions

    used = prefetch_used
    sc, models, r, frames = talus_calcaneus_128
    o = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton", final="likelihood",
                            final_highpass_px=2.0)
    truth = sc.poses(1)
    offs = [np.r_[0.6, -0.4, 0.3, np.radians([0.8, -0.5, 0.6])],
            np.r_[-0.5, 0.3, 0.4, np.radians([-0.6, 0.7, 0.4])]]
    calls: list = []

    def idle():
        calls.append(1)

    out = {}
    for on in (False, True):
        monkeypatch.setattr(reg, "STAGE_PREFETCH", on)
        frame = prepare_frame(frames[1])  # a new frame object each time: no rows left from the other run
        jobs = [JointJob(k, pose_from_params(d, center=m.centroid, base=truth[k]), m.centroid, m.outline,
                         (truth[[1 - k]], [1 - k]))
                for k, (d, m) in enumerate(zip(offs, models, strict=True))]
        used.clear()
        calls.clear()
        regs = register_together(r, frame, jobs, replace(o), idle=idle)
        out[on] = (regs, list(used), len(calls))
    (off, used_off, n_off), (on_, used_on, n_on) = out[False], out[True]
    assert used_off == [False, False] and used_on == [True, True], (used_off, used_on)
    assert n_on == n_off > 0  # the caller's idle work as often as without the prefetch
    for a, b in zip(off, on_, strict=True):
        assert a.timing["likelihood_taken"] == b.timing["likelihood_taken"] == 1
        np.testing.assert_array_equal(a.pose, b.pose)
        assert a.score == b.score
