"""Warp batched metrics (CPU device) against the numpy references."""

import numpy as np
import pytest
import warp as wp

from core.similarity import similarity
from core.similarity.batched import BATCHED_KINDS, BatchedMetric

# stated agreement (core.similarity.batched docs): 1e-4 absolute, GO 1e-2
TOL = {k: (1e-2 if k == "go" else 1e-4) for k in BATCHED_KINDS}


@pytest.fixture(scope="module")
def batch(talus_case):
    c = talus_case
    rng = np.random.default_rng(0)
    t = rng.normal(0, 2.0, (5, 3))
    t[0] = 0
    r = rng.normal(0, np.deg2rad(2), (5, 3))
    r[0] = 0
    poses = c.perturb(t, r)
    return poses, c.render(poses), c.drrs(poses)


def _reference(kind, drrs, fluoro, **opts):
    return np.array([[similarity(kind, drrs[v][b], fluoro[v], **opts) for v in range(len(fluoro))]
                     for b in range(len(drrs[0]))])


@pytest.mark.parametrize("kind", BATCHED_KINDS)
def test_device_scores_match_the_numpy_reference(talus_case, batch, kind):
    _, drr_batch, drrs = batch
    bm = BatchedMetric(kind, list(talus_case.fluoro), device="cpu")
    got = bm.evaluate(drr_batch)
    ref = _reference(kind, drrs, talus_case.fluoro)
    np.testing.assert_allclose(got.item[:, :, 0], ref, atol=TOL[kind], rtol=0)
    np.testing.assert_allclose(got.pose, ref.mean(axis=1), atol=TOL[kind], rtol=0)
    assert got.pose.shape == (5,) and got.item.shape == (5, 2, 1)


@pytest.mark.parametrize("kind", ["ncc", "gc", "gi", "mi", "go"])
def test_domain_options_match_the_reference(talus_case, batch, kind):
    _, drr_batch, drrs = batch
    masks = []
    for f in talus_case.fluoro:
        m = np.ones(f.shape, bool)
        m[:, : f.shape[1] // 3] = False  # e.g. a pressure plate over a third of the ROI
        masks.append(m)
    opts = dict(dilate=1, threshold=0.02, fluoro_sigma=1.0)
    extra = {"mi": dict(bins=16, binning="nearest"), "gc": dict(operator="prewitt")}.get(kind, {})
    bm = BatchedMetric(kind, list(talus_case.fluoro), device="cpu", fluoro_masks=masks, **opts, **extra)
    got = bm.evaluate(drr_batch).item[:, :, 0]
    ref = np.array([[similarity(kind, drrs[v][b], talus_case.fluoro[v], fluoro_mask=masks[v], **opts, **extra)
                     for v in range(2)] for b in range(5)])
    np.testing.assert_allclose(got, ref, atol=TOL[kind], rtol=0)


def test_several_bones_weights_raw_arrays_and_buffer_reuse(talus_case, batch):
    _, drr_batch, drrs = batch
    f = talus_case.fluoro
    # one pose = 2 views x 2 "bones" (the same DRR twice, second bone against a shifted ROI)
    imgs = drr_batch.images.numpy()  # (5 * 2, H, W)
    four = np.repeat(imgs.reshape(5, 2, 1, *imgs.shape[1:]), 2, axis=2).reshape(20, *imgs.shape[1:])
    arr = wp.array(four, dtype=wp.float32, device="cpu")
    rolled = [np.roll(x, 3, axis=1) for x in f]
    w = np.array([1.0, 3.0, 0.5, 0.0])
    bm = BatchedMetric("gc", [[f[0], rolled[0]], [f[1], rolled[1]]], device="cpu", weights=w)
    s1 = bm.evaluate(arr)
    plan = bm._plans[(arr.ptr, arr.shape)]
    s2 = bm.evaluate(arr)
    assert bm._plans[(arr.ptr, arr.shape)] is plan and len(bm._plans) == 1  # buffers reused
    np.testing.assert_array_equal(s1.pose, s2.pose)
    ref = np.stack([_reference("gc", drrs, f), _reference("gc", drrs, rolled)], axis=2)  # (B, V, nb)
    np.testing.assert_allclose(s1.item, ref, atol=1e-4)
    np.testing.assert_allclose(s1.pose, (ref.reshape(5, 4) * w).sum(1) / w.sum(), atol=1e-4)


def test_nan_drr_pixels_count_as_zero_and_empty_domain_scores_zero(talus_case, batch):
    _, drr_batch, _ = batch
    imgs = drr_batch.images.numpy()
    nan = imgs.copy()
    r, c = np.argwhere(imgs[0] > 0)[5]
    nan[0, r, c] = np.nan
    zeroed = imgs.copy()
    zeroed[0, r, c] = 0.0
    bm = BatchedMetric("ncc", list(talus_case.fluoro), device="cpu")
    a = bm.evaluate(wp.array(nan, dtype=wp.float32, device="cpu")).item
    b = bm.evaluate(wp.array(zeroed, dtype=wp.float32, device="cpu")).item
    np.testing.assert_allclose(a, b, atol=1e-7)
    empty = wp.zeros(imgs.shape, dtype=wp.float32, device="cpu")
    for kind in BATCHED_KINDS:
        assert np.all(BatchedMetric(kind, list(talus_case.fluoro), device="cpu")(empty) == 0.0), kind


@pytest.mark.parametrize("kind", ["ncc", "gc"])
def test_a_domain_of_one_or_two_pixels_scores_within_bounds(talus_case, batch, kind):
    """Float32 rounding of the sums must not pass for variance: a one-pixel Ω scored ~9."""
    _, drr_batch, drrs = batch
    f = talus_case.fluoro
    inside = np.argwhere(drrs[0][0] > 0)
    for n_px in (1, 2):
        masks = []
        for v in range(2):
            m = np.zeros(f[v].shape, bool)
            for r, c in np.argwhere(drrs[v][0] > 0)[len(inside) // 2: len(inside) // 2 + n_px]:
                m[r, c] = True
            masks.append(m)
        bm = BatchedMetric(kind, list(f), device="cpu", fluoro_masks=masks)
        got = bm.evaluate(drr_batch).item[:, :, 0]
        ref = np.array([[similarity(kind, drrs[v][b], f[v], fluoro_mask=masks[v]) for v in range(2)]
                        for b in range(5)])
        assert np.all(np.abs(got) <= 1.0)
        if n_px == 1:  # (two pixels correlate ±1 in exact arithmetic, ill-conditioned in float32)
            np.testing.assert_allclose(got, ref, atol=TOL[kind], rtol=0)


def test_bad_input_is_rejected(talus_case, batch):
    _, drr_batch, _ = batch
    f = list(talus_case.fluoro)
    with pytest.raises(ValueError, match="kind"):
        BatchedMetric("rmi", f, device="cpu")
    with pytest.raises(ValueError, match="operator"):
        BatchedMetric("gc", f, device="cpu", operator="abdou")
    bad = [f[0].copy(), f[1]]
    bad[0][2, 2] = np.nan
    with pytest.raises(ValueError, match=r"fluoro_rois\[0\]"):
        BatchedMetric("ncc", bad, device="cpu")
    with pytest.raises(ValueError, match="fluoro_masks"):
        BatchedMetric("ncc", f, device="cpu", fluoro_masks=[np.ones((3, 3), bool)] * 2)
    with pytest.raises(ValueError, match="weights"):
        BatchedMetric("ncc", f, device="cpu", weights=[1.0])
    bm = BatchedMetric("ncc", f, device="cpu")
    with pytest.raises(ValueError, match="images"):
        bm(wp.zeros((3, *drr_batch.images.shape[1:]), dtype=wp.float32, device="cpu"))  # 3 items, 2 views
    with pytest.raises(ValueError, match="images"):
        bm(wp.zeros((2, 8, 8), dtype=wp.float32, device="cpu"))  # smaller than the ROIs
    with pytest.raises(ValueError, match="images"):
        bm(drr_batch.numpy())
    with pytest.raises(ValueError, match="images"):
        BatchedMetric("ncc", [f[0]], device="cpu")(drr_batch)  # a two-view batch, one ROI


def test_benchmark_quick_run_reports_every_kind_and_agrees_with_the_reference():
    from core.studies.similarity.benchmark import run_similarity_benchmark

    res = run_similarity_benchmark(devices=["cpu"], quick=True, kinds=("ncc", "gc", "mi"))
    case = res["devices"]["cpu"]["cases"]["batch128_one_roi"]
    assert set(case["metrics"]) == {"ncc", "gc", "mi"} and 0 < case["omega_fraction"] < 1
    for kind, m in case["metrics"].items():
        assert m["ms_per_batch"] > 0 and m["max_abs_diff_vs_numpy_reference"] < TOL[kind], kind


@pytest.mark.parametrize("kind", ["gc", "ncc"])
def test_drr_blur_on_the_device_matches_blurring_on_the_host(talus_case, batch, kind):
    """``drr_sigma`` blurs each DRR within its ROI like scipy (nearest borders, 3σ taps)."""
    from scipy import ndimage

    from core.similarity.batched import gaussian_weights

    _, drr_batch, drrs = batch
    sigma = 1.3
    w = gaussian_weights(sigma)
    assert w.size == 2 * int(3 * sigma + 0.5) + 1 and np.isclose(w.sum(), 1.0)
    blurred = [[ndimage.gaussian_filter(np.nan_to_num(d), sigma, mode="nearest", truncate=3.0) for d in row]
               for row in drrs]
    got = BatchedMetric(kind, list(talus_case.fluoro), device="cpu", drr_sigma=sigma,
                        fluoro_sigma=sigma).evaluate(drr_batch)
    ref = _reference(kind, blurred, talus_case.fluoro, fluoro_sigma=sigma)
    np.testing.assert_allclose(got.item[:, :, 0], ref, atol=TOL[kind], rtol=0)
    # the blur matters: without it the scores differ
    plain = BatchedMetric(kind, list(talus_case.fluoro), device="cpu", fluoro_sigma=sigma).evaluate(drr_batch)
    assert np.abs(plain.item - got.item).max() > 10 * TOL[kind]
    with pytest.raises(ValueError, match="drr_sigma"):
        BatchedMetric(kind, list(talus_case.fluoro), device="cpu", drr_sigma=-1.0)
