"""The final stage's robust factors filtered on the device
(core.tracking.engine_likelihood.robust_factors_device) against the host's
(core.tracking.final_stage.robust_factors), and the stage's pose with either (CPU device)."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.mark.parametrize("kind", ["cauchy", "huber"])
def test_device_factors_equal_the_hosts(kind):
    import warp as wp

    from core.tracking.engine_likelihood import robust_factors_device
    from core.tracking.final_stage import robust_factors

    g = np.random.default_rng(1)
    e = g.normal(0.0, 1.0, (2, 72, 90))
    e[0, 20:30, 10:50] += 8.0  # structure the model lacks
    e[1, 50:53, 5:80] -= 5.0
    w = g.uniform(0.5, 2.0, e.shape)
    w[0, :, 70:] = 0.0  # outside the region (padded layout)
    w[1, 60:, :] = 0.0
    w[1, 10:14, 30:40] = 0.0  # unusable pixels
    e = np.where(w > 0, e, 0.0)
    host = robust_factors(e, w > 0, 2.5, sigma_px=2.0, kind=kind)
    dev = robust_factors_device(wp.array(e.astype(np.float32), dtype=wp.float32, device="cpu"),
                                wp.array(w.astype(np.float32), dtype=wp.float32, device="cpu"), 2.5,
                                sigma_px=2.0, kind=kind).numpy()
    assert dev.shape == host.shape
    assert np.max(np.abs(dev - host)) < 1e-4
    assert np.all(dev[w == 0] == 0) and np.max(dev[0, 22:28, 15:45]) < (0.2 if kind == "cauchy" else 0.5)


def test_stage_pose_the_same_with_device_factors(talus_scene):
    import core.tracking.final_stage as fst
    from core.tracking.cost import prepare_frame
    from core.tracking.register import RegistrationOptions, register

    sc, bone, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    truth = sc.poses(2)[0]
    fr = prepare_frame(talus_scene["fluence"](2), valid_range=None)
    o = RegistrationOptions(bounds=(3.0, 3.0), search="newton", final="likelihood", final_highpass_px=2.0)
    poses = []
    for on in (True, False):
        fst.ROBUST_ON_DEVICE = on
        try:
            res = register(r, fr, bone=0, initial_pose=truth, center=bone.centroid, options=o)
        finally:
            fst.ROBUST_ON_DEVICE = True
        assert res.timing["likelihood_taken"] == 1
        poses.append(res.pose)
    assert np.allclose(poses[0][:3, 3], poses[1][:3, 3], atol=1e-4)  # mm
    assert np.allclose(poses[0][:3, :3], poses[1][:3, :3], atol=1e-6)


def test_device_median_is_numpys():
    """The per-view scale of the robust factors (the median of the local RMS over the used
    pixels) taken on the device equals np.median's, for odd and even counts of used pixels."""
    import warp as wp

    from core.tracking.engine_likelihood import robust_factors_device

    g = np.random.default_rng(2)
    e = g.normal(0.0, 1.0, (3, 33, 17))
    w = g.uniform(0.5, 2.0, e.shape)
    w[0, :, 9:] = 0.0  # 33 · 9 used (odd)
    w[1, 4:8, 2:12] = 0.0  # 561 - 40 (odd)
    w[2, 0, :] = 0.0  # 544 (even)
    bufs: dict = {}
    f = robust_factors_device(wp.array(e.astype(np.float32), dtype=wp.float32, device="cpu"),
                              wp.array(w.astype(np.float32), dtype=wp.float32, device="cpu"), 2.5, bufs=bufs)
    local = bufs["rf_local"].numpy()
    want = np.array([np.median(x[x >= 0]) for x in local], dtype=np.float32)
    np.testing.assert_array_equal(bufs["rf_scale"].numpy(), want)
    assert np.all(f.numpy()[w == 0] == 0)
