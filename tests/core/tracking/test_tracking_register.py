import numpy as np
import pytest

from core.geometry.transforms import params_from_pose, pose_from_params
from core.tracking.cost import (
    MetricTerm,
    OutsideViewError,
    RegistrationCost,
    prepare_frame,
    search_roi,
)
from core.tracking.register import Level, RegistrationOptions, default_levels, register


def _perturbed(T, c, mm, deg, rng):
    d = rng.normal(size=3)
    a = rng.normal(size=3)
    p = np.r_[d / np.linalg.norm(d) * mm, a / np.linalg.norm(a) * np.radians(deg)]
    return pose_from_params(p, center=c, base=T)


def _errors(pose, truth, c):
    e = params_from_pose(pose, center=c, base=truth)
    return np.linalg.norm(e[:3]), np.degrees(np.linalg.norm(e[3:]))


def test_cost_is_lowest_at_the_truth_and_batched(talus_scene, rng):
    s = talus_scene
    T, c = s["scene"].poses(0)[0], s["model"].centroid
    frame = prepare_frame(s["fluence"](0))
    roi = search_roi(s["renderer"], T, 0, views=(0, 1), center=c, reach_mm=5.0)
    cost = RegistrationCost(s["renderer"], frame, bone=0, base_pose=T, center=c, roi=roi, scale=1.0)
    X = np.vstack([np.zeros(6), rng.uniform(-2, 2, size=(7, 6))])
    f = cost(X)
    assert f.shape == (8,) and np.argmin(f) == 0 and f[0] < 0.02
    assert cost.timer.calls == 1 and cost.timer.evaluations == 8  # one launch for the population
    np.testing.assert_allclose(cost.params(cost.poses(X[3:4])[0]), X[3], atol=1e-9)
    two = RegistrationCost(s["renderer"], frame, bone=0, base_pose=T, center=c, roi=roi, scale=2.0,
                           terms=(MetricTerm("gc", 1.0), MetricTerm("ncc", 3.0)))
    sc = two.scores(X[:2])
    assert sc.shape == (2, 2)
    np.testing.assert_allclose(two(X[:2]), (1 - sc) @ [0.25, 0.75])


def test_register_recovers_the_pose(talus_scene, rng):
    s = talus_scene
    truth, c = s["scene"].poses(2)[0], s["model"].centroid
    frame = prepare_frame(s["fluence"](2))
    init = _perturbed(truth, c, 3.0, 3.0, rng)
    res = register(s["renderer"], frame, bone=0, initial_pose=init, center=c,
                   options=RegistrationOptions(bounds=(6.0, 6.0)))
    dt, dr = _errors(res.pose, truth, c)
    assert dt < 0.05 and dr < 0.1
    assert res.converged and res.score > 0.99 and res.view_scores.shape == (2,)
    assert res.evaluations == sum(st.evaluations for st in res.stages)
    assert res.timing["calls"] == res.generations + 1  # + the final full-resolution scoring
    assert [st.method for st in res.stages] == ["cmaes", "quadratic"]
    assert res.fit is not None and res.fit.H.shape == (6, 6)


def test_register_with_pso_and_simplex_levels(talus_scene, rng):
    s = talus_scene
    truth, c = s["scene"].poses(4)[0], s["model"].centroid
    frame = prepare_frame(s["fluence"](4))
    init = _perturbed(truth, c, 2.0, 2.0, rng)
    o = RegistrationOptions(levels=(Level(2.0, "pso", (1.0, 1.0), popsize=30, max_generations=15),
                                    Level(1.0, "nelder_mead", (0.3, 0.3), tol_x=0.01)),
                            refine=None, bounds=(5.0, 5.0))
    res = register(s["renderer"], frame, bone=0, initial_pose=init, center=c, options=o)
    dt, dr = _errors(res.pose, truth, c)
    assert dt < 0.15 and dr < 0.3
    assert [st.method for st in res.stages] == ["pso", "nelder_mead"]


def test_bounds_and_outside_view(talus_scene, rng):
    s = talus_scene
    truth, c = s["scene"].poses(0)[0], s["model"].centroid
    frame = prepare_frame(s["fluence"](0))
    init = pose_from_params(np.r_[4.0, 0, 0, 0, 0, 0], center=c, base=truth)
    res = register(s["renderer"], frame, bone=0, initial_pose=init, center=c,
                   options=RegistrationOptions(bounds=(1.0, 1.0), refine=None,
                                               levels=(Level(1.0, "cmaes", (0.5, 0.5), max_generations=15),)))
    assert not res.converged and res.reason == "at_bound"
    far = truth.copy()
    far[:3, 3] += [0.0, 0.0, 2000.0]
    with pytest.raises(OutsideViewError):
        register(s["renderer"], frame, bone=0, initial_pose=far, center=c)


def test_options_validation_and_levels():
    lv = default_levels(0.3)
    assert [x.scale for x in lv] == [4.0, 2.0, 1.0]
    assert [x.method for x in lv] == ["cmaes", "quadratic", "quadratic"]
    assert [(x.scale, x.method) for x in default_levels(1.0)] == [(1.0, "cmaes"), (1.0, "quadratic")]
    assert [(x.scale, x.method) for x in default_levels(0.3, search="local")] == [(2.0, "quadratic"),
                                                                                  (1.0, "quadratic")]
    assert [x.scale for x in default_levels(1.0, search="local")] == [1.0]
    w = RegistrationOptions(search="local").widened(2.0)
    assert w.bounds == (20.0, 20.0) and w.sigma == (3.0, 3.0) and w.search == "global"
    with pytest.raises(ValueError, match="search"):
        RegistrationOptions(search="everywhere")
    with pytest.raises(ValueError, match="method"):
        Level(1.0, "annealing")
    with pytest.raises(ValueError, match="bounds"):
        RegistrationOptions(bounds=(0.0, 1.0))
    with pytest.raises(ValueError, match="kind"):
        MetricTerm("lad")
    with pytest.raises(ValueError, match="fluence"):
        prepare_frame([np.zeros(3)])


def test_smoothing_in_mm_becomes_pixels_per_level(talus_scene):
    from core.tracking.cost import RegistrationCost, _in_pixels, mm_per_pixel, prepare_frame, search_roi

    assert _in_pixels({"fluoro_sigma_mm": 0.6, "dilate": 1}, 0.3) == {"fluoro_sigma": 2.0, "dilate": 1}
    assert _in_pixels({"drr_sigma_mm": 0.3}, 1.5) == {"drr_sigma": 0.0}  # below a quarter pixel: none
    with pytest.raises(ValueError, match="not both"):
        _in_pixels({"drr_sigma_mm": 0.3, "drr_sigma": 1.0}, 0.3)
    s = talus_scene
    sc, m = s["scene"], s["model"]
    T = sc.poses(0)[0]
    px = mm_per_pixel(s["renderer"], T, m.centroid, (0, 1))
    cam = sc.rig[0]
    assert 0.5 * cam.pixel_size < px < 1.5 * cam.pixel_size
    frame = prepare_frame(s["fluence"](0))
    roi = search_roi(s["renderer"], T, 0, views=(0, 1), center=m.centroid, reach_mm=2.0)
    terms = (MetricTerm("gc", 1.0, {"fluoro_sigma_mm": 2 * px, "drr_sigma_mm": 2 * px}),)
    c1 = RegistrationCost(s["renderer"], frame, bone=0, base_pose=T, center=m.centroid, roi=roi, terms=terms)
    c2 = RegistrationCost(s["renderer"], frame, bone=0, base_pose=T, center=m.centroid, roi=roi, scale=2.0,
                          terms=terms)
    assert np.isclose(c1.metrics[0].drr_sigma, 2.0) and np.isclose(c2.metrics[0].drr_sigma, 1.0)
