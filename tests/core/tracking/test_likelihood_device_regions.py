"""The likelihood engine's regions made on the device (engine_likelihood.DEVICE_REGIONS, the default)
against the host's on the edge cases: a region at the image's rim, with unusable pixels (saturated,
black, the frame's own mask) just outside it, on the rim and inside it, so that the mask's erosion
reaches past the region and past the image; and a view without a usable pixel. Also the stage's
evaluations: the poses its steps rendered."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from core.tracking.cost import OutsideViewError, prepare_frame


def _frame(talus_scene, *, empty_view: int | None = None):
    """Frame 3 with unusable pixels planted about each view's rim region (:func:`_rois`); the
    frame's own mask of view 1 leaves out a block crossing its region's edge. ``empty_view``: that
    view's own mask leaves out every pixel."""
    fl = [np.array(f, dtype=np.float32) for f in talus_scene["fluence"](3)]
    H, W = fl[0].shape
    # view 0's region at the top-left corner, view 1's at the bottom-right one (_rois)
    for r, c, val in ((0, 0, 2.0), (0, 42, 2.0), (50, 5, 0.0), (20, 20, 2.0), (47, 39, 0.0)):
        fl[0][r, c] = val  # the corner, 2 columns and 2 rows past the region, inside, its last pixel
    for r, c, val in ((H - 1, W - 1, 0.0), (H - 50, W - 10, 2.0), (H - 20, W - 42, 2.0),
                      (H - 30, W - 30, 0.0)):
        fl[1][r, c] = val
    masks = [None, np.ones((H, W), bool)]
    masks[1][H - 60:H - 40, W - 45:W - 35] = False  # across the region's top-left edge
    if empty_view is not None:
        masks[empty_view] = np.zeros((H, W), bool)
    return prepare_frame(fl, masks=masks, valid_range=(0.02, 1.5), erode_px=3)


def _rois(frame) -> np.ndarray:
    H, W = frame.shapes[0]
    return np.array([[0, 0, 40, 48], [W - 40, H - 48, 40, 48]])


def _engine(talus_scene, monkeypatch, device_regions: bool, frame, roi):
    import core.tracking.engine_likelihood as el
    from core.tracking.engine_likelihood import LikelihoodEngine

    monkeypatch.setattr(el, "DEVICE_REGIONS", device_regions)
    sc, model, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    eng = LikelihoodEngine(r, bone=0, views=(0, 1), highpass_px=2.0)
    eng.set_frame(frame, base_pose=sc.poses(3)[0], center=model.centroid, roi=roi)
    return eng


def test_device_regions_at_the_image_rim_equal_the_hosts(talus_scene, monkeypatch):
    frame = _frame(talus_scene)
    roi = _rois(frame)
    host = _engine(talus_scene, monkeypatch, False, frame, roi)
    li_h, m_h = host._bufs["li"].numpy().copy(), host._bufs["mask"].numpy().copy()
    dev = _engine(talus_scene, monkeypatch, True, frame, roi)
    assert dev._count_pending  # (the device path was taken: the region lies inside the image)
    li_d, m_d = dev._bufs["li"].numpy(), dev._bufs["mask"].numpy()
    np.testing.assert_array_equal(m_d > 0, m_h > 0)
    np.testing.assert_allclose(li_d, li_h, rtol=1e-6, atol=1e-6)
    for v in range(2):  # the planted pixels and the erosion took pixels out of both views' regions
        k = m_h[v, :48, :40] > 0
        assert 0 < k.sum() < k.size - 20, (v, k.sum())
    assert not m_h[0, 0, 39] and m_h[0, 0, 38]  # (3 columns from the pixel 2 past the region, 4)
    assert not m_h[0, 47, 39]  # (the region's last pixel, black)
    wp.synchronize_device(dev.device)
    dev._take_count()  # (as a step's synchronisation takes it; no step: the bone is not in these regions)
    assert dev.n_pixels == host.n_pixels == int((m_h > 0).sum())


@pytest.mark.parametrize("device_regions", [False, True])
def test_a_view_without_usable_pixels_is_outside_the_view(talus_scene, monkeypatch, device_regions):
    """Host: set_frame raises; device: the first step does (its count is read there), and the final
    stage then keeps the similarity's pose either way, its evaluations counting the first step's 13
    poses where it rendered them (device)."""
    from dataclasses import replace

    from core.tracking.final_stage import final_stage
    from core.tracking.register import RegistrationOptions, register

    frame = _frame(talus_scene, empty_view=1)
    roi = _rois(frame)
    with pytest.raises(OutsideViewError, match="view 1"):
        eng = _engine(talus_scene, monkeypatch, device_regions, frame, roi)
        eng.step(np.zeros(6), np.full(6, 0.05))
    sc, model, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    truth = sc.poses(3)[0]
    o = RegistrationOptions(bounds=(3.0, 3.0), search="newton")
    res = register(r, prepare_frame(talus_scene["fluence"](3), valid_range=None), bone=0, initial_pose=truth,
                   center=model.centroid, options=o)
    out = final_stage(r, frame, res, bone=0, initial_pose=truth, center=model.centroid,
                      options=replace(o, final="likelihood", final_highpass_px=2.0), views=(0, 1))
    assert out.timing["likelihood_taken"] == 0 and "likelihood_setup_s" not in out.timing
    np.testing.assert_array_equal(out.pose, res.pose)
    assert out.evaluations == res.evaluations + (13 if device_regions else 0)
    assert out.timing.get("likelihood_renders", 0) == int(device_regions)


def test_the_stages_evaluations_are_the_poses_it_rendered(talus_scene):
    """The registration's evaluations after the stage: the similarity's plus 13 a render (the steps'
    DRR launches; a step on the images before it renders none)."""
    from core.tracking.register import RegistrationOptions, register

    sc, model, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    truth = sc.poses(2)[0]
    o = RegistrationOptions(bounds=(3.0, 3.0), search="newton", final="likelihood", final_highpass_px=2.0)
    res = register(r, prepare_frame(talus_scene["fluence"](2), valid_range=None), bone=0, initial_pose=truth,
                   center=model.centroid, options=o)
    t = res.timing
    assert t["likelihood_taken"] == 1 and 1 <= t["likelihood_renders"] < t["likelihood_steps"]
    assert res.evaluations == res.fit.similarity.evaluations + 13 * t["likelihood_renders"]


def test_own_masks_after_a_larger_frame_without_them(talus_scene, monkeypatch):
    """The stage's pinned buffers are grown only: a frame with masks of its own after a larger frame
    without them uploads its masks in the fluence buffer's layout (one block of the same n elements),
    so its regions are those of a fresh engine (before: the mask buffer kept the smaller shape, the
    copy raised or misplaced the masks)."""
    import core.tracking.engine_likelihood as el
    from core.tracking.engine_likelihood import LikelihoodEngine

    monkeypatch.setattr(el, "DEVICE_REGIONS", True)
    sc, model, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    fl = [np.array(f, dtype=np.float32) for f in talus_scene["fluence"](3)]
    H, W = fl[0].shape
    masks = [None, np.ones((H, W), bool)]
    masks[1][50:60, 45:55] = False
    own = prepare_frame(fl, masks=masks, valid_range=(0.02, 1.5), erode_px=2)
    small = np.array([[30, 20, 40, 48], [40, 30, 40, 48]])
    kw = dict(base_pose=sc.poses(3)[0], center=model.centroid)
    eng = LikelihoodEngine(r, bone=0, views=(0, 1), highpass_px=2.0)
    larger = np.array([[10, 10, 100, 100]] * 2)
    eng.set_frame(prepare_frame(fl, valid_range=(0.02, 1.5), erode_px=2), roi=larger, **kw)
    eng.set_frame(own, roi=small, **kw)
    fresh = LikelihoodEngine(r, bone=0, views=(0, 1), highpass_px=2.0)
    fresh.set_frame(own, roi=small, **kw)
    m, m0 = eng._bufs["mask"].numpy(), fresh._bufs["mask"].numpy()
    assert not m0[1, 20:30, 5:15].any() and m0[1].any()  # (the block of the frame's own mask)
    np.testing.assert_array_equal(m > 0, m0 > 0)
    np.testing.assert_array_equal(eng._bufs["li"].numpy(), fresh._bufs["li"].numpy())
