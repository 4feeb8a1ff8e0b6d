"""engine_frames.pyramid_rois prepares the views side by side (a thread a view after the first): the same
regions and masks, to the bit, as one view after another (the function before, kept here), and the same
OutsideViewError for a view without a usable pixel."""

from __future__ import annotations

import numpy as np
import pytest


def _one_by_one(frame, views, roi, scale):
    """pyramid_rois as it was: each view read, low-passed and sampled in turn."""
    import cv2

    from core.similarity import sample_roi
    from core.tracking.cost import OutsideViewError, padded_region

    s = float(scale)
    roi = np.asarray(roi, dtype=np.int64).reshape(len(views), 4)
    sig = 0.5 * s
    k = 2 * int(4.0 * sig + 0.5) + 1
    rois, masks = [], []
    for i, v in enumerate(views):
        sub, m, r = padded_region(frame, v, roi[i], s)
        sub = cv2.GaussianBlur(sub, (k, k), sig, sigmaY=sig, borderType=cv2.BORDER_REPLICATE)
        rois.append(sample_roi(sub, r, scale=s))
        mm = None if m is None else sample_roi(m.astype(np.float32), r, scale=s) > 0.999
        masks.append(np.ones(rois[-1].shape, bool) if mm is None else np.ascontiguousarray(mm))
        if not masks[-1].any():
            raise OutsideViewError(f"frame: no usable fluoroscope pixel in the search region of view {v}")
    return rois, masks


def _frame(n_views: int, seed: int, valid=True):
    from core.tracking.cost import prepare_frame

    g = np.random.default_rng(seed)
    imgs = [g.uniform(0.05, 0.95, (128, 120)).astype(np.float32) for _ in range(n_views)]
    for im in imgs:
        im[:9] = 0.0  # black rows: masks with their erosion
        im[40:44, 50:60] = 1.0  # saturated
    return prepare_frame(imgs, valid_range=(0.02, 0.999) if valid else None)


@pytest.mark.parametrize("scale", [2.0, 4.0])
@pytest.mark.parametrize("n_views", [1, 2, 3])
def test_same_regions_and_masks(scale, n_views):
    from core.tracking.engine_frames import pyramid_rois

    roi = np.array([[10, 0, 70, 90], [0, 20, 120, 80], [30, 30, 40, 50]][:n_views])
    for seed, valid in ((0, True), (1, False)):
        views = list(range(n_views))[::-1]  # any order of the views
        got = pyramid_rois(_frame(n_views, seed, valid), views, roi, scale)
        want = _one_by_one(_frame(n_views, seed, valid), views, roi, scale)
        for a, b in zip(got[0] + got[1], want[0] + want[1], strict=True):
            assert a.dtype == b.dtype and a.shape == b.shape and a.flags.c_contiguous
            assert np.array_equal(a, b)


def test_no_usable_pixel_raises_for_that_view():
    from core.tracking.cost import OutsideViewError
    from core.tracking.engine_frames import pyramid_rois

    roi = np.array([[10, 20, 60, 60], [0, 0, 120, 8]])  # view 1: the black rows only
    with pytest.raises(OutsideViewError, match="view 1"):
        pyramid_rois(_frame(2, 0), [0, 1], roi, 2.0)
    with pytest.raises(OutsideViewError, match="view 1"):
        _one_by_one(_frame(2, 0), [0, 1], roi, 2.0)
