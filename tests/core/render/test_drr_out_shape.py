"""DRRRenderer.render(out_shape=...): a fixed output size for ROIs that change between calls."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from core.geometry import Camera, Rig, make_K
from core.render import CTVolume, DRRRenderer


def _camera(angle=0.0, pixels=48, f=1600.0):
    ca, sa = np.cos(angle), np.sin(angle)
    R = np.array([[ca, 0.0, -sa], [0.0, 1.0, 0.0], [sa, 0.0, ca]])
    c = (pixels - 1) / 2
    return Camera(make_K(f, f, c, c), R, [0.0, 0.0, 1000.0], pixels, pixels, pixel_size=0.9)


def test_out_shape_pads_the_items_and_keeps_the_buffer():
    rng = np.random.default_rng(2)
    vol = CTVolume((rng.random((12, 13, 14)) * 0.03).astype(np.float32), spacing=[1.0] * 3,
                   origin=[-6.0, -6.5, -7.0], units="1/mm")
    r = DRRRenderer(Rig((_camera(0.0), _camera(np.deg2rad(90)))), [vol], device="cpu")
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([0.1, -0.2, 0.05]).as_matrix()
    roi = np.array([[[[10, 12, 20, 18]], [[8, 9, 22, 25]]]])  # (B, views, bones, 4)
    plain = r.render(T[None, None], roi=roi)
    padded = r.render(T[None, None], roi=roi, out_shape=(32, 40))
    assert padded.images.shape == (2, 32, 40)
    a, b = plain.images.numpy(), padded.images.numpy()
    np.testing.assert_array_equal(b[:, : a.shape[1], : a.shape[2]], a)
    assert not b[:, a.shape[1]:].any() and not b[:, :, a.shape[2]:].any()  # zero beyond each ROI
    # a smaller ROI at the same out_shape renders into the same buffer
    again = r.render(T[None, None], roi=roi // 2 + 1, out_shape=(32, 40))
    assert again.images.ptr == padded.images.ptr
