"""core.studies.tracking.tibia_cost's helpers: the costs by name and the frames' preparations."""

from __future__ import annotations

import numpy as np
import pytest

from core.studies.tracking import tibia_cost as tc
from core.tracking.cost import RIM_OPTION


def test_costs_by_name():
    opts = {c: tc._options(c) for c in ("gc", "band", "gc60+band", "components+band", "gc+noise", "gc+tight")}
    for c, o in opts.items():
        (t,) = o.terms
        assert t.kind == "gc"
        assert (RIM_OPTION in t.options) == ("band" in c)
        assert t.options.get("components", False) == c.startswith("components")
        assert o.noise_correction == c.endswith("+noise")
        assert (o.levels is not None) == c.endswith("+tight")
    # the plain cost whatever the default
    assert opts["gc"].terms[0].options == {"fluoro_sigma_mm": 0.3, "drr_sigma_mm": 0.3}
    assert opts["gc60+band"].terms[0].options["fluoro_sigma_mm"] == 0.6
    (lv,) = opts["gc+tight"].levels
    assert lv.method == "gauss_newton" and lv.tol_x == 0.002 and lv.options["tol_noise"] < 1e-3
    with pytest.raises(ValueError, match="cost"):
        tc._options("mi")


def test_black_distance_and_filled_frames():
    img = np.full((40, 40), 0.5, np.float32)
    img[:, :10] = 0.0  # black outside a straight "rim"
    d = tc._black_distance(img)
    assert d[0, 9] == 0 and d[20, 10] == pytest.approx(1.0) and d[20, 20] == pytest.approx(11.0, abs=0.2)
    assert np.isinf(tc._black_distance(np.full((8, 8), 0.5, np.float32))).all()
    (filled,), (mask,) = tc._filled([img])
    assert not mask[:, :13].any() and mask[:, 13:].all()  # black and 3 px around it unusable
    np.testing.assert_array_equal(filled, np.full_like(img, 0.5))  # given the nearest usable value


def test_mixed_costs_by_name():
    o = tc._options("gcncc25")
    assert [t.kind for t in o.terms] == ["gc", "ncc"] and [t.weight for t in o.terms] == [1.0, 0.25]
    assert all(t.options == {"fluoro_sigma_mm": 0.3, "drr_sigma_mm": 0.3} for t in o.terms)
    (lv,) = o.levels  # the engine takes one term: the quadratic search on the cost
    assert lv.method == "quadratic" and lv.scale == 1.0 and lv.tol_x == 0.005
    assert [t.kind for t in tc._options("gcgd10+band").terms] == ["gc", "gd"]
    assert all(RIM_OPTION in t.options for t in tc._options("gcgd10+band").terms)
    assert tc._options("gc+quad").levels[0].method == "quadratic"
    assert tc._options("gcncc50+fine").levels[0].sigma == (0.1, 0.2)
    (t,) = tc._options("ncc").terms
    assert t.kind == "ncc" and tc._options("ncc").levels is None
    with pytest.raises(ValueError, match="cost"):
        tc._options("gcmi25")


def test_noise_draws_and_spread():
    class Scene:
        seed = 3

        def frame_rng(self, f, v):
            return np.random.default_rng([self.seed, 0x5CE4E, f, v])

    class TS:
        scene = Scene()

    a, b = tc._rng(TS, 5, 1, 0).random(4), TS.scene.frame_rng(5, 1).random(4)
    np.testing.assert_array_equal(a, b)  # draw 0: the trial's own
    c, d = tc._rng(TS, 5, 1, 1).random(4), tc._rng(TS, 5, 1, 2).random(4)
    assert not np.allclose(a, c) and not np.allclose(c, d)
    rows = [{"frame": f, "draw": k, "error": [0.0] * 6, "long_axis_deg": m + s}
            for f, m in ((0, 0.1), (1, -0.3)) for k, s in enumerate((0.2, -0.2))]
    s = tc._summary(rows, None, {})
    assert s["draws"] == 2 and s["long_axis_spread_deg"] == pytest.approx(np.sqrt(0.08), abs=1e-5)
    assert s["long_axis_bias_rms_deg"] == pytest.approx(np.sqrt((0.1**2 + 0.3**2) / 2), abs=1e-5)
    assert "long_axis_spread_deg" not in tc._summary(rows[::2], None, {})
