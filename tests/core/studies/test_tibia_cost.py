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
