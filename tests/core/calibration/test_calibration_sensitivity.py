"""Monte Carlo / Latin-hypercube perturbation and Sobol indices of the DLT camera parameters."""

import numpy as np
import pytest

from core.calibration.dlt import camera_parameters, dlt_batch
from core.calibration.objects import cube_target
from core.calibration.sensitivity import PARAMETERS, _params, perturbation_study, sobol_analysis
from core.geometry.transforms import make_rigid
from core.synthetic.capture import capture_centre


@pytest.fixture(scope="module")
def cube(rig):
    return cube_target().centers_lab(make_rigid(np.eye(3), capture_centre(rig)))


def test_one_at_a_time_spread_grows_with_the_amplitude(rig, cube):
    st = perturbation_study(rig[0], cube, n_samples=1500, amplitude=(0.01, 0.25), rng=0)
    assert st.deviation.shape == (len(PARAMETERS), 1500)
    assert np.array_equal(st.marker[:16], np.r_[np.arange(15), 0])
    assert 0.01 <= st.amplitude.min() and st.amplitude.max() <= 0.25
    # Latin hypercube: every tenth of the amplitude range holds a tenth of the samples
    assert np.all(np.histogram(st.amplitude, bins=10, range=(0.01, 0.25))[0] == 150)
    sp = st.spread(bins=(0.01, 0.05, 0.21, 0.25))
    for name in ("f", "cu", "X", "Y", "Z"):
        lo, hi = sp[name]["by_amplitude"][0]["std"], sp[name]["by_amplitude"][-1]["std"]
        assert hi > 3 * lo > 0
    assert sp["sid"]["std"] == pytest.approx(sp["f"]["std"] * rig[0].pixel_size)
    assert sp["reprojection_rms"]["max"] < 0.25


def test_noise_free_and_linear_regime(rig, cube):
    tiny = perturbation_study(rig[0], cube, n_samples=200, amplitude=(1e-6, 1e-6), mode="all")
    assert np.abs(tiny.parameter("f")).max() < 1e-2 and np.abs(tiny.parameter("X")).max() < 1e-3
    a = perturbation_study(rig[0], cube, n_samples=3000, amplitude=(0.05, 0.05), mode="all", rng=1)
    b = perturbation_study(rig[0], cube, n_samples=3000, amplitude=(0.1, 0.1), mode="all", rng=2)
    for name in ("sid", "X", "rx"):  # small perturbations: the spread is proportional to the noise
        assert b.parameter(name).std() / a.parameter(name).std() == pytest.approx(2.0, rel=0.12)
    with pytest.raises(ValueError, match="mode"):
        perturbation_study(rig[0], cube, mode="some")
    with pytest.raises(ValueError, match="points"):
        perturbation_study(rig[0], cube[:5])
    with pytest.raises(ValueError, match="name"):
        a.parameter("skew")


def test_sobol_first_order_matches_the_linearised_variance_split(rig, cube):
    res = sobol_analysis(rig[1], cube, amplitude=0.05, n=512, rng=3)
    assert res.first_order.shape == (len(PARAMETERS), 30) and len(res.inputs) == 30
    assert res.n_evaluations == 512 * 32
    # ground truth for a (locally) linear response: S_i = J_i² / Σ J_j²
    uv0 = rig[1].project(cube)
    ref = camera_parameters(dlt_batch(cube, uv0[None]))
    h = 1e-4
    J = np.zeros((len(PARAMETERS), 30))
    for i in range(30):
        d = np.zeros(30)
        d[i] = h
        J[:, i] = _params(dlt_batch(cube, (uv0.ravel() + d).reshape(1, 15, 2)), ref, 1.0)[:, 0] / h
    for k, name in enumerate(PARAMETERS):
        if name in ("sid",):
            continue
        S = J[k] ** 2 / np.sum(J[k] ** 2)
        np.testing.assert_allclose(res.first_order[k], S, atol=0.06, err_msg=name)
        assert res.total[k].sum() == pytest.approx(1.0, abs=0.15)
    tab = res.table()
    assert set(tab) == set(PARAMETERS)
    assert tab["f"]["sum_first_order"] == pytest.approx(1.0, abs=0.15)
    with pytest.raises(ValueError, match="power of 2"):
        sobol_analysis(rig[1], cube, n=100)
