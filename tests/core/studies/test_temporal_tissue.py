"""temporal_tissue: variant names, the residual of a frame (gains, neighbours), its average over
frames (shifted, low-passed) and the neighbours' gain correction — tiny images, no rendering."""

from types import SimpleNamespace

import numpy as np
import pytest

from core.studies.tracking import temporal_tissue as tt


def test_parse_variants():
    p = tt.parse("hp4+r", 256)
    assert p["source"] is None and p["method"] == "hp4+r" and p["K"] == 0
    p = tt.parse("a4l:hp2+r", 256)
    assert (p["source"], p["K"], p["lowpass_px"], p["shift"], p["regressor"], p["method"]) == (
        "a", 4, 1.0, False, False, "hp2+r")
    p = tt.parse("b12l8sg:hp0+r", 512)
    assert (p["source"], p["K"], p["lowpass_px"], p["shift"], p["regressor"]) == ("b", 12, 4.0, True, True)
    assert tt.parse("a1t:hp0+r", 256)["tissue_motion"]
    assert tt.parse("p2c:hp0+r", 256)["centred"]
    for bad in ("c1:hp0", "a:hp0", "a0:hp0", "a2x:hp0", "b1t:hp0", "b1c:hp0"):
        with pytest.raises(ValueError, match="variant"):
            tt.parse(bad, 256)


def _images(rng, h=48, w=40):
    """Two views of two bones (sharp-edged blobs) plus a smooth tissue ramp."""
    v, u = np.mgrid[0:h, 0:w].astype(float)
    D = np.zeros((2, 2, h, w))
    for view in range(2):
        D[view, 0] = 0.5 * (((u - 14 - view) / 7) ** 2 + ((v - 20) / 9) ** 2 < 1)
        D[view, 1] = 0.4 * (((u - 27) / 6) ** 2 + ((v - 26 - view) / 8) ** 2 < 1)
    T = np.stack([2.0 + 0.02 * u + 0.01 * v + 0.1 * view for view in range(2)])
    return D, T


def test_residual_images_gains_and_neighbour_correction():
    rng = np.random.default_rng(0)
    D, T = _images(rng)
    g_true = np.array([[0.9, 0.8], [0.85, 0.7]])
    Y = T + np.einsum("vb,vbhw->vhw", g_true, D)
    g = tt.view_gains(Y, D, None, highpass_px=1.0)
    np.testing.assert_allclose(g, g_true, atol=0.02)  # the smooth tissue leaves the high-passed fit
    batch = SimpleNamespace(numpy=lambda: D[None].astype(np.float32))
    renderer = SimpleNamespace(render=lambda P, roi: batch)
    frame = SimpleNamespace(images=tuple(Y.astype(np.float32)), masks=(None, None))
    R, g2 = tt.residual_images(renderer, frame, np.stack([np.eye(4)] * 2), highpass_px=1.0)
    np.testing.assert_allclose(g2, g)
    assert np.abs(R - T).max() < 0.03  # what the bones leave: the tissue
    R1, g1 = tt.residual_images(renderer, frame, np.stack([np.eye(4)] * 2), highpass_px=None)
    np.testing.assert_array_equal(g1, 1.0)
    np.testing.assert_allclose(R1, Y - D.sum(axis=1), atol=1e-5)
    # with the residual and the correction subtracted, the neighbour (bone 1) subtracted at gain 1
    # leaves bone 0 at its own gain over the tissue it carried
    C = tt.neighbour_correction(D, g, 0)
    left = Y - R - C - D[:, 1]
    np.testing.assert_allclose(left, g[:, 0, None, None] * D[:, 0], atol=1e-5)
    np.testing.assert_array_equal(tt.neighbour_correction(D, np.ones((2, 2)), 1), 0.0)


def test_averaged_shift_and_lowpass():
    rng = np.random.default_rng(1)
    R = [rng.normal(size=(2, 32, 32)) for _ in range(4)]
    np.testing.assert_allclose(tt.averaged(R), np.mean(R, axis=0))
    assert tt.averaged(R, lowpass_px=1.0).std() < 0.5 * tt.averaged(R).std()
    img = np.zeros((1, 32, 32))
    img[0, 10, 12] = 1.0
    moved = tt.averaged([img], shifts=[np.array([[3.0, -2.0]])])  # (du, dv): 3 columns right, 2 rows up
    assert np.unravel_index(np.argmax(moved[0]), moved[0].shape) == (8, 15)


def test_projected_shift_of_a_translation():
    cams = [SimpleNamespace(project=lambda X, s=s: s * np.asarray(X)[..., :2]) for s in (2.0, 3.0)]
    rig = SimpleNamespace(project=lambda X: np.stack([c.project(X) for c in cams]))
    P1 = np.eye(4)
    P1[:3, 3] = (1.0, -0.5, 4.0)
    d = tt.projected_shift(rig, np.array([5.0, 6.0, 7.0]), np.eye(4), P1)
    np.testing.assert_allclose(d, [[2.0, -1.0], [3.0, -1.5]])
