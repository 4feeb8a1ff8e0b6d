"""Ground-truth checks of the HU bone phantoms and the soft-tissue envelope."""

import numpy as np
import pytest

from core.synthetic import sdf as S
from core.synthetic.phantoms import (
    BONE_NAMES,
    bone_centroid,
    bone_phantom,
    hu_from_sdf,
    soft_tissue_envelope,
)


def test_sdf_primitives_are_distances():
    p = np.array([[0.0, 0, 0], [5, 0, 0], [13, 0, 0], [0, 0, 20]])
    np.testing.assert_allclose(S.Sphere((0, 0, 0), 10)(p), [-10, -5, 3, 10])
    cap = S.Capsule((0, 0, -5), (0, 0, 5), 2.0)
    np.testing.assert_allclose(cap(p), [-2, 3, 11, 13])
    cone = S.RoundCone((0, 0, 0), (0, 0, 10), 3.0, 1.0)
    q = np.array([[0, 0, -5.0], [0, 0, 14.0], [0, 0, 5.0]])
    np.testing.assert_allclose(cone(q)[:2], [2.0, 3.0])
    assert cone(q)[2] < 0
    box = S.Box((0, 0, 0), (2, 3, 4))
    np.testing.assert_allclose(box(np.array([[0.0, 0, 0], [5, 0, 0], [5, 7, 0]])), [-2, 3, 5])
    e = S.Ellipsoid((0, 0, 0), (10, 5, 3))
    np.testing.assert_allclose(e(np.array([[10.0, 0, 0], [0, 5, 0], [0, 0, 3]])), 0, atol=1e-12)
    su = S.SmoothUnion([S.Sphere((0, 0, 0), 5), S.Sphere((8, 0, 0), 5)], k=4.0)
    assert su(np.array([[4.0, 0, 0]]))[0] < min(-1, -1)  # smooth union bulges between the balls
    moved = S.transformed(S.Sphere((0, 0, 0), 1), translation=(10, 0, 0))
    assert moved(np.array([[10.0, 0, 0]]))[0] == pytest.approx(-1)


def test_hu_profile_of_a_flat_surface():
    d = np.linspace(-6, 3, 91)  # 0.1 mm steps through a plane surface
    hu = hu_from_sdf(d, voxel_mm=0.1, cortex_mm=1.5, cortical_hu=1500, trabecular_hu=300)
    assert hu[-1] == pytest.approx(40) and hu[0] == pytest.approx(300)
    cortical = d[hu > 900]
    assert cortical.size * 0.1 == pytest.approx(1.5, abs=0.15)


@pytest.fixture(scope="module")
def phantoms_1mm():
    return {n: bone_phantom(n, spacing=1.0, seed=0) for n in BONE_NAMES}


def _sdf_grid(ph):
    v = ph.volume
    k, j, i = np.indices(v.data.shape).reshape(3, -1)
    xyz = v.index_to_physical(np.column_stack([i, j, k]))
    return xyz, S.sample_sdf(ph.sdf, xyz).reshape(v.data.shape)


@pytest.mark.parametrize("name", BONE_NAMES)
def test_bone_phantom_hu_ranges_and_volume(name, phantoms_1mm):
    ph = phantoms_1mm[name]
    v = ph.volume
    assert v.units == "HU" and v.name == name and v.data.dtype == np.int16
    assert np.all(v.spacing == 1.0)
    data = v.data
    assert 1200 <= data.max() <= 1800  # cortical bone
    assert np.all(data[0] == 40) and np.all(data[:, :, -1] == 40)  # soft tissue at the box faces
    assert data.min() >= 0  # trabecular texture never falls below soft tissue/marrow levels
    xyz, d = _sdf_grid(ph)
    deep = data[d < -4.5]
    if name != "tibia":  # the tibia's deep interior is partly marrow canal
        assert 180 <= deep.mean() <= 420
    assert data[(d > -0.6) & (d < -0.4)].mean() > 900  # inside the cortex (>= 0.9 mm) everywhere
    # the bone's volume from the voxel grid agrees with the SDF's on a half-voxel-shifted grid
    vol_vox = (d < 0).sum() * 1.0
    vol_shift = (S.sample_sdf(ph.sdf, xyz + 0.5) < 0).sum() * 1.0
    assert vol_vox == pytest.approx(vol_shift, rel=0.03)
    # HU-weighted: partial-volume ramps keep the cortical "mass" consistent with the shape
    expected_cm3 = {"tibia": (40, 110), "talus": (25, 50), "calcaneus": (50, 100),
                    "metatarsal2": (5, 12)}[name]
    assert expected_cm3[0] <= vol_vox / 1000 <= expected_cm3[1]


def test_tibia_cortex_thickens_into_the_diaphysis(phantoms_1mm):
    ph = phantoms_1mm["tibia"]
    v = ph.volume
    mid = (1700 + 260) / 2

    def cortex_along_x(z):  # anterior-posterior line through the shaft axis at height z
        x = np.arange(-20.0, 20.0, 1.0)
        ijk = np.rint(v.physical_to_index(np.column_stack([x, np.full_like(x, 1.0), np.full_like(x, z)])))
        ijk = ijk.astype(int)
        prof = v.data[ijk[:, 2], ijk[:, 1], ijk[:, 0]]
        return (prof > mid).sum() / 2.0  # two walls

    assert cortex_along_x(100.0) == pytest.approx(4.0, abs=1.0)
    assert cortex_along_x(15.0) <= 2.5


def test_phantom_cortical_thickness_talus():
    ph = bone_phantom("talus", spacing=0.5, seed=1, dtype=np.float32)
    v = ph.volume
    z = np.arange(-15.0, 3.0, 0.5)  # vertical line up through the talar dome
    ijk = np.rint(v.physical_to_index(np.column_stack([np.full_like(z, -3.0), np.zeros_like(z), z])))
    ijk = ijk.astype(int)
    prof = v.data[ijk[:, 2], ijk[:, 1], ijk[:, 0]]
    assert (prof > (1400 + 380) / 2).sum() * 0.5 == pytest.approx(1.0, abs=0.5)
    assert v.data.dtype == np.float32


def test_phantom_determinism_and_texture():
    a = bone_phantom("metatarsal2", spacing=1.0, seed=3).volume.data
    b = bone_phantom("metatarsal2", spacing=1.0, seed=3).volume.data
    c = bone_phantom("metatarsal2", spacing=1.0, seed=4).volume.data
    np.testing.assert_array_equal(a, b)
    assert np.any(a != c)
    with pytest.raises(ValueError, match="name"):
        bone_phantom("femur")


def test_bone_centroid_inside_bone():
    for n in ("talus", "calcaneus"):
        spec_sdf = bone_phantom(n, spacing=2.0).sdf
        assert spec_sdf(bone_centroid(n)[None])[0] < 0


def test_soft_tissue_envelope_parts_add_up():
    foot, shank = soft_tissue_envelope(spacing=4.0)
    assert foot.data.shape == shank.data.shape
    mu_f, mu_s = foot.to_attenuation().data, shank.to_attenuation().data
    total = mu_f + mu_s
    mu_tissue = 0.0206 * 1.04
    assert total.max() == pytest.approx(mu_tissue, rel=1e-3)
    inside = total > 0.99 * mu_tissue
    assert inside.mean() > 0.15
    assert foot.data.min() == -1000 and foot.data.max() <= 40 + 1e-3
    # the shank part carries the tissue above the ankle, the foot part below
    k_top, k_bot = -1, 2
    assert mu_s[k_top].sum() > 0 and mu_f[k_top].sum() == 0
    assert mu_f[k_bot].sum() > 0 and mu_s[k_bot].sum() == 0
