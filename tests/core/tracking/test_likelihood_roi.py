"""The stage's regions with a count per thread block (likelihood_frames.ROI_BLOCK_COUNT,
core.tracking.likelihood_roi): the same line integrals, usable pixels and count as the tracker's
engine's kernel, to the bit, on the rim cases of test_likelihood_device_regions (an erosion past the
region and the image, the frame's own mask), with blocks smaller than the region."""

from __future__ import annotations

import numpy as np
import warp as wp

import core.tracking.likelihood_frames as lf

from .test_likelihood_device_regions import _engine, _frame, _rois


def _regions(talus_scene, monkeypatch, on: bool):
    monkeypatch.setattr(lf, "ROI_BLOCK_COUNT", on)
    monkeypatch.setattr(lf, "ROI_BLOCK_CHUNK", 256)  # (several blocks a view)
    frame = _frame(talus_scene)
    eng = _engine(talus_scene, monkeypatch, True, frame, _rois(frame))
    wp.synchronize_device(eng.device)
    eng._take_count()
    return eng._bufs["li"].numpy().copy(), eng._bufs["mask"].numpy().copy(), eng.n_pixels


def test_block_count_regions_equal_the_engines(talus_scene, monkeypatch):
    li0, m0, n0 = _regions(talus_scene, monkeypatch, False)
    li1, m1, n1 = _regions(talus_scene, monkeypatch, True)
    np.testing.assert_array_equal(li1, li0)
    np.testing.assert_array_equal(m1, m0)
    assert n1 == n0 == int((m0 > 0).sum()) > 0
