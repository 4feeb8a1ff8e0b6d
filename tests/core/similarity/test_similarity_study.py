"""Response-study harness and edge-operator comparison (small, fast configurations)."""

import numpy as np
import pytest

from core.studies.similarity.edge_study import _auc, foot_comparison, line_pair_comparison, line_pair_image
from core.studies.similarity.study import StudyConfig, combine, curve_stats, response_study, summarize
from core.studies.similarity.study_report import ranking, write_figures


def test_curve_stats_of_clean_bumpy_and_offset_peaks():
    x = np.linspace(-10, 10, 21)
    clean = np.exp(-(x**2) / 20)
    s = curve_stats(x, clean)
    assert s["local_extrema"] == 1 and s["capture"] == 10 and s["peak_offset"] == 0
    assert s["sharpness"] == pytest.approx(-2 * np.polyfit(x[8:13], clean[8:13], 2)[0] / np.ptp(clean))
    bumpy = clean + 0.2 * (np.abs(x) == 6)
    b = curve_stats(x, bumpy)
    assert b["local_extrema"] == 5 and b["capture"] == 5  # rises again at |x| = 6
    off = curve_stats(x, np.exp(-((x - 3) ** 2) / 20))
    assert off["peak_offset"] == 3 and off["capture_hi"] == 0 and off["capture"] == 0


def test_auc_matches_pairwise_counting():
    rng = np.random.default_rng(0)
    s = rng.integers(0, 5, 60).astype(float)  # with ties
    p = rng.random(60) < 0.4
    pairs = [(a > b) + 0.5 * (a == b) for a in s[p] for b in s[~p]]
    assert _auc(s, p) == pytest.approx(np.mean(pairs))


def test_response_study_small_run(talus_case, tmp_path):
    metrics = {"gc": ("gc", {}), "ncc": ("ncc", {}), "gi~1": ("gi", {"fluoro_sigma": 1.0})}
    cfg = StudyConfig(metrics=metrics, n_random=6, sweep_steps=5, noise_levels=(0.0, 0.2), noise_repeats=2,
                      max_translation_px=4, max_rotation_deg=4)
    res = response_study(talus_case, cfg)
    for name in metrics:
        assert res.translation[name].shape == (6,) and res.rotation[name].shape == (6,)
        assert res.noise[name].shape == (2, 2)
        for axis in ("tx", "ty", "tz", "rx", "ry", "rz"):  # the sweep's middle pose is the reference
            assert res.sweeps[name][axis][2] == pytest.approx(res.reference[name], abs=1e-9)
    assert np.all(res.translation_px <= 4) and np.all(res.rotation_deg <= 4)
    assert res.noise["gc"][1].mean() < res.reference["gc"]  # noise lowers the match
    both = combine(res, {"gc": 1.0, "ncc": 3.0}, "mix")
    mix = (res.translation["gc"] + 3 * res.translation["ncc"]) / 4
    np.testing.assert_allclose(both.translation["mix"], mix)
    summ = summarize(both)
    assert set(summ) == {"gc", "ncc", "gi~1", "mix"}
    assert -1 <= summ["gc"]["translation"]["spearman"] <= 1
    rank = ranking({res.case: summ})
    paths = write_figures([both], {res.case: summ}, rank, tmp_path)
    assert all(p.is_file() and p.stat().st_size > 1000 for p in paths)


def test_line_pairs_ground_truth_and_thesis_findings():
    img, truth = line_pair_image(size=192)
    assert img.shape == (192, 192) and 0 <= img.min() and img.max() <= 1
    for f, t in truth.items():  # bars darken the image between their true edges
        r0, r1 = t["rows"]
        prof = img[r0:r1].mean(axis=0)
        e = t["edges"]
        bar = prof[int(np.ceil(e[0])) : int(np.floor(e[1])) + 1].mean()
        gap = prof[int(np.ceil(e[1])) : int(np.floor(e[2])) + 1].mean()
        if f < 1:
            assert bar < gap, f
    res = line_pair_comparison(variants={"sobel": ("sobel", 0.0), "abdou": ("abdou", 0.0),
                                         "laplacian_line": ("laplacian_line", 0.0)})
    v = res["variants"]
    assert v["sobel"]["0.5"]["resolved"] >= 0.9 and v["sobel"]["0.5"]["cnr"] > 5
    # thesis 6.4.2: the wide Abdou kernel cannot resolve 1.5 lp/mm, the Laplacian line can
    assert v["abdou"]["1.5"]["resolved"] < 0.6 < v["laplacian_line"]["1.5"]["resolved"]


def test_foot_outlines_are_found_better_after_smoothing():
    stats, img, _ = foot_comparison(pixels=256, spacing=1.0, device="cpu", variants={
        "sobel~1": ("sobel", 1.0), "laplacian_point": ("laplacian_point", 0.0)})
    assert img.shape == (256, 256)
    assert stats["sobel~1"]["auc"] > stats["laplacian_point"]["auc"]
    assert 0.5 < stats["sobel~1"]["auc"] <= 1.0
