"""The Gauss–Newton engine's poses on the device (core.tracking.engine_render): the item table of
pose_table_kernel is the host's, and a step rendered through it scores as the host path (CPU
device, 128² talus)."""

from __future__ import annotations

import numpy as np
import warp as wp

from core.geometry.transforms import pose_from_params
from core.render._kernels import ITEM_COLS
from core.tracking.cost import DEFAULT_TERMS, prepare_frame, search_roi
from core.tracking.engine import GaussNewtonCost, step_design
from core.tracking.engine_kernels import pose_table_kernel
from core.tracking.engine_render import DeviceRender, host_poses

H = np.array([0.25] * 3 + [0.5] * 3)


def _engine(sc, device_poses: bool):
    r, m = sc["renderer"], sc["model"]
    truth = sc["scene"].poses(2)[0]
    start = pose_from_params(np.r_[1.0, -0.8, 0.6, np.radians([1.0, -1.0, 1.5])], center=m.centroid,
                             base=truth)
    roi = search_roi(r, start, 0, views=(0, 1), center=m.centroid, reach_mm=7.6, points=m.outline)
    gn = GaussNewtonCost(r, bone=0, views=(0, 1), scale=1.0, term=DEFAULT_TERMS[0])
    if device_poses:  # on CUDA by default; here forced on the CPU
        gn._dev_render = DeviceRender(gn)
    gn.set_frame(prepare_frame(sc["fluence"](2)), base_pose=start, center=m.centroid, roi=roi)
    return gn


def test_device_table_is_the_hosts(talus_scene):
    gn = _engine(talus_scene, True)
    rng = np.random.default_rng(3)
    X = np.r_[step_design(np.zeros(6), H), rng.uniform(-4, 4, (3, 6)), np.zeros((1, 6))]
    X[-1, 3:] = [1e-10, 0.0, 0.0]  # below Rodrigues' small-angle threshold
    d = gn._dev_render
    table = wp.zeros((len(X) * 2, ITEM_COLS), dtype=wp.float32, device="cpu")
    wp.launch(pose_table_kernel, dim=(len(X), 2), device="cpu",
              inputs=[wp.array(X, dtype=wp.float64, device="cpu"), d.geo, d.src, d.view_ids, 0, table])
    gn._render(host_poses(X, gn.base, gn.center)[:, None], (0,))  # the host path's table
    ref = gn._tables[(len(X), (0,))][0].reshape(len(X) * 2, ITEM_COLS)
    np.testing.assert_allclose(table.numpy(), ref, rtol=2e-7, atol=1e-6)


def test_device_poses_step_scores_as_the_host_path(talus_scene):
    dev, host = _engine(talus_scene, True), _engine(talus_scene, False)
    x = np.array([0.3, -0.2, 0.1, -0.4, 0.5, 0.2])
    a, b = dev.step(x, H), host.step(x, H)
    np.testing.assert_allclose(a.costs, b.costs, atol=1e-6)
    np.testing.assert_allclose(a.g, b.g, rtol=1e-4, atol=1e-6 * np.abs(b.g).max())
    np.testing.assert_allclose(a.H, b.H, rtol=1e-4, atol=1e-6 * np.abs(b.H).max())
    np.testing.assert_allclose(dev(x[None]), host(x[None]), atol=1e-6)  # a single pose: its own pipeline


def test_second_round_keeps_the_regions_and_prepares_as_afresh(talus_scene):
    """The same frame and regions again with the neighbours at new poses (joint tracking's second
    round): the kept line integrals and masks are not prepared again, and the regions the engine
    scores are those a fresh engine prepares."""
    sc = talus_scene
    r, m = sc["renderer"], sc["model"]
    frame = prepare_frame(sc["fluence"](2))
    truth = sc["scene"].poses(2)[0]
    start = pose_from_params(np.r_[0.5, -0.3, 0.2, np.radians([0.5, -0.5, 0.8])], center=m.centroid,
                             base=truth)
    roi = search_roi(r, start, 0, views=(0, 1), center=m.centroid, reach_mm=7.6, points=m.outline)
    away = pose_from_params(np.r_[30.0, 0.0, 0.0, 0.0, 0.0, 0.0], center=m.centroid, base=truth)
    kept = GaussNewtonCost(r, bone=0, views=(0, 1), scale=1.0, term=DEFAULT_TERMS[0])
    kept.set_frame(frame, base_pose=start, center=m.centroid, roi=roi, others=(away[None], [0]))
    kept.step(np.zeros(6), H)  # the usable pixels counted and found
    kept.set_frame(frame, base_pose=truth, center=m.centroid, roi=roi, others=(away[None], [0]))
    assert not kept._count_pending  # nothing prepared again
    fresh = GaussNewtonCost(r, bone=0, views=(0, 1), scale=1.0, term=DEFAULT_TERMS[0])
    fresh.set_frame(frame, base_pose=truth, center=m.centroid, roi=roi, others=(away[None], [0]))
    for a in ("_raw", "_fluoro", "_fgrad", "_fmask"):
        np.testing.assert_array_equal(getattr(kept, a).numpy(), getattr(fresh, a).numpy())
    x = np.array([0.2, -0.1, 0.1, 0.3, -0.2, 0.1])
    np.testing.assert_array_equal(kept.step(x, H).costs, fresh.step(x, H).costs)
