"""Numpy reference metrics (thesis §6.2): normalisation, closed forms, invariances, bad input."""

import numpy as np
import pytest

from core.similarity import (
    METRICS,
    domain,
    joint_histogram,
    line_integral_image,
    mutual_information,
    ncc,
    regional_mutual_information,
    sample_roi,
    sid,
    similarity,
)
from core.similarity.gradient import GO_RANDOM_WEIGHT


def test_every_metric_scores_one_against_itself_and_near_zero_against_noise(smooth_pair):
    drr, other = smooth_pair
    for kind, info in METRICS.items():
        same = similarity(kind, drr, drr)
        unrelated = similarity(kind, drr, other + 0.05)
        assert same == pytest.approx(1.0, abs=1e-4), kind
        lo, hi = info.score_range
        assert lo - 1e-9 <= unrelated <= hi + 1e-9, kind
        if kind not in ("lad", "pi"):  # no reference point in their definitions (documented)
            assert abs(unrelated) < 0.12, (kind, unrelated)


def test_sid_is_one_minus_sid_over_its_random_pairing_expectation(smooth_pair):
    drr, other = smooth_pair
    om = drr > 0
    d, f = drr[om], other[om] * 3 + 1
    perm = np.mean((d[:, None] - f[None, :]) ** 2) * d.size  # exact mean over all pairings
    expected = 1 - np.sum((d - f) ** 2) / perm
    assert sid(drr, other * 3 + 1) == pytest.approx(expected, rel=1e-9)


def test_ncc_is_pearson_on_omega_only(smooth_pair):
    drr, other = smooth_pair
    om = drr > 0
    assert ncc(drr, other) == pytest.approx(np.corrcoef(drr[om], other[om])[0, 1])
    changed = other.copy()
    changed[~om] = 1e6  # pixels outside Ω do not matter
    assert ncc(drr, changed) == pytest.approx(ncc(drr, other))
    assert ncc(drr, -2 * drr + 5) == pytest.approx(-1.0)


def test_invariances_of_the_pattern_metrics(smooth_pair):
    drr, _ = smooth_pair
    affine = 3.0 * drr + 2.0
    for kind in ("ncc", "mi", "nmi", "gc", "gi", "go"):
        assert similarity(kind, drr, affine) == pytest.approx(1.0, abs=1e-6), kind
    # orientations modulo π and MI: an inverted fluoroscope image still matches
    for kind in ("mi", "nmi", "go"):
        assert similarity(kind, drr, -drr) == pytest.approx(1.0, abs=1e-6), kind
    # intensity comparisons are not scale-invariant
    for kind in ("sid", "gd", "lad"):
        assert similarity(kind, drr, affine) < 0.8, kind


def test_mutual_information_nearest_binning_matches_a_histogram2d_computation(smooth_pair):
    drr, other = smooth_pair
    om = drr > 0
    a, b = drr[om], other[om]
    edges_a = np.linspace(a.min(), a.max(), 17)[1:-1]
    # nearest bin centre of 16 centres spanning the range == np.digitize on midpoints
    ca = np.linspace(a.min(), a.max(), 16)
    cb = np.linspace(b.min(), b.max(), 16)
    ia = np.digitize(a, (ca[1:] + ca[:-1]) / 2)
    ib = np.digitize(b, (cb[1:] + cb[:-1]) / 2)
    h = np.zeros((16, 16))
    np.add.at(h, (ia, ib), 1)
    p = h / h.sum()
    pa, pb = p.sum(1), p.sum(0)

    def ent(q):
        return -np.sum(q[q > 0] * np.log(q[q > 0]))

    mi = ent(pa) + ent(pb) - ent(p)
    assert edges_a.size == 15
    got = mutual_information(drr, other, bins=16, binning="nearest")
    assert got == pytest.approx(mi / np.sqrt(ent(pa) * ent(pb)), rel=1e-9)


def test_linear_binning_keeps_the_mass_and_the_mean_bin():
    rng = np.random.default_rng(3)
    a, b = rng.random(500), rng.random(500)
    h = joint_histogram(a, b, bins=8)
    assert h.sum() == pytest.approx(500)
    t = (a - a.min()) / (a.max() - a.min()) * 7
    assert (h.sum(axis=1) * np.arange(8)).sum() / 500 == pytest.approx(t.mean())  # linear weights


def test_regional_mi_of_correlated_white_noise_is_rho_squared():
    rng = np.random.default_rng(4)
    x = rng.normal(size=(120, 120))
    rho = 0.6
    y = rho * x + np.sqrt(1 - rho**2) * rng.normal(size=x.shape)
    got = regional_mutual_information(x + 10, y, radius=1)
    assert got == pytest.approx(rho**2, abs=0.03)


def test_gradient_metrics_penalise_perpendicular_orientations():
    drr = (U * U / 40.0) + 1.0
    perp = V * V / 40.0
    inner = np.zeros(drr.shape, bool)  # away from the replicated border Sobel is exact here
    inner[1:-1, 1:-1] = True
    gd, gf = (2 * U / 40)[inner], (2 * V / 40)[inner]
    gi = similarity("gi", drr, perp, fluoro_mask=inner)
    assert gi == pytest.approx(-np.mean(np.minimum(gd / gd.mean(), gf / gf.mean())), abs=1e-9)
    assert similarity("gi", drr, perp.T) == pytest.approx(1.0)
    w = (2 - np.log1p(np.pi / 2)) / 2
    go = similarity("go", drr, perp, n_lb_fraction=0.0)
    assert go == pytest.approx((w - GO_RANDOM_WEIGHT) / (1 - GO_RANDOM_WEIGHT), abs=1e-9)


U, V = np.meshgrid(np.arange(1.0, 31.0), np.arange(1.0, 31.0))


def test_domain_threshold_dilation_and_mask():
    drr = np.zeros((9, 9))
    drr[4, 4] = 1.0
    assert domain(drr).sum() == 1
    assert domain(drr, dilate=2).sum() == 25
    mask = np.ones((9, 9), bool)
    mask[4, 4] = False
    assert domain(drr, fluoro_mask=mask).sum() == 0
    assert domain(drr, threshold=1.0).sum() == 0


def test_empty_domain_and_constant_images_score_zero(smooth_pair):
    drr, other = smooth_pair
    zero = np.zeros_like(drr)
    const = np.full_like(other, 0.7)
    for kind in METRICS:
        assert similarity(kind, zero, other) == 0.0, kind
        if kind != "lad":  # LAD scores absolute differences: defined for a constant image
            assert similarity(kind, drr, const) == pytest.approx(0.0, abs=1e-12), kind


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_rmi_of_a_constant_image_is_exactly_zero_whatever_its_value(smooth_pair, dtype):
    # Centred on the mean alone, a constant image's neighbourhoods kept ±1 ulp residues and scored
    # up to 6e-11 of slogdet round-off (sign set by the BLAS build); they must cancel exactly.
    drr, _ = smooth_pair
    for value in (0.7, 0.3, 1 / 3, 1.1, 2.2e-5, 1000.1, 4095.3):
        const = np.full(drr.shape, value, dtype=dtype)
        assert regional_mutual_information(drr, const) == 0.0, value
        assert regional_mutual_information(const, drr) == 0.0, value
        assert regional_mutual_information(const, drr, radius=2) == 0.0, value


def test_bad_input_raises_naming_the_argument(smooth_pair):
    drr, other = smooth_pair
    nan = other.copy()
    nan[3, 3] = np.nan
    with pytest.raises(ValueError, match="fluoro"):
        ncc(drr, nan)
    with pytest.raises(ValueError, match="fluoro"):
        ncc(drr, other[:-1])
    with pytest.raises(ValueError, match="drr"):
        ncc(np.zeros(5), np.zeros(5))
    with pytest.raises(ValueError, match="kind"):
        similarity("ssd", drr, other)
    with pytest.raises(ValueError, match="fluoro_mask"):
        ncc(drr, other, fluoro_mask=np.ones(3, bool))
    with pytest.raises(ValueError, match="bins"):
        mutual_information(drr, other, bins=1)
    with pytest.raises(ValueError, match="operator"):
        similarity("gc", drr, other, operator="laplacian_point")


def test_line_integral_image_and_roi_sampling():
    f = np.array([[1.0, np.exp(-1.0)], [0.0, 0.5]])
    li = line_integral_image(f)
    np.testing.assert_allclose(li, [[0, 1], [np.log(4096), np.log(2)]], rtol=1e-6)
    vv, uu = np.mgrid[0:50, 0:60].astype(np.float32)
    img = 2 * uu + 3 * vv  # linear: bilinear sampling is exact
    roi = np.array([10, 5, 20, 16])
    out = sample_roi(img, roi, scale=2.0)
    assert out.shape == (8, 10)
    r, c = np.mgrid[0:8, 0:10]
    np.testing.assert_allclose(out, 2 * (10 + (c + 0.5) * 2 - 0.5) + 3 * (5 + (r + 0.5) * 2 - 0.5), rtol=1e-5)


def test_true_pose_scores_best_along_an_image_shift(talus_case):
    """Ground truth: against a realistic synthetic frame, the gradient metrics, RMI and PI peak at the
    true pose along a translation sweep (±4 px) of the talus (NCC and MI do not: the overlapping
    tibia and calcaneus pull them off, see the response study)."""
    c = talus_case
    steps = np.arange(-4, 5)
    t = np.zeros((len(steps), 3))
    t[:, 1] = steps * c.mm_per_px
    drrs = c.drrs(c.perturb(t))
    for kind in ("gc", "gi", "go", "gd", "rmi", "pi"):
        s = [np.mean([similarity(kind, drrs[v][b], c.fluoro[v]) for v in range(c.n_views)])
             for b in range(len(steps))]
        assert abs(steps[int(np.argmax(s))]) <= 1, (kind, np.round(s, 3))
