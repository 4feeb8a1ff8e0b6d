"""The harder synthetic foot trial: shapes, trabecular network, CT-not-truth, overlap in both views."""

from __future__ import annotations

import numpy as np
import pytest

from core.synthetic.hard_foot import (
    HARD_BONES,
    NEIGHBOURS,
    hard_bone_spec,
    make_hard_foot_scene,
    trabecular_network,
)


def test_trabecular_network_fraction_and_texture():
    g = np.random.default_rng(0)
    net = trabecular_network((40, 40, 40), 0.5, g, spacing_mm=1.6, bvf=0.25)
    assert 0.0 <= net.min() and net.max() <= 1.0
    assert net.mean() == pytest.approx(0.25, abs=0.08)
    assert net.std() > 0.2  # a network (mostly 0 or 1), not a faint texture


@pytest.mark.parametrize("name", HARD_BONES + NEIGHBOURS)
def test_shapes_are_solid_and_of_anatomical_size(name):
    from core.synthetic.phantoms import _extent

    spec = hard_bone_spec(name).base
    lo, hi = _extent(spec.shape, spec.search, 0.0)
    size = hi - lo
    assert np.all(size > 15) and np.all(size < 160)
    if name == "talus":
        assert 55 < size[0] < 80  # ~65 mm long (+ 2 mm of search steps each side)


@pytest.fixture(scope="module")
def trial():
    return make_hard_foot_scene(n_frames=2, pixels=64, spacing=3.0, tissue_spacing=8.0)


def test_ct_is_not_the_truth(trial):
    for ct, truth in zip(trial.ct, trial.truth_volumes, strict=True):
        assert ct.data.dtype == np.int16 and ct.data.shape == truth.data.shape
        assert not np.allclose(ct.origin, truth.origin)
        diff = ct.data.astype(float) - truth.data
        assert 5 < np.std(diff) < 400
        # same physical frame: the bone's centre of mass (HU above soft tissue, a linear weight
        # that resampling keeps) agrees within a voxel
        def com(v):
            w = np.asarray(v.data, float) - 40.0
            k, j, i = np.indices(w.shape)
            ijk = np.array([(w * i).sum(), (w * j).sum(), (w * k).sum()]) / w.sum()
            return v.index_to_physical(ijk[None])[0]

        assert np.linalg.norm(com(ct) - com(truth)) < 2.0


def test_bones_overlap_in_both_views_and_neighbours_are_rendered(trial):
    sc = trial.scene
    assert sc.names == HARD_BONES + NEIGHBOURS
    P = sc.poses(0)

    def box(vol, T, cam):
        lo, hi = vol.bounds()
        c = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        uv = cam.project(c @ T[:3, :3].T + T[:3, 3])
        return uv.min(0), uv.max(0)

    for cam in sc.rig:
        b = [box(v, T, cam) for v, T in zip(sc.bones, P, strict=True)]
        for other in (0, 2, 3):  # the talus overlaps tibia, calcaneus and fibula in every view
            assert np.all(b[1][0] < b[other][1]) and np.all(b[other][0] < b[1][1])
