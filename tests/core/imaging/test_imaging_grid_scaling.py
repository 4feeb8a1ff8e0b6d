"""The large-grid paths of grid detection, indexing and model choice, against ground truth at small
size (the timings are in ``core.studies.imaging.grid_benchmark``, not asserted here)."""

import numpy as np
import pytest

from core.imaging import distortion_models
from core.imaging.distortion_eval import AUTO_MODELS, cross_validate, select_model
from core.imaging.distortion_models import DistortionModel, even_subsample, fit_distortion
from core.imaging.grid_detection import detect_grid_points
from core.imaging.grid_indexing import index_grid
from core.imaging.pointmaps import _quad_basis, fit_local_weighted_mean, fit_polynomial_map
from core.imaging.polybasis import design_matrix
from core.synthetic import Distortion


def _lattice(n=60, pitch=20.0, angle_deg=20.0, size=1600, seed=0):
    """A rotated square lattice through a strong intensifier distortion: (true ij, distorted uv)."""
    k = np.arange(n) - n // 2
    ij = np.stack(np.meshgrid(k, k, indexing="ij"), -1).reshape(-1, 2)
    a = np.radians(angle_deg)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    ideal = ij @ R.T * pitch + (size - 1) / 2
    d = Distortion((size / 2 + 12.0, size / 2 - 7.0), size / 2, k1=0.06, twist_rad=np.radians(5.0),
                   twist_power=4.0)
    uv = d.forward(ideal) + np.random.default_rng(seed).normal(0, 0.1, ideal.shape)
    inside = np.all((uv > 0) & (uv < size - 1), axis=1)
    return ij[inside], uv[inside]


def test_indexing_is_exact_up_to_a_translation_on_a_large_lattice():
    ij, uv = _lattice()
    rng = np.random.default_rng(1)
    keep = rng.random(len(uv)) > 0.05  # 5 % of the holes lost
    junk = rng.uniform(300, 1300, size=(300, 2))  # inside the lattice (a speckle beyond its edge
    from scipy.spatial import cKDTree  # where a next row would be is a lattice point)

    junk = junk[cKDTree(uv).query(junk)[0] > 7.0][:60]  # speckles well off the lattice
    pts = np.vstack([uv[keep], junk])
    gi = index_grid(pts, origin_uv=(799.5, 799.5))
    real = np.arange(len(pts)) < keep.sum()
    assert real[gi.point_index].all()  # no speckle got a cell
    assert len(gi) >= 0.99 * keep.sum()
    true = ij[keep][gi.point_index]
    shift = gi.ij - true
    assert (shift == shift[0]).all()  # one translation for every point: i ≈ +u, j ≈ +v, no flip
    assert len({tuple(c) for c in gi.ij}) == len(gi)
    assert set(gi.unassigned) | set(gi.point_index) == set(range(len(pts)))


def test_indexing_check_drops_a_displaced_point_only():
    ij, uv = _lattice(n=30, pitch=24.0, angle_deg=5.0, size=900)
    bad = int(np.argmin(np.linalg.norm(uv - [500.0, 430.0], axis=1)))
    uv = uv.copy()
    uv[bad] += [0.25 * 24.0, 0.0]  # inside the growth tolerance, outside the check's 0.15 pitch
    gi = index_grid(uv, origin_uv=(449.5, 449.5))
    assert bad in gi.unassigned and len(gi) == len(uv) - 1
    shift = gi.ij - ij[gi.point_index]
    assert (shift == shift[0]).all()


def _blobs(centres, d, shape, bright, background_slope=0.0):
    """Noise-free soft discs of diameter ``d`` at sub-pixel ``centres`` on a sloped background."""
    v, u = np.mgrid[: shape[0], : shape[1]].astype(float)
    img = 1000.0 + background_slope * u
    for cu, cv in centres:
        r = np.hypot(u - cu, v - cv)
        img += (300.0 if bright else -300.0) * np.clip(d / 2 + 0.5 - r, 0, 1)
    return img.astype(np.float32)


@pytest.mark.parametrize("d", [4.0, 12.0])  # 12 px: the polarity is weighed on a 2x2-binned copy
@pytest.mark.parametrize("bright", [True, False])
def test_detection_finds_symmetric_features_of_either_polarity(d, bright):
    rng = np.random.default_rng(2)
    pitch = 4 * d
    g = np.arange(2 * d, 300 - 2 * d, pitch)
    centres = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2) + rng.uniform(-0.5, 0.5, (len(g) ** 2, 2))
    img = _blobs(centres, d, (300, 300), bright, background_slope=0.5)
    pts = detect_grid_points(img, feature_diameter_px=d)
    assert pts.polarity == ("bright" if bright else "dark")
    assert len(pts) == len(centres)
    from scipy.spatial import cKDTree

    err, j = cKDTree(centres).query(pts.uv)
    assert len(np.unique(j)) == len(centres)
    assert err.max() < 0.05  # symmetric features: the weighted centroid is the centre


def test_even_subsample_spreads_over_the_points():
    _, uv = _lattice(n=40)
    keep = even_subsample(uv, 200, seed=3)
    assert len(keep) == 200 and len(np.unique(keep)) == 200 and (np.diff(keep) > 0).all()
    c = np.median(uv, axis=0)
    quad = (uv[keep, 0] > c[0]) * 2 + (uv[keep, 1] > c[1])
    assert np.bincount(quad, minlength=4).min() >= 35  # each quadrant about a quarter
    assert (even_subsample(uv[:50], 200) == np.arange(50)).all()
    with pytest.raises(ValueError, match="n: expected a positive"):
        even_subsample(uv, 0)


def test_thin_plate_spline_is_capped_and_says_so(monkeypatch):
    ij, uv = _lattice(n=24, pitch=40.0, size=1000)
    ideal = ij * 40.0 + 500.0
    monkeypatch.setattr(distortion_models, "TPS_MAX_POINTS", 150)
    m = fit_distortion(ideal, uv, "tps")
    assert m.n_points == len(uv) and m.n_fit == 150 and len(m.forward_map.src) == 150
    back = DistortionModel.from_dict(m.to_dict())
    assert back.n_fit == 150 and back.n_points == len(uv)
    assert fit_distortion(ideal, uv, "poly(5,5)").n_fit is None  # polynomials use every point
    full = fit_distortion(ideal, uv, "tps", max_points=10_000)
    assert full.n_fit is None and len(full.forward_map.src) == len(uv)
    # a capped spline still corrects held-out points inside the grid (0.1 px noise, ~8 px
    # distortion at the rim; an interpolating spline through a third of the points)
    rest = np.setdiff1d(np.arange(len(uv)), even_subsample(ideal, 150))
    err = np.linalg.norm(m.inverse(uv[rest]) - ideal[rest], axis=1)
    r = np.max(np.abs(ideal[rest] - 500.0), axis=1)
    assert np.median(err) < 0.3 and np.sqrt(np.mean(err[r < 0.8 * r.max()] ** 2)) < 0.5
    rows = cross_validate(ideal, uv, ["tps", "poly(5,5)"], folds=4)
    assert rows[0]["n_fit"] == 150 and "subsample of 150" in rows[0]["note"]
    assert rows[1]["n_fit"] == rows[1]["n_train"] and "note" not in rows[1]


def test_select_model_defaults_to_the_automatic_candidates():
    ij, uv = _lattice(n=24, pitch=40.0, size=1000)
    ideal = ij * 40.0 + 500.0
    spec, rows = select_model(ideal, uv, folds=4)
    assert [r["model"] for r in rows] == list(AUTO_MODELS)
    chosen = [r for r in rows if r.get("chosen")]
    assert len(chosen) == 1 and chosen[0]["model"] == spec.label
    assert chosen[0]["rms_px"] == min(r["rms_px"] for r in rows)
    assert chosen[0]["rms_px"] < 0.2  # 0.1 px localisation noise


def test_local_weighted_mean_matches_the_definition():
    rng = np.random.default_rng(4)
    src = rng.uniform(0, 500, size=(300, 2))
    dst = src + 0.01 * (src - 250) ** 2 / 50 + rng.normal(0, 0.1, src.shape)
    m = fit_local_weighted_mean(src, dst, n_neighbours=10)
    x = np.vstack([rng.uniform(-100, 600, size=(400, 2)), src[:20]])  # also outside every support
    got = m(x)
    xn = m.norm.apply(x)
    want = np.empty_like(got)
    for k, p in enumerate(xn):
        R = np.linalg.norm(p - m.centers, axis=1) / m.radius
        w = np.where(R < 1, 1 - 3 * R**2 + 2 * R**3, 0.0)
        if w.sum() > 1e-12:
            vals = np.einsum("nt,ntc->nc", _quad_basis(p - m.centers), m.coef)
            want[k] = (w[:, None] * vals).sum(0) / w.sum()
        else:
            j = int(np.argmin(np.linalg.norm(p - m.centers, axis=1)))
            want[k] = _quad_basis((p - m.centers[j])[None])[0] @ m.coef[j]
    assert np.abs(got - want).max() < 1e-9
    for i in (0, 17):  # each local quadratic is the least-squares fit to its neighbours
        nb = np.argsort(np.linalg.norm(m.centers - m.centers[i], axis=1))[:10]
        ref = np.linalg.lstsq(_quad_basis(m.centers[nb] - m.centers[i]), dst[nb], rcond=None)[0]
        assert np.allclose(m.coef[i], ref, atol=1e-8)


def test_polynomial_fit_is_the_least_squares_solution():
    ij, uv = _lattice(n=30, pitch=30.0, size=1000)
    ideal = ij * 30.0 + 500.0
    m = fit_polynomial_map(ideal, uv, (6, 6))
    V = design_matrix(m.norm.apply(ideal), (6, 6), basis="power", terms="total", extent=m.norm.extent)
    ref = np.linalg.lstsq(V, uv, rcond=None)[0]
    assert np.allclose(m.coef, ref, rtol=1e-8, atol=1e-8)
    sv = np.linalg.svd(V, compute_uv=False)
    assert m.rank == V.shape[1] and m.condition == pytest.approx(sv.max() / sv.min(), rel=1e-8)


def test_grid_benchmark_smallest_case_checks_out():
    import json

    from core.studies.imaging.grid_benchmark import run

    res = run(sizes=(250,), repeats=1, folds=3)
    case = res["cases"][0]
    assert case["indexing"]["exact"] and case["indexing"]["indexed"] == case["detection"]["detected"] >= 245
    assert case["model"]["chosen"] in res["candidates"] and case["model"]["truth_rms_px"] < 0.2
    assert set(case["times_median_s"]["fit_s"]) == set(res["candidates"])
    json.dumps(res)  # plain JSON types
