"""The band at the round field's rim in the gradient correlation's domain (the ``gc`` term's
``rim_sigmas``, core.tracking.cost.RIM_OPTION) on ideal 128² views of the talus (CPU device)."""

from __future__ import annotations

import numpy as np
import pytest

from core.tracking.cost import (
    RIM_OPTION,
    MetricTerm,
    RegistrationCost,
    fluoro_rois,
    prepare_frame,
    rim_masks,
    rim_radius,
    search_roi,
)
from core.tracking.engine import GaussNewtonCost, step_design

H = np.array([0.25] * 3 + [0.5] * 3)
SMOOTH = {"fluoro_sigma": 1.0, "drr_sigma": 1.0}  # px: the 128² views' 0.3 mm would be dropped


def _field(sc, frame: int):
    """Frame ``frame``'s views with view 0 black outside a round field whose rim crosses the
    talus's search region (view 1 untouched), the pose, the region and the radius's term."""
    m = sc["model"]
    pose = sc["scene"].poses(frame)[0]
    roi = search_roi(sc["renderer"], pose, 0, views=(0, 1), center=m.centroid, reach_mm=4.0, points=m.outline)
    flu = [0.8 * np.array(f, dtype=np.float32) for f in sc["fluence"](frame)]
    u0, v0, w, h = (int(a) for a in roi[0])
    yy, xx = np.mgrid[0:flu[0].shape[0], 0:flu[0].shape[1]]
    cy, cx = v0 + h // 2, u0 - w // 2  # a field centred left of the region: its rim runs through it
    flu[0][np.hypot(yy - cy, xx - cx) > 0.8 * w] = 0.0
    return flu, pose, roi


def _engine(sc, frame, pose, roi, term, device_frames=True, **kw):
    gn = GaussNewtonCost(sc["renderer"], bone=0, views=(0, 1), term=term)
    gn.device_frames = device_frames
    gn.set_frame(frame, base_pose=pose, center=sc["model"].centroid, roi=roi, **kw)
    return gn


@pytest.mark.parametrize("device_frames", [True, False])
def test_the_band_leaves_the_domain_on_both_paths_and_scores_as_the_host_cost(talus_scene, device_frames):
    sc = talus_scene
    flu, pose, roi = _field(sc, 2)
    frame = prepare_frame(flu)
    term = MetricTerm("gc", 1.0, {**SMOOTH, RIM_OPTION: 4.0})
    gn = _engine(sc, frame, pose, roi, term, device_frames)
    plain = _engine(sc, frame, pose, roi, MetricTerm("gc", 1.0, SMOOTH), device_frames)
    _, masks = fluoro_rois(sc["renderer"], frame, views=(0, 1), roi=roi)
    r = rim_radius(4.0, 1.0)
    assert r == 6.0
    want = rim_masks(frame, (0, 1), roi, masks, r)
    got, before = gn._fmask.numpy(), plain._fmask.numpy()
    for v in (0, 1):
        h, w = want[v].shape
        np.testing.assert_array_equal(got[v, :h, :w].astype(bool), want[v])
        np.testing.assert_array_equal(before[v, :h, :w].astype(bool), masks[v])
    assert 0 < want[0].sum() < masks[0].sum()  # the band took usable pixels of view 0
    np.testing.assert_array_equal(want[1], masks[1])  # view 1 has no black pixel
    # the pixels taken are those within the radius of a black pixel, the erosion's 3 px included
    u0, v0, w, h = (int(a) for a in roi[0])
    dark = np.argwhere(flu[0] <= 0.005)
    yy, xx = np.mgrid[v0:v0 + h, u0:u0 + w]
    taken = masks[0] & ~want[0]
    d = np.min(np.hypot(yy[taken][:, None] - dark[None, :, 0], xx[taken][:, None] - dark[None, :, 1]), axis=1)
    assert d.max() <= r + 0.5
    X = step_design(np.zeros(6), H) + np.r_[0.2, -0.1, 0.1, 0.3, -0.2, 0.1]
    rc = RegistrationCost(sc["renderer"], frame, bone=0, base_pose=pose, center=sc["model"].centroid, roi=roi,
                          terms=(term,))
    np.testing.assert_allclose(gn(X), rc(X), atol=1e-6)
    assert np.max(np.abs(gn(X) - plain(X))) > 1e-5  # the band changes the scores


def test_no_black_pixel_near_the_region_leaves_the_engine_bit_equal(talus_scene):
    sc = talus_scene
    pose = sc["scene"].poses(3)[0]
    m = sc["model"]
    roi = search_roi(sc["renderer"], pose, 0, views=(0, 1), center=m.centroid, reach_mm=4.0, points=m.outline)
    frame = prepare_frame(sc["fluence"](3))
    out = []
    for opts in (SMOOTH, {**SMOOTH, RIM_OPTION: 4.0}):
        gn = _engine(sc, frame, pose, roi, MetricTerm("gc", 1.0, opts))
        s = gn.step(np.zeros(6), H)
        out.append((gn._fmask.numpy(), s.costs, s.g, s.H, s.r))
    for a, b in zip(*out, strict=True):
        np.testing.assert_array_equal(a, b)


def test_the_band_follows_the_smoothing_of_each_set_up(talus_scene):
    """The same frame and regions set up at another pixel size (so another smoothing σ and band):
    the masks prepared again with the new band, as a fresh engine's; without smoothing none."""
    sc = talus_scene
    flu, pose, roi = _field(sc, 2)
    frame = prepare_frame(flu)
    term = MetricTerm("gc", 1.0, {"fluoro_sigma_mm": 1.5, "drr_sigma_mm": 1.5, RIM_OPTION: 4.0})
    gn = _engine(sc, frame, pose, roi, term, px_mm=1.5)  # σ 1 px: a 6 px band
    wide = gn._fmask.numpy().copy()
    for k, px_mm in enumerate((0.75, 1.5, 100.0)):  # σ 2 px, 1 px, dropped
        moved = pose.copy()
        moved[0, 3] += 1e-3 * (k + 1)  # (another set-up: the same inputs again keep the last one)
        gn.set_frame(frame, base_pose=moved, center=sc["model"].centroid, roi=roi, px_mm=px_mm)
        fresh = _engine(sc, frame, moved, roi, term, px_mm=px_mm)
        np.testing.assert_array_equal(gn._fmask.numpy(), fresh._fmask.numpy())
        if px_mm == 0.75:
            assert gn._fmask.numpy().sum() < wide.sum()
        elif px_mm == 1.5:
            np.testing.assert_array_equal(gn._fmask.numpy(), wide)
        else:  # no smoothing: no band, the erosion's masks
            plain = _engine(sc, frame, pose, roi, MetricTerm("gc", 1.0, {}))
            np.testing.assert_array_equal(gn._fmask.numpy(), plain._fmask.numpy())


def test_rim_radius():
    assert rim_radius(None, 1.5) == 0.0 and rim_radius(0, 1.5) == 0.0
    assert rim_radius(4.0, 0.0) == 0.0  # no smoothing
    assert rim_radius(4.0, 1.5, scale=2.0) == 0.0  # a pyramid level
    assert rim_radius(4.0, 1.5) == 8.0
    assert rim_radius(4.0, 1.45) == 8.0 and rim_radius(4.0, 1.51) == 9.0  # whole pixels


def test_the_band_is_kept_from_set_up_to_set_up(talus_scene):
    """Set-ups whose smoothing differs a little (the bone's pixel size from frame to frame) have the
    same whole-pixel band: the engine's RimCache serves it without building the field again."""
    from core.tracking.likelihood_rim import rim_cache

    sc = talus_scene
    flu, pose, roi = _field(sc, 2)
    frame = prepare_frame(flu)
    term = MetricTerm("gc", 1.0, {"fluoro_sigma_mm": 1.5, "drr_sigma_mm": 1.5, RIM_OPTION: 4.0})
    gn = _engine(sc, frame, pose, roi, term, px_mm=1.5)
    cache = rim_cache(gn)
    built = cache.built
    first = gn._fmask.numpy().copy()
    for k, px_mm in enumerate((1.52, 1.55)):  # σ 0.99, 0.97 px: radius 6 as for 1 px
        moved = pose.copy()
        moved[1, 3] += 1e-3 * (k + 1)
        gn.set_frame(frame, base_pose=moved, center=sc["model"].centroid, roi=roi, px_mm=px_mm)
        np.testing.assert_array_equal(gn._fmask.numpy(), first)
    assert cache.built == built and cache.hits >= 2
