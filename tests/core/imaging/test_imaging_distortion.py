"""Distortion models, maps and their evaluation against core.synthetic ground truth (thesis §3.5)."""

import json

import numpy as np
import pytest

from core.imaging.distortion import calibrate_distortion
from core.imaging.distortion_eval import (
    condition_sweep,
    cross_validate,
    evaluate_lattice,
    residual_table,
    select_model,
)
from core.imaging.distortion_maps import remap_tables, undistort_image
from core.imaging.distortion_models import DistortionModel, ModelSpec, fit_distortion
from core.imaging.grid_detection import detect_grid_points
from core.imaging.grid_indexing import index_grid
from core.imaging.pointmaps import fit_polynomial_map
from core.imaging.polybasis import Normalisation, design_matrix, polynomial_terms


@pytest.fixture(scope="module")
def calibration(grid_frame, camera1024):
    return calibrate_distortion(grid_frame.image, pitch_mm=15.0,
                                feature_diameter_px=3.0 / camera1024.pixel_size, model="poly(8,8)")


def test_terms_match_the_thesis_and_matlab():
    assert len(polynomial_terms(3)) == 10  # MATLAB fitgeotrans 'polynomial', 3
    assert len(polynomial_terms((20, 20))) == 231  # thesis: 231 terms
    assert len(polynomial_terms((2, 3))) == 9 and len(polynomial_terms((4, 4), "tensor")) == 25
    assert polynomial_terms((2, 1)).tolist() == [[0, 0], [1, 0], [2, 0], [0, 1], [1, 1]]
    with pytest.raises(ValueError, match="order"):
        polynomial_terms((0, 3))
    with pytest.raises(ValueError, match="Bernstein"):
        design_matrix(np.zeros((3, 2)), 3, basis="bernstein", terms="total")


def test_bases_span_the_same_space_and_jacobians_are_exact():
    rng = np.random.default_rng(0)
    p = rng.uniform(0, 1000, (200, 2))
    q = p + 5 * np.sin(p / 300.0)
    fits = [fit_polynomial_map(p, q, (6, 6), basis=b, terms="tensor")
            for b in ("power", "chebyshev", "bernstein")]
    x = rng.uniform(100, 900, (50, 2))
    for f in fits[1:]:
        np.testing.assert_allclose(f(x), fits[0](x), atol=1e-6)
    assert fits[1].condition < fits[0].condition  # Chebyshev is better conditioned
    for f in fits:
        h = 1e-4
        eu, ev = np.array([h, 0.0]), np.array([0.0, h])
        fd = np.stack([(f(x + eu) - f(x - eu)) / (2 * h), (f(x + ev) - f(x - ev)) / (2 * h)], -1)
        np.testing.assert_allclose(f.jacobian(x), fd, atol=1e-6)
    n = Normalisation.hartley(p)
    xn = n.apply(p)
    assert np.allclose(xn.mean(axis=0), 0) and np.sqrt(np.mean(np.sum(xn**2, 1))) == pytest.approx(np.sqrt(2))


def test_exact_points_recover_the_true_distortion(thesis_distortion):
    """Noise-free control points: the (8,8) model reproduces the true maps within 0.02 px."""
    g = np.stack(np.meshgrid(np.arange(60, 965, 45.0), np.arange(60, 965, 45.0)), -1).reshape(-1, 2)
    q = thesis_distortion.forward(g)
    m = fit_distortion(g, q, "poly(10,10)")
    x = np.random.default_rng(1).uniform(100, 920, (500, 2))
    assert np.abs(m.forward(x) - thesis_distortion.forward(x)).max() < 0.02
    qx = thesis_distortion.forward(x)
    assert np.abs(m.inverse(qx) - x).max() < 0.02
    for spec in ("tps", "lwm(12)"):  # local models: interpolation error between 45 px knots
        mm = fit_distortion(g, q, spec)
        assert np.abs(mm.inverse(qx) - x).max() < 0.25, spec


def test_grid_calibration_matches_ground_truth(calibration, grid_frame, similarity_residual):
    cal = calibration
    assert cal.points.polarity == "bright" and len(cal.index) >= 245
    assert cal.grid.mm_per_px == pytest.approx(0.2915, rel=0.01)  # 0.293 mm pixels at 1.0026 magnification
    # corrected true positions lie on a similarity of the true ideal grid (within ~0.1 px)
    corr = cal.model.inverse(grid_frame.distorted_uv)
    w = grid_frame.ideal_uv[:, 0] + 1j * grid_frame.ideal_uv[:, 1]
    z = corr[:, 0] + 1j * corr[:, 1]
    A = np.column_stack([w, np.ones_like(w)])
    res = np.abs(A @ np.linalg.lstsq(A, z, rcond=None)[0] - z)
    assert np.sqrt(np.mean(res**2)) < 0.1
    assert cal.residuals.rms * cal.grid.mm_per_px < 0.06  # residual = localisation noise
    assert json.loads(json.dumps(cal.summary()))["model"] == "poly(8,8)"


def test_acceptance_lattice_errors_and_model_ranking(calibration, lattice_points):
    """Thesis Tables 3.1–3.3: order >= (5,5) gets lattice RMS < 0.1 mm and beats (3,3) and TPS."""
    g = calibration.grid
    rms = {}
    for spec in ("poly(3,3)", "poly(5,5)", "poly(6,6)", "poly(8,8)", "poly(10,10)", "tps"):
        m = fit_distortion(g.ideal_uv, g.distorted_uv, spec, mm_per_px=g.mm_per_px)
        le = evaluate_lattice(m, lattice_points, pitch_mm=20.0)
        assert le.distance_error_mm.size == 3 * 2 * 6 * 15  # 15 row/column pairs of 6 per line
        rms[spec] = le.distance_rms_mm
    for spec in ("poly(5,5)", "poly(6,6)", "poly(8,8)", "poly(10,10)"):
        assert rms[spec] < 0.1, rms
        assert rms[spec] < rms["poly(3,3)"] and rms[spec] < rms["tps"], rms
    assert rms["poly(3,3)"] > 0.2  # too simple for the S-distortion


def test_condition_numbers_fig_3_11(calibration):
    g = calibration.grid
    rows = condition_sweep(g.ideal_uv, g.distorted_uv, orders=(3, 5, 10, 15, 20))
    norm = {r["order"]: r for r in rows if r["normalise"]}
    raw = {r["order"]: r for r in rows if not r["normalise"]}
    assert all(norm[n]["condition"] < 1e8 for n in (3, 5, 10, 15))
    assert raw[15]["condition"] > 1e30 and raw[10]["condition"] > 1e20  # explodes
    assert raw[15]["mean_residual_px"] > 3 * norm[15]["mean_residual_px"]
    assert norm[15]["rank"] == norm[15]["n_terms"] == 136
    assert norm[20]["n_terms"] == 231 and norm[20]["mean_residual_px"] < norm[15]["mean_residual_px"]


def test_round_trip_and_residual_table(calibration):
    g = calibration.grid
    v, u = np.mgrid[40:1000:37, 40:1000:37]
    q = np.stack([u, v], -1).reshape(-1, 2).astype(float)
    q = q[np.linalg.norm(q - 511.5, axis=1) < 440]  # the field the grid covers
    models = [fit_distortion(g.ideal_uv, g.distorted_uv, s, mm_per_px=g.mm_per_px)
              for s in ("poly(5,5)", "poly(8,8)", "cheb(10,10)", "tps", "lwm(12)")]
    for m in models:
        assert m.round_trip_error(q).max() < 0.05, m.label
    assert models[1].round_trip_error(q).max() < 1e-6
    assert models[1].round_trip_error(q, refined=False).max() < 0.5  # the closed-form guess alone
    rows = residual_table(models, g.distorted_uv, g.ideal_uv)
    assert [r["model"] for r in rows] == ["poly(5,5)", "poly(8,8)", "cheb(10,10)", "tps", "lwm(12)"]
    assert rows[3]["px"]["max"] < 1e-6  # an interpolating spline has no residual at its knots...
    for r in rows:
        assert set(r["mm"]) == {"mean", "rms", "sd", "max", "min"}


def test_cross_validation_picks_a_high_order_polynomial(calibration):
    """...which is why models are chosen on held-out points, not on their residual."""
    g = calibration.grid
    cands = ["poly(3,3)", "poly(5,5)", "poly(8,8)", "poly(15,15)", "tps"]
    best, rows = select_model(g.ideal_uv, g.distorted_uv, cands, folds=4)
    assert best.kind == "polynomial" and 5 <= best.order[0] <= 10
    by = {r["model"]: r["rms_px"] for r in rows}
    assert by["tps"] > by[best.label] and by["poly(3,3)"] > 3 * by[best.label]
    assert by["poly(15,15)"] > by[best.label]  # over-fits between the outer holes
    rows = cross_validate(g.ideal_uv[:40], g.distorted_uv[:40], ["poly(8,8)"], folds=4)
    assert rows[0]["rms_px"] == np.inf and "needs at least 45" in rows[0]["error"]


def test_too_few_points_names_found_and_needed():
    p = np.random.default_rng(0).uniform(0, 100, (30, 2))
    with pytest.raises(ValueError, match=r"found 30 grid points.*needs at least 45"):
        fit_distortion(p, p, "poly(8,8)")
    with pytest.raises(ValueError, match="cannot parse"):
        ModelSpec.parse("spline9")
    with pytest.raises(ValueError, match="ideal_uv, distorted_uv"):
        fit_distortion(p, p[:20], "poly(2,2)")


@pytest.mark.parametrize("spec", ["poly(6,5)", "cheb(8,8)", "bern(5,5)", "poly(4,4)/raw", "tps(0.01)",
                                  "lwm(10)"])
def test_models_serialise_to_json(calibration, spec):
    g = calibration.grid
    m = fit_distortion(g.ideal_uv, g.distorted_uv, spec, mm_per_px=g.mm_per_px)
    assert ModelSpec.parse(m.label) == m.spec
    back = DistortionModel.from_dict(json.loads(json.dumps(m.to_dict())))
    x = g.distorted_uv[:20] + 3.0
    np.testing.assert_allclose(back.inverse(x), m.inverse(x), atol=1e-9)
    np.testing.assert_allclose(back.forward(x), m.forward(x), atol=1e-9)
    assert back.mm_per_px == m.mm_per_px and back.label == m.label


def test_undistorted_frame_shows_a_straight_grid(calibration, grid_frame, camera1024, similarity_residual):
    out = undistort_image(grid_frame.image, calibration.model)
    assert out.dtype == np.float32 and out.shape == grid_frame.image.shape
    pts = detect_grid_points(out, feature_diameter_px=3.0 / camera1024.pixel_size)
    gi = index_grid(pts.uv)
    res = similarity_residual(gi.ij, gi.uv)
    # (holes cut by the raw frame's edge come out cut in the corrected one too: 95th percentile)
    assert len(gi) >= 240 and np.percentile(res, 95) < 0.4 and np.median(res) < 0.2
    assert np.sqrt(np.mean(similarity_residual(calibration.index.ij, calibration.index.uv) ** 2)) > 5
    mx, my = remap_tables(calibration.model, out.shape)
    assert remap_tables(calibration.model, out.shape)[0] is mx  # cached
    assert not mx.flags.writeable
    mx4, my4 = remap_tables(calibration.model, out.shape, step=8)
    assert np.abs(mx4 - mx).max() < 0.01 and np.abs(my4 - my).max() < 0.01
    with pytest.raises(ValueError, match="interpolation"):
        undistort_image(grid_frame.image, calibration.model, interpolation="bicubic")
