"""The likelihood stage's regions taken from the search's upload of the frame on the device
(likelihood_frames.SHARE_SEARCH_UPLOAD): the tracker's engine of the same bone and views staged rows
covering the stage's, so the stage makes its line integrals and usable pixels from those; the same
values, and the registration with its stage the same to the bit as with the stage's own upload
(128² ideal talus views, Warp's CPU device). A frame with unusable pixels (erosion, the frame's own
mask) too, and a frame the search did not stage (the stage uploads its own)."""

from __future__ import annotations

import numpy as np
import pytest


def _register(talus_scene, frame, share: bool, monkeypatch, calls: list):
    import core.tracking.likelihood_frames as lf
    from core.tracking.register import RegistrationOptions, register

    monkeypatch.setattr(lf, "SHARE_SEARCH_UPLOAD", share)
    plain = lf._FrameRegions._search_upload

    def spy(self, *a, **k):
        out = plain(self, *a, **k)
        calls.append(out is not None)
        return out

    monkeypatch.setattr(lf._FrameRegions, "_search_upload", spy)
    sc, model, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    truth = sc.poses(2)[0]
    start = truth.copy()
    start[:3, 3] += (0.4, -0.3, 0.2)
    o = RegistrationOptions(bounds=(3.0, 3.0), search="newton", final="likelihood", final_highpass_px=2.0)
    return register(r, frame, bone=0, initial_pose=start, center=model.centroid, options=o)


@pytest.mark.parametrize("masked", [False, True])
def test_stage_from_the_searchs_upload_is_the_same(talus_scene, monkeypatch, masked):
    from core.tracking.cost import prepare_frame

    fl = [np.array(f, dtype=np.float32) for f in talus_scene["fluence"](2)]
    masks = None
    if masked:  # unusable pixels inside and about the bone's regions, and a block of the frame's own mask
        H, W = fl[0].shape
        fl[0][60:63, 50:90] = 2.0
        fl[1][40:44, 70] = 0.0
        masks = [np.ones((H, W), bool), None]
        masks[0][30:50, 55:70] = False
    frame = prepare_frame(fl, masks=masks, valid_range=(0.02, 1.5) if masked else None,
                          erode_px=2 if masked else 0)
    out = []
    for share in (False, True):
        calls: list = []
        res = _register(talus_scene, frame, share, monkeypatch, calls)
        assert res.timing["likelihood_taken"] == 1
        out.append(res)
        assert calls == ([True] if share else []), calls  # (shared: the search's rows covered the stage's)
    np.testing.assert_array_equal(out[0].pose, out[1].pose)
    np.testing.assert_array_equal(np.asarray(out[0].fit.covariance), np.asarray(out[1].fit.covariance))
    assert out[0].timing["likelihood_steps"] == out[1].timing["likelihood_steps"]


def test_stage_uploads_its_own_rows_for_another_frame(talus_scene, monkeypatch):
    """A frame the search did not stage (the same images, another object): the stage's own upload."""
    from core.tracking.cost import prepare_frame
    from core.tracking.final_stage import final_stage
    from core.tracking.register import RegistrationOptions

    calls: list = []
    fl = talus_scene["fluence"](2)
    res = _register(talus_scene, prepare_frame(fl, valid_range=None), True, monkeypatch, calls)
    sc, model, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    o = RegistrationOptions(bounds=(3.0, 3.0), search="newton", final="likelihood", final_highpass_px=2.0)
    again = final_stage(r, prepare_frame(fl, valid_range=None), res.fit.similarity, bone=0,
                        initial_pose=sc.poses(2)[0], center=model.centroid, options=o, views=(0, 1))
    assert calls == [True, False]
    assert again.timing["likelihood_taken"] == 1


@pytest.mark.parametrize("shift_mm", [0.0, 25.0])
def test_stage_from_its_prefetched_rows_is_the_same(talus_scene, monkeypatch, shift_mm):
    """final_stage.stage_prefetch in register's idle slot (the stage's regions at the search's start
    grown by 2 mm more reach, uploaded while the search runs): the stage takes them where they cover
    its own (the start 0.5 mm off) and uploads its own where not (a prefetch about a pose 25 mm off);
    the registration with its stage the same to the bit as without a prefetch."""
    import core.tracking.likelihood_frames as lf
    import core.tracking.register as reg
    from core.tracking.cost import prepare_frame
    from core.tracking.final_stage import stage_prefetch
    from core.tracking.register import RegistrationOptions, register

    monkeypatch.setattr(lf, "SHARE_SEARCH_UPLOAD", False)
    monkeypatch.setattr(reg, "STAGE_PREFETCH", False)  # (register's own prefetch: only the test's idle here)
    plain = lf._FrameRegions._prefetched
    used: list = []

    def spy(self, *a, **k):
        out = plain(self, *a, **k)
        used.append(out is not None)
        return out

    monkeypatch.setattr(lf._FrameRegions, "_prefetched", spy)
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
