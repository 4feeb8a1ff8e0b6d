"""The likelihood stage's faster kernels on Warp's CPU device: the blocked blur and the median's
count by bisection give the values of the kernels they replace, to the bit; the design's
differences blurred instead of its images give the same moments up to float32 rounding."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp


@pytest.mark.parametrize("sigma", [2.0, 8.0])
def test_blocked_blur_is_the_plain_blur_to_the_bit(sigma):
    from core.similarity import _kernels as K
    from core.similarity.batched import gaussian_weights
    from core.tracking.likelihood_fast import blur_block_dim, blur_block_kernel

    g = np.random.default_rng(1)
    x = g.normal(size=(6, 37, 45)).astype(np.float32)
    x[0, 3, 5] = np.nan
    src = wp.array(x, dtype=wp.float32, device="cpu")
    ref = wp.array(np.array([[37, 45], [29, 40], [33, 7]], np.int32), dtype=wp.vec2i, device="cpu")
    taps = wp.array(gaussian_weights(sigma, truncate=4.0), dtype=wp.float32, device="cpu")
    for axis in (0, 1):
        a = wp.zeros(x.shape, dtype=wp.float32, device="cpu")
        b = wp.full(x.shape, 7.0, dtype=wp.float32, device="cpu")
        wp.launch(K.blur_kernel, dim=x.shape, inputs=[src, a, taps, ref, 3, axis], device="cpu")
        wp.launch(blur_block_kernel, dim=blur_block_dim(x.shape, axis), inputs=[src, b, taps, ref, 3, axis],
                  device="cpu")
        np.testing.assert_array_equal(a.numpy(), b.numpy())


def test_median_by_bisection_is_the_counted_one(monkeypatch):
    import core.tracking.likelihood_kernels as lk

    g = np.random.default_rng(2)
    e = g.normal(0.0, 1.0, (2, 40, 52)).astype(np.float32)
    w = g.uniform(0.5, 2.0, e.shape).astype(np.float32)
    w[0, :, 40:] = 0.0
    w[1, 10:13, :] = 0.0
    w[1, 0, 1] = 0.0  # (an odd count in one view, an even one in the other)
    e = np.where(w > 0, e, 0.0).astype(np.float32)
    out = []
    for bisect in (False, True):
        monkeypatch.setattr(lk, "MEDIAN_BISECT", bisect)
        f = lk.robust_factors_device(wp.array(e, dtype=wp.float32, device="cpu"),
                                     wp.array(w, dtype=wp.float32, device="cpu"), 2.5)
        out.append(f.numpy())
    np.testing.assert_array_equal(out[0], out[1])


def test_differences_blurred_give_the_same_moments(talus_scene, monkeypatch):
    import core.tracking.engine_likelihood as el
    from core.tracking.cost import prepare_frame, search_roi, snap_roi

    sc, model, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    truth = sc.poses(1)[0]
    fr = prepare_frame(talus_scene["fluence"](1), valid_range=None)
    roi = snap_roi(search_roi(r, truth, 0, views=(0, 1), center=model.centroid, reach_mm=1.0, margin_px=4),
                   r, (0, 1))
    x = np.r_[0.2, -0.1, 0.1, 0.3, -0.2, 0.1]
    M, res = [], []
    for diff in (False, True):
        monkeypatch.setattr(el, "DIFF_IMAGES", diff)
        eng = el.LikelihoodEngine(r, bone=0, views=(0, 1), highpass_px=2.0)
        eng.set_frame(fr, base_pose=truth, center=model.centroid, roi=roi)
        s = eng.step(x, np.full(6, 0.05))
        M.append(s["M"])
        res.append(eng.residual(s))
    assert np.abs(M[0]).max() > 0
    np.testing.assert_allclose(M[1], M[0], rtol=1e-4, atol=1e-6 * np.abs(M[0]).max())
    np.testing.assert_allclose(res[1], res[0], atol=1e-4 * np.abs(res[0]).max())
