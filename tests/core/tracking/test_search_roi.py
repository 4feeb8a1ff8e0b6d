"""The search regions of :func:`core.tracking.cost.search_roi` (all views projected together) against
the per-view projection of :meth:`core.geometry.Camera.project`."""

import math
from types import SimpleNamespace

import numpy as np
import pytest

from core.geometry.transforms import pose_from_params
from core.synthetic.rig import foot_rig
from core.tracking.cost import OutsideViewError, search_roi, snap_roi


def _reference(cams, pose, center, points, reach_mm, margin_px):
    """The regions from each camera's own projection (the definition of search_roi's docs)."""
    lab = points @ pose[:3, :3].T + pose[:3, 3]
    c_lab = pose[:3, :3] @ center + pose[:3, 3]
    out = []
    for cam in cams:
        uv, z = cam.project(lab, return_depth=True)
        W, H = cam.width, cam.height
        if (z <= 0).any():
            u0, v0, w0, h0 = 0, 0, W, H
        else:
            lo = np.clip(np.floor(uv.min(axis=0)), 0, [W, H]).astype(int)
            hi = np.clip(np.ceil(uv.max(axis=0)) + 1, 0, [W, H]).astype(int)
            u0, v0, w0, h0 = lo[0], lo[1], max(hi[0] - lo[0], 0), max(hi[1] - lo[1], 0)
        if w0 <= 0 or h0 <= 0:
            return None
        depth = float(cam.R[2] @ c_lab + cam.t[2])
        grow = margin_px + (math.ceil(reach_mm * max(cam.fx, cam.fy) / depth) if depth > 0 else 0)
        lo = (max(u0 - grow, 0), max(v0 - grow, 0))
        hi = (min(u0 + w0 + grow, W), min(v0 + h0 + grow, H))
        if hi[0] <= lo[0] or hi[1] <= lo[1]:
            return None
        out.append((lo[0], lo[1], hi[0] - lo[0], hi[1] - lo[1]))
    return np.array(out)


def test_search_roi_projects_all_views_as_each_camera_does():
    rig = foot_rig(pixels=128)
    renderer = SimpleNamespace(cameras=tuple(rig.cameras))
    rng = np.random.default_rng(7)
    points = rng.normal(scale=(25.0, 12.0, 10.0), size=(200, 3))  # a bone-sized cloud (hull: fewer)
    center = points.mean(axis=0)
    got_inside = got_outside = 0
    for k in range(60):
        spread = 5.0 if k < 40 else 300.0  # near the rig's centre, then partly or wholly outside
        pose = pose_from_params(np.r_[rng.normal(0, spread, 3), rng.normal(0, 0.3, 3)], center=center)
        want = _reference(renderer.cameras, pose, center, points, 4.0, 3)
        for views in ((0, 1), [1, 0], range(2), (1,)):
            ref = None if want is None else want[list(views)]
            if want is None and len(tuple(views)) < 2:
                continue  # (which view is empty is not recorded by the reference)
            if ref is None:
                with pytest.raises(OutsideViewError):
                    search_roi(renderer, pose, 0, views=views, center=center, reach_mm=4.0, margin_px=3,
                               points=points)
                got_outside += 1
                continue
            roi = search_roi(renderer, pose, 0, views=views, center=center, reach_mm=4.0, margin_px=3,
                             points=points)
            assert roi.dtype == np.int64 and roi.shape == (len(tuple(views)), 4)
            np.testing.assert_array_equal(roi, ref)
            got_inside += 1
    assert got_inside > 100 and got_outside > 0
    snapped = snap_roi(np.array([[17, 3, 40, 50], [0, 100, 5, 30]]), renderer, (0, 1))
    np.testing.assert_array_equal(snapped, [[16, 0, 48, 64], [0, 96, 16, 32]])


def test_search_roi_volume_box_as_auto_roi(monkeypatch):
    """Without points, the volume box's corners projected with the camera table (roi.BOX_CORNERS)
    give the regions of the renderer's auto_roi, to the pixel, inside, across and outside the views."""
    import core.tracking.roi as roi_mod
    from core.render.drr import DRRRenderer

    rig = foot_rig(pixels=128)
    lo, hi = np.array([-30.0, -18.0, -12.0]), np.array([34.0, 15.0, 13.0])
    corners = np.array([[a, b, d] for a in (lo[0], hi[0]) for b in (lo[1], hi[1]) for d in (lo[2], hi[2])])
    renderer = SimpleNamespace(cameras=tuple(rig.cameras), _corners=[corners + 1.0, corners])
    renderer.auto_roi = lambda *a, **k: DRRRenderer.auto_roi(renderer, *a, **k)
    rng = np.random.default_rng(11)
    center = corners.mean(axis=0)
    seen = {"inside": 0, "outside": 0}
    for k in range(80):
        spread = 5.0 if k < 50 else 300.0
        pose = pose_from_params(np.r_[rng.normal(0, spread, 3), rng.normal(0, 0.4, 3)], center=center)
        got = []
        for flag in (True, False):
            monkeypatch.setattr(roi_mod, "BOX_CORNERS", flag)
            try:
                got.append(search_roi(renderer, pose, 1, views=(0, 1), center=center, reach_mm=1.0,
                                      margin_px=4))
            except OutsideViewError:
                got.append(None)
        if got[1] is None:
            assert got[0] is None
            seen["outside"] += 1
        else:
            np.testing.assert_array_equal(got[0], got[1])
            seen["inside"] += 1
    assert seen["inside"] > 50 and seen["outside"] > 0
