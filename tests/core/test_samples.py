"""Real data: the Autoscoper wrist sample loads and renders (skipped when the folder is absent)."""

import numpy as np
import pytest

from core.render import DRRRenderer, HUTransfer
from core.samples import WRIST_RADIUS_POSE, wrist_preview


def test_wrist_volumes_and_cameras_load(wrist):
    rad = wrist.volumes["radius"]
    assert rad.shape_ijk == (68, 86, 128)  # TIFF (pages, rows, cols) = (k, j, i)
    np.testing.assert_allclose(rad.spacing, [0.39625, 0.39625, 0.625])
    assert rad.data.min() == -1024 and rad.data.max() > 2000  # CT numbers + 1024 stored
    assert len(wrist.rig) == 2
    assert np.rad2deg(wrist.rig.angle_between_views()) == pytest.approx(110.0, abs=1.0)
    for v in range(2):
        assert wrist.frame(v, 0).shape == (1760, 1760)


def test_radius_renders_where_it_is_in_both_radiographs(wrist, tmp_path):
    scale = 4.0
    rgb, drrs = wrist_preview(wrist, device="cpu", scale=scale)
    assert rgb.ndim == 3 and rgb.dtype == np.uint8
    vol = wrist.volumes["radius"]
    mu = HUTransfer(threshold=300.0)(vol.data)  # the preview's transfer
    k, j, i = np.nonzero(mu)
    w = mu[k, j, i]
    centre = vol.index_to_physical(np.c_[i, j, k].T.dot(w)[None] / w.sum())[0]
    lab = WRIST_RADIUS_POSE[:3, :3] @ centre + WRIST_RADIUS_POSE[:3, 3]
    pts = vol.index_to_physical(np.c_[i, j, k])
    cov3 = np.cov(pts.T, aweights=w)
    shaft = WRIST_RADIUS_POSE[:3, :3] @ np.linalg.eigh(cov3)[1][:, -1]  # long axis, lab
    # the same ROIs the preview rendered (its margin and scale)
    rois = DRRRenderer(wrist.rig, [vol], device="cpu").auto_roi(
        WRIST_RADIUS_POSE[None, None], views=(0, 1), bones=(0,), margin=120)
    for v, drr in enumerate(drrs):
        assert drr.max() > 0.3  # > 10 mm of bone (mu ~ 0.05 /mm) along the densest ray
        # the DRR's intensity centroid is where the mu-weighted centroid projects (a shifted,
        # mirrored or mis-scaled DRR would fail), and that is on the radius in the radiographs
        u0, v0 = rois[0, v, 0, :2]
        r, c = np.mgrid[0 : drr.shape[0], 0 : drr.shape[1]]
        uc = u0 + ((c * drr).sum() / drr.sum() + 0.5) * scale - 0.5
        vc = v0 + ((r * drr).sum() / drr.sum() + 0.5) * scale - 0.5
        u, vv = wrist.rig[v].project(lab)
        assert abs(uc - u) < 3 and abs(vc - vv) < 3, (uc, vc, u, vv)
        # and its long axis is the projected shaft axis (catches mirrored / transposed images)
        cov = np.cov(np.c_[c.ravel(), r.ravel()].T, aweights=drr.ravel())
        axis2d = np.linalg.eigh(cov)[1][:, -1]
        a, b = wrist.rig[v].project(np.stack([lab, lab + 20 * shaft]))
        axis3d = (b - a) / np.linalg.norm(b - a)
        assert abs(axis2d @ axis3d) > np.cos(np.deg2rad(5))
        assert 600 < u < 900 and 1250 < vv < 1650
    import cv2

    assert cv2.imwrite(str(tmp_path / "wrist_radius.png"), rgb[..., ::-1])
