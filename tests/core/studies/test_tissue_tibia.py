"""tissue_tibia: a pose moved by a tracker's error, and the first-order bias of one view's terms."""

from types import SimpleNamespace

import numpy as np
import pytest

from core.geometry.transforms import pose_from_params
from core.studies.tracking import tissue_tibia as tt
from core.studies.tracking.acceptance import pose_errors
from tests.core.studies._blobs import blobs as _blobs


def test_moved_pose_has_the_given_error():
    c = np.array([10.0, -5.0, 30.0])
    P = pose_from_params(np.array([[1.0, 2.0, -3.0, 0.1, -0.2, 0.3]]), center=c, base=np.eye(4))[0]
    e = np.array([0.02, -0.01, 0.03, 0.05, -0.04, 0.2])
    np.testing.assert_allclose(pose_errors(tt._moved(P, e, c), P, c), e, atol=1e-9)


@pytest.mark.parametrize("tissue", [False, True])
def test_view_terms_give_back_a_small_offset(tissue):
    h = 0.05
    X = np.concatenate([np.zeros((1, 6)), np.eye(6) * h, -np.eye(6) * h])
    D = [np.stack([_blobs(x) for x in X])]
    delta = np.array([0.03, -0.02, 0.01, 0.04, -0.03, 0.02])
    y = 0.9 * _blobs(delta) + 0.2
    T = None
    if tissue:  # a smooth ramp the frame holds at a gain of its own, fitted out
        v, u = np.mgrid[0:40, 0:48].astype(float)
        ramp = np.exp(-((u - 20) ** 2 + (v - 18) ** 2) / (2 * 9.0**2))
        T = [ramp]
        y = y + 0.7 * (ramp - ramp.mean())  # (high-passed with a σ far beyond the region: a constant out)
    cost = SimpleNamespace(_filtered=lambda img: np.asarray(img, float), weights=[np.ones((40, 48))],
                           fluoro_rois=[y])
    JD, JT, r, coef = tt._view_terms(cost, D, T, 0, (0, 0, 48, 40), 1e3, h)
    assert JT is None  # (one tissue image: no pose derivative)
    est = np.linalg.solve(JD @ JD.T, JD @ r)
    np.testing.assert_allclose(est, delta, rtol=0.05, atol=2e-4)
    assert coef[0] == pytest.approx(0.9, rel=0.01)
    if tissue:
        assert coef[2] == pytest.approx(0.7, rel=0.05)
