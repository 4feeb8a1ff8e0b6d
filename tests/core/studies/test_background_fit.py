"""background_fit: its method names and the bias / spread statistics of a bone's errors."""

import numpy as np
import pytest

from core.studies.tracking import background_fit as bf


def test_methods_parse():
    assert bf.method("hp4+r", 256) == ({"highpass_px": 1.0, "background": 0}, {"robust": 2.5})
    assert bf.method("leg4", 512) == ({"background": 4, "basis": "legendre"}, {})
    assert bf.method("bs8d16+r2", 256) == ({"background": 8, "basis": "bspline", "dilate": 4},
                                           {"robust": 2.0})
    assert bf.method("leg4tp+r", 256) == ({"background": 4, "basis": "legendre", "tissue": True, "psf": True},
                                          {"robust": 2.5})
    assert all(bf.method(m, 256) for m in bf.METHODS)
    with pytest.raises(ValueError, match="method"):
        bf.method("poly4", 256)


def test_summary_splits_bias_and_spread():
    g = np.random.default_rng(1)
    free = np.tile([0.02, 0.0, 0.0, 0.1, 0.0, 0.0], (5, 1))
    noisy = free[:, None] + g.normal(size=(5, 400, 6)) * [0.01, 0.01, 0.01, 0.05, 0.05, 0.05]
    bound = {"rms_mm": 0.02, "rms_deg": 0.1, "sigma": [0.01] * 3 + [0.05] * 3}
    s = bf.summarise(free, noisy, bound)
    assert s["bias_mm"] == pytest.approx(0.02) and s["bias_over_bound"] == [1.0, 1.0]
    assert s["spread_mm"] == pytest.approx(0.01 * np.sqrt(3), rel=0.05)
    assert all(x == pytest.approx(1.0, abs=0.1) for x in s["spread_axis_over_sigma"])
    assert s["rms_mm"] ** 2 == pytest.approx(s["bias_mm"] ** 2 + s["spread_mm"] ** 2, rel=0.05)
