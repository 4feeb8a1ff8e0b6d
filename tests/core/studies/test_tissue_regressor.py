"""tissue_regressor: a user's tissue volumes (resampled, scaled, shifted), estimated poses and the
regressor images."""

from types import SimpleNamespace

import numpy as np
import pytest

from core.render import CTVolume
from core.studies.tracking import tissue_regressor as tr


def _scene():
    z, y, x = np.mgrid[0:20, 0:16, 0:24]
    blob = ((x - 11.5) / 9) ** 2 + ((y - 7.5) / 6) ** 2 + ((z - 9.5) / 8) ** 2 < 1
    w = np.clip(z / 19.0, 0, 1)  # the shank part's share grows along z
    vols = [CTVolume((-1000 + 1040 * blob * s).astype(np.float32), spacing=np.full(3, 3.0),
                     origin=np.array([-30.0, -20.0, -25.0]), name=nm)
            for nm, s in (("soft_foot", 1 - w), ("soft_shank", w))]
    return SimpleNamespace(tissue=tuple(vols))


def _mass(v):
    return float((v.data + 1000).sum() * np.prod(v.spacing))


def test_user_tissue_volumes():
    sc = _scene()
    exact = tr.user_tissue(sc, "exact")
    assert exact[0] is sc.tissue[0]
    coarse = tr.user_tissue(sc, "coarse")
    assert np.allclose(coarse[0].spacing, 4.0)
    for a, b in zip(exact, coarse, strict=True):  # the same anatomy, resampled
        assert _mass(b) == pytest.approx(_mass(a), rel=0.1)
    assert np.allclose(tr.user_tissue(sc, "fine")[0].spacing, 2.0)
    big = tr.user_tissue(sc, "scale+2")
    assert np.allclose(big[0].spacing, 4.08)
    assert _mass(big[0]) == pytest.approx(_mass(coarse[0]) * 1.02**3, rel=1e-6)
    moved = tr.user_tissue(sc, "shift1")
    assert np.linalg.norm(moved[1].origin - coarse[1].origin) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="tissue"):
        tr.user_tissue(sc, "warped")


def test_estimated_poses_are_tracker_sized_and_repeatable():
    P = np.stack([np.eye(4)] * 3)
    models = [SimpleNamespace(centroid=np.full(3, 10.0 * b)) for b in range(3)]
    ts = SimpleNamespace(truth=lambda f: P, models=models)
    a, b = tr.estimated_poses(ts, 4, 0.05), tr.estimated_poses(ts, 4, 0.05)
    np.testing.assert_array_equal(a, b)
    assert 0 < np.abs(a[:, :3, 3]).max() < 0.5
    np.testing.assert_allclose(tr.estimated_poses(ts, 4, 0.0), P, atol=1e-12)


def test_regressor_images_through_the_psf():
    Lt = np.random.default_rng(0).uniform(0, 2, size=(2, 2, 12, 10))
    delta = np.zeros((3, 3))
    delta[1, 1] = 1
    one = tr.regressor_images(Lt, delta, parts=False)
    assert one.shape == (2, 1, 12, 10)
    np.testing.assert_allclose(one[:, 0], Lt.sum(axis=1), atol=1e-5)
    two = tr.regressor_images(Lt, np.ones((3, 3)), parts=True)
    assert two.shape == (2, 2, 12, 10) and two[0, 0].std() < Lt[0, 0].std()
    more = tr.regressor_images(Lt, delta, parts=False, gradients=True, laplacian=True)
    assert more.shape == (2, 4, 12, 10)  # the sum, its u and v derivatives and its Laplacian
    np.testing.assert_allclose(more[:, 1], np.gradient(one[:, 0], axis=2), atol=1e-12)
