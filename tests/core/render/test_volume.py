import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from core.render import CTVolume, HUTransfer


def _vol(**kw):
    rng = np.random.default_rng(0)
    data = rng.integers(-1000, 2000, size=(5, 6, 7)).astype(np.int16)
    D = Rotation.from_rotvec([0.1, 0.2, 0.3]).as_matrix()
    return CTVolume(data, spacing=[0.4, 0.5, 0.6], origin=[10.0, -5.0, 3.0], direction=D, **kw)


def test_index_physical_round_trip_and_affine():
    v = _vol()
    ijk = np.array([[0, 0, 0], [6, 5, 4], [1.5, 2.25, 3.75]])
    xyz = v.index_to_physical(ijk)
    np.testing.assert_allclose(xyz[0], v.origin)
    np.testing.assert_allclose(v.physical_to_index(xyz), ijk, atol=1e-12)
    h = np.c_[ijk, np.ones(3)]
    np.testing.assert_allclose((v.T_physical_from_index @ h.T).T[:, :3], xyz)
    # voxel (i, j, k) is data[k, j, i]
    assert v.shape_ijk == (7, 6, 5)


def test_box_corners_are_half_a_voxel_out():
    v = CTVolume(np.zeros((2, 3, 4)), spacing=[1, 2, 3], origin=[0, 0, 0])
    lo, hi = v.bounds()
    np.testing.assert_allclose(lo, [-0.5, -1.0, -1.5])
    np.testing.assert_allclose(hi, [3.5, 5.0, 4.5])


def test_crop_keeps_physical_positions():
    v = _vol()
    c = v.crop(slice(2, 6), slice(1, 4), slice(3, 5))
    assert c.data.shape == (2, 3, 4)
    np.testing.assert_allclose(c.index_to_physical([0, 0, 0]), v.index_to_physical([2, 1, 3]))
    assert c.data[0, 0, 0] == v.data[3, 1, 2]


def test_crop_to_mask_and_centroid():
    data = np.full((20, 20, 20), -1000, np.int16)
    data[5:9, 10:14, 2:6] = 1500
    v = CTVolume(data, spacing=[1, 1, 2], origin=[0, 0, 0])
    np.testing.assert_allclose(v.centroid(), [3.5, 11.5, 2 * 6.5])
    c = v.crop_to_mask(margin=1)
    assert c.data.shape == (6, 6, 6)
    np.testing.assert_allclose(c.centroid(), v.centroid())
    assert v.bone_mask().sum() == 64


def test_hu_transfer_linear_bilinear_threshold_curve():
    hu = np.array([-1000, -500, 0, 1000, 2000], dtype=float)
    mu = HUTransfer(mu_water=0.02)(hu)
    np.testing.assert_allclose(mu, [0, 0.01, 0.02, 0.04, 0.06], rtol=1e-6)
    mu2 = HUTransfer(mu_water=0.02, bone_slope=1.5)(hu)
    np.testing.assert_allclose(mu2, [0, 0.01, 0.02, 0.05, 0.08], rtol=1e-6)
    mu3 = HUTransfer(mu_water=0.02, threshold=500)(hu)
    np.testing.assert_allclose(mu3, [0, 0, 0, 0.04, 0.06], rtol=1e-6)
    mu4 = HUTransfer(curve=((-1000, 0, 3000), (0.0, 0.02, 0.1)))(hu)
    np.testing.assert_allclose(mu4, [0, 0.01, 0.02, 0.02 + 0.08 / 3, 0.02 + 0.16 / 3], rtol=1e-6)
    assert mu.dtype == np.float32
    att = _vol().to_attenuation(HUTransfer(threshold=200))
    assert att.units == "1/mm" and att.data.min() >= 0
    with pytest.raises(ValueError, match="units"):
        att.to_attenuation()


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"spacing": [1, 0, 1]}, "spacing"),
        ({"spacing": [1, -1, 1]}, "spacing"),
        ({"spacing": [1, 1]}, "spacing"),
        ({"origin": [0, np.nan, 0]}, "origin"),
        ({"direction": np.diag([1.0, 2.0, 1.0])}, "direction"),
    ],
)
def test_bad_geometry(kwargs, match):
    with pytest.raises(ValueError, match=match):
        CTVolume(np.zeros((2, 2, 2)), **kwargs)


def test_bad_data_and_transfer():
    with pytest.raises(ValueError, match="data"):
        CTVolume(np.zeros((2, 2)))
    with pytest.raises(ValueError, match="data"):
        CTVolume(np.full((2, 2, 2), np.nan))
    with pytest.raises(ValueError, match="data"):
        CTVolume(np.zeros((2, 2, 2), dtype=bool))
    with pytest.raises(ValueError, match="mu_water"):
        HUTransfer(mu_water=0)
    with pytest.raises(ValueError, match="window"):
        HUTransfer(window=(10, -10))
    with pytest.raises(ValueError, match="curve"):
        HUTransfer(curve=((0, 0), (1, 2)))
