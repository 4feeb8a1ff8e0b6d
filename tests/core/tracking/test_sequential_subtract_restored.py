"""Sequential tracking with the neighbours subtracted (TrackingOptions.sequential_subtract) in a
frame where one bone's result is taken back from the journal (resume) and another is registered:
the restored bone is subtracted at its own pose of that frame — what a run that was not cut off
between the two records subtracted — not at its previous frame's pose (ideal 128² views of the
talus and calcaneus, Warp's CPU device)."""

from __future__ import annotations

import numpy as np


def test_a_restored_neighbour_is_subtracted_at_its_pose_of_the_frame(talus_calcaneus_128, monkeypatch):
    import core.tracking.frame_step as fs
    from core.tracking.register import RegistrationOptions
    from core.tracking.results import FrameResult
    from core.tracking.trial import TrackingOptions, track

    sc, models, r, frames = talus_calcaneus_128
    seen = []
    real = fs.register_checked

    def spy(*a, **k):
        others = a[9]
        seen.append((a[3], None if others is None else (np.array(others[0]), list(others[1]))))
        return real(*a, **k)

    monkeypatch.setattr(fs, "register_checked", spy)
    talus, calcaneus = (m.name for m in models)
    p0, p1 = sc.poses(0), sc.poses(1)
    # frame 1's talus recorded before the run stopped; its calcaneus still to register
    done = FrameResult(talus, 1, p1[0], 0.9, 10, 0.0, True)
    skip = {talus: {0: p0[0], 1: done}, calcaneus: {0: p0[1]}}
    reg = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")
    o = TrackingOptions(mode="sequential", verify_restarts=0, registration=reg, trajectory_limit=None,
                        sequential_subtract=True)
    res = track(r, models, frames.__getitem__, [0, 1], keyframes=skip, skip=skip, options=o)
    assert res.results[(talus, 1)] is done
    (bone, others), = seen  # the calcaneus of frame 1 only
    assert bone == 1 and others[1] == [0]
    assert np.array_equal(others[0][0], p1[0])  # the talus at its frame-1 pose, not frame 0's
