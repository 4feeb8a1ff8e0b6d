from collections import Counter

import numpy as np
import pytest

from core.render import CTVolume
from core.tracking.bones import bone_model, marching_tetrahedra, mesh_area, mesh_volume


def _sphere(n=36, r=11.3, c=(17.2, 18.1, 16.7)):
    k, j, i = np.mgrid[0:n, 0:n, 0:n]
    return r - np.sqrt((i - c[0]) ** 2 + (j - c[1]) ** 2 + (k - c[2]) ** 2), r, np.array(c)


def test_marching_tetrahedra_sphere_is_closed_oriented_and_accurate():
    f, r, c = _sphere()
    v, faces = marching_tetrahedra(f)
    d = np.linalg.norm(v - c, axis=1)
    assert np.abs(d - r).max() < 0.05  # linear interpolation of a distance field
    edges = Counter(map(tuple, np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])))
    assert max(edges.values()) == 1 and all(edges[(b, a)] == 1 for a, b in edges)  # watertight, manifold
    assert mesh_volume(v, faces) == pytest.approx(4 / 3 * np.pi * r**3, rel=0.01)  # positive: outward
    assert mesh_area(v, faces) == pytest.approx(4 * np.pi * r**2, rel=0.01)


def test_marching_tetrahedra_closes_at_the_border_and_handles_empty():
    f = np.ones((4, 5, 6))  # all inside: the surface closes in the padding, 1/3 voxel out
    v, faces = marching_tetrahedra(f, level=0.5)  # (pad value -1: crossing at 0.5 / 1.5)
    assert mesh_volume(v, faces) == pytest.approx((3 + 2 / 3) * (4 + 2 / 3) * (5 + 2 / 3), rel=0.03)
    v, faces = marching_tetrahedra(np.zeros((3, 3, 3)), level=1.0)
    assert v.shape == (0, 3) and faces.shape == (0, 3)
    with pytest.raises(ValueError, match="field"):
        marching_tetrahedra(np.zeros((3, 3)))


def test_bone_model_of_a_phantom():
    from core.synthetic import bone_phantom

    vol = bone_phantom("talus", spacing=1.5).volume
    m = bone_model(vol, threshold=200.0)
    np.testing.assert_allclose(m.centroid, vol.centroid(200.0), atol=1e-9)
    assert m.mask.sum() == (vol.data >= 200).sum()
    voxel_volume = m.n_voxels * np.prod(vol.spacing)
    assert mesh_volume(m.vertices, m.faces) == pytest.approx(voxel_volume, rel=0.1)
    lo, hi = m.volume.bounds()
    assert np.all(m.vertices >= lo - 1e-6) and np.all(m.vertices <= hi + 1e-6)
    coarse = bone_model(vol, mesh_step=2)
    assert len(coarse.faces) < len(m.faces) / 2
    assert mesh_volume(coarse.vertices, coarse.faces) == pytest.approx(voxel_volume, rel=0.2)
    T = np.eye(4)
    T[:3, 3] = [5, 6, 7]
    np.testing.assert_allclose(m.surface_points(T), m.vertices + np.array([5, 6, 7]))


def test_bone_model_from_labels_removes_the_neighbour():
    data = np.full((20, 20, 40), -100, dtype=np.int16)
    labels = np.zeros(data.shape, dtype=np.uint8)
    data[5:15, 5:15, 4:14] = 800
    labels[5:15, 5:15, 4:14] = 1
    data[5:15, 5:15, 16:30] = 900  # the other bone, touching the first one's margin
    labels[5:15, 5:15, 16:30] = 2
    ct = CTVolume(data, spacing=(1.0, 1.0, 1.0), name="ct")
    m = bone_model(ct, labels=labels, label=1, margin_mm=4.0, name="a")
    assert m.name == "a" and m.volume.data.max() == 800
    assert m.volume.data.shape[2] == 10 + 2 * 4
    np.testing.assert_allclose(m.centroid, [8.5, 9.5, 9.5])
    with pytest.raises(ValueError, match="label"):
        bone_model(ct, labels=labels, label=7)
    with pytest.raises(ValueError, match="labels, label"):
        bone_model(ct, label=1)


def test_bone_model_rejects_a_ct_without_bone():
    ct = CTVolume(np.zeros((5, 5, 5), dtype=np.int16), name="empty")
    with pytest.raises(ValueError, match="threshold: no voxel of bone 'empty'"):
        bone_model(ct)
    with pytest.raises(ValueError, match="HU"):
        bone_model(CTVolume(np.ones((3, 3, 3), np.float32), units="1/mm"))


def test_bone_model_isolate_keeps_the_bone_and_its_marrow_and_drops_the_tissue_around_it():
    # a hollow shaft (cortex 900 HU, marrow 20 HU) cut open at one end of the crop, in soft tissue
    # of 40 HU with 12 HU of CT noise: rendered without a threshold, the noise above 40 HU would
    # give the DRR support over the whole crop
    g = np.random.default_rng(3)
    k, j, i = np.mgrid[0:40, 0:24, 0:24]
    r = np.hypot(i - 11.5, j - 11.5)
    data = 40.0 + 12.0 * g.standard_normal(r.shape)
    shaft = (r <= 7) & (k >= 6)
    data[shaft] = 900.0
    data[shaft & (r <= 4)] = 20.0  # the canal, open at the top slice
    ct = CTVolume(np.rint(data).astype(np.int16), spacing=(0.5, 0.5, 0.5), name="shaft")
    plain = bone_model(ct, mesh=False, margin_mm=2.0)
    iso = bone_model(ct, mesh=False, margin_mm=2.0, isolate_mm=1.0)
    np.testing.assert_array_equal(iso.mask, plain.mask)
    np.testing.assert_allclose(iso.centroid, plain.centroid)
    d, dp = iso.volume.data, plain.volume.data
    kk, jj, ii = np.mgrid[0:d.shape[0], 0:d.shape[1], 0:d.shape[2]]
    x, y = iso.volume.index_to_physical(np.column_stack([ii.ravel(), jj.ravel(), kk.ravel()]))[:, :2].T
    rr = np.hypot(x - 11.5 * 0.5, y - 11.5 * 0.5).reshape(d.shape)
    inside = rr <= 7 * 0.5 + 0.5  # the shaft and its partial-volume rim
    np.testing.assert_array_equal(d[inside & (kk >= 8)], dp[inside & (kk >= 8)])  # marrow included
    assert np.all(d[rr > 7 * 0.5 + 1.5] == -1000)  # tissue and noise beyond the rim: air
    assert np.all(dp[rr > 7 * 0.5 + 1.5] > -1000)
    with pytest.raises(ValueError, match="isolate_mm"):
        bone_model(ct, mesh=False, isolate_mm=-1.0)
