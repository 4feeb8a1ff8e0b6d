"""Grey-level linearity over tube-setting sweeps of a synthetic plug phantom (thesis §3.2)."""

import json

import numpy as np
import pytest

from core.imaging.linearity import linear_fit, linearity_study, roi_mask
from core.synthetic import ImagingModel
from core.synthetic.analytic import attenuation_per_mm

PLUGS = {"lung": ("water", 0.3), "water": ("water", 1.0), "bone": ("aluminium", 1.0)}  # material, density
CENTRES = [(40, 48), (100, 48), (160, 48)]


def _phantom(energy_kev: float) -> np.ndarray:
    """Line integrals (H=96, W=200) of three 20 mm plugs (discs of radius 15 px) at one energy."""
    L = np.zeros((96, 200))
    v, u = np.ogrid[:96, :200]
    for (mat, rho), (cu, cv) in zip(PLUGS.values(), CENTRES, strict=True):
        mu = attenuation_per_mm(mat, energy_kev, density=rho if mat == "water" else None)
        L[(u - cu) ** 2 + (v - cv) ** 2 <= 15**2] = 20.0 * mu
    return L


ROIS = [("circle", cu, cv, 8) for cu, cv in CENTRES]


def test_ma_sweep_is_linear_with_the_transmission_as_slope():
    """Gain and quanta both scale with mA: grey level is linear in mA, slope ∝ exp(-μL)."""
    mas = np.array([5.0, 8.0, 12.0, 16.0, 19.2])
    L = _phantom(45.0)
    imgs = []
    for k, ma in enumerate(mas):
        m = ImagingModel(photons_per_pixel=60.0 * ma, gain_dn=150.0 * ma, read_noise_dn=3.0)
        imgs.append(np.stack([m.apply(L, rng=100 * k + i) for i in range(4)]))  # a short sequence each
    res = linearity_study(imgs, mas, ROIS, names=list(PLUGS))
    for j, fit in enumerate(res.fits):
        assert fit.r2 > 0.999
        trans = np.exp(-L[CENTRES[j][1], CENTRES[j][0]])
        assert fit.slope == pytest.approx(150.0 * trans, rel=0.02)
        assert fit.intercept == pytest.approx(60.0, abs=3.0)  # the dark level
    d = json.loads(json.dumps(res.to_dict()))
    assert [r["name"] for r in d["rois"]] == ["lung", "water", "bone"]


def test_kv_sweep_curves_more_for_dense_plugs():
    """Over 60–80 kV (mean energy ~40–55 keV), μ of the dense plug changes most with energy: its
    grey level bends and its R² is the lowest (thesis Fig. 3.3)."""
    kvs = np.array([60.0, 65.0, 70.0, 75.0, 80.0])
    m = ImagingModel(gain_dn=3000.0)
    imgs = [m.expected_dn(_phantom(0.4 * kv + 16.0)) for kv in kvs]
    res = linearity_study(imgs, kvs, ROIS, names=list(PLUGS), full_scale=4095)
    r2 = {n: f.r2 for n, f in zip(res.names, res.fits, strict=True)}
    assert r2["bone"] < min(r2["water"], r2["lung"]) and min(r2.values()) > 0.99
    assert np.all(res.means <= 1.0) and np.all(np.diff(res.means, axis=0) > 0)  # brighter with kV


def test_bad_input_is_named():
    with pytest.raises(ValueError, match="roi"):
        roi_mask((10, 10), ("ellipse", 1, 2, 3))
    with pytest.raises(ValueError, match="covers no pixel"):
        roi_mask((10, 10), ("rect", 20, 20, 3, 3))
    with pytest.raises(ValueError, match="distinct settings"):
        linear_fit([1.0, 1.0], [2.0, 3.0])
    with pytest.raises(ValueError, match="one setting per image"):
        linearity_study([np.zeros((8, 8))], [1.0, 2.0], [("rect", 0, 0, 4, 4)])
    assert linear_fit([0, 1, 2], [1, 3, 5]).r2 == pytest.approx(1.0)
