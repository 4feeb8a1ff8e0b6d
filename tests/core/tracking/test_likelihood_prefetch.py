"""The likelihood stage's regions from the rows final_stage.stage_prefetch uploaded while the search
ran (likelihood_frames.PREFETCH): the stage makes its line integrals and usable pixels from those where
they cover its own, and the registration with its stage is the same to the bit as with the stage's own
upload (128² ideal talus views, Warp's CPU device; a frame with unusable pixels: erosion, the frame's
own mask)."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.mark.parametrize("shift_mm", [0.0, 25.0])
def test_stage_from_its_prefetched_rows_is_the_same(talus_scene, monkeypatch, prefetch_used, shift_mm):
    """final_stage.stage_prefetch in register's idle slot (the stage's regions at the search's start
    grown by 2 mm more reach, uploaded while the search runs): the stage takes them where they cover
    its own (the start 0.5 mm off) and uploads its own where not (a prefetch about a pose 25 mm off);
    the registration with its stage the same to the bit as without a prefetch."""
    import core.tracking.register as reg
    from core.tracking.cost import prepare_frame
    from core.tracking.final_stage import stage_prefetch
    from core.tracking.register import RegistrationOptions, register

    monkeypatch.setattr(reg, "STAGE_PREFETCH", False)  # (register's own prefetch: only the test's idle here)
    used = prefetch_used
    sc, model, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    fl = [np.array(f, dtype=np.float32) for f in talus_scene["fluence"](2)]
    H, W = fl[0].shape
    masks = [np.ones((H, W), bool), None]
    masks[0][30:50, 55:70] = False
    frame = prepare_frame(fl, masks=masks, valid_range=(0.02, 1.5), erode_px=2)
    start = sc.poses(2)[0].copy()
    start[:3, 3] += (0.4, -0.3, 0.2)
    far = start.copy()
    far[:3, 3] += (shift_mm, 0.0, 0.0)
    o = RegistrationOptions(bounds=(3.0, 3.0), search="newton", final="likelihood", final_highpass_px=2.0)
    went = []

    def idle():
        went.append(stage_prefetch(r, frame, bone=0, pose=far, center=model.centroid, options=o,
                                   views=(0, 1)))

    out = []
    for pre in (False, True):
        res = register(r, frame, bone=0, initial_pose=start, center=model.centroid, options=o,
                       idle=idle if pre else None)
        assert res.timing["likelihood_taken"] == 1
        out.append(res)
    assert went == [True]
    assert used == [False, shift_mm == 0.0], used  # (no prefetch yet for the first frame object's stage)
    np.testing.assert_array_equal(out[0].pose, out[1].pose)
    np.testing.assert_array_equal(np.asarray(out[0].fit.covariance), np.asarray(out[1].fit.covariance))


def test_a_prefetch_of_another_frame_is_not_taken(talus_scene, monkeypatch, prefetch_used):
    """Rows prefetched for another frame object (the same images) or before another frame's prefetch
    on the same engine are not taken: the stage uploads its own; the rows of the frame's own last
    prefetch are. The same pose each time."""
    import core.tracking.register as reg
    from core.tracking.cost import prepare_frame
    from core.tracking.final_stage import final_stage, stage_prefetch
    from core.tracking.register import RegistrationOptions, register

    monkeypatch.setattr(reg, "STAGE_PREFETCH", False)
    used = prefetch_used
    sc, model, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    fl = talus_scene["fluence"](2)
    a, b = prepare_frame(fl, valid_range=None), prepare_frame(fl, valid_range=None)
    truth = sc.poses(2)[0]
    o = RegistrationOptions(bounds=(3.0, 3.0), search="newton", final="likelihood", final_highpass_px=2.0)
    res = register(r, b, bone=0, initial_pose=truth, center=model.centroid, options=o)
    kw = dict(bone=0, initial_pose=truth, center=model.centroid, options=o, views=(0, 1))
    poses = []
    for pre in ((a,), (b, a), (a, b)):  # the prefetches before each stage of frame b, in order
        for f in pre:
            assert stage_prefetch(r, f, bone=0, pose=truth, center=model.centroid, options=o, views=(0, 1))
        out = final_stage(r, b, res.fit.similarity, **kw)
        assert out.timing["likelihood_taken"] == 1
        poses.append(out.pose)
    assert used == [False, False, False, True], used  # (register's own stage first: no prefetch)
    for p in poses[1:]:
        np.testing.assert_array_equal(p, poses[0])
