"""engine_buffers.copy_array: wp.copy's bytes without its checks between a CUDA array and host memory."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from core.tracking.engine_buffers import copy_array


def test_copy_array_on_the_host_is_wp_copy():
    src = wp.array(np.arange(12, dtype=np.float32), device="cpu")
    a = wp.zeros(12, dtype=wp.float32, device="cpu")
    b = wp.zeros(12, dtype=wp.float32, device="cpu")
    copy_array(a, src, 5)
    wp.copy(b, src, 0, 0, 5)
    assert np.array_equal(a.numpy(), b.numpy()) and a.numpy()[4] == 4 and a.numpy()[5] == 0
    copy_array(a, src)
    assert np.array_equal(a.numpy(), src.numpy())
    with pytest.raises(ValueError, match="do not fit"):
        copy_array(wp.zeros(4, dtype=wp.float32, device="cpu"), src)
    with pytest.raises(ValueError, match="do not fit"):  # (checked before the runtime's copy)
        copy_array(a, src, -3)
    with pytest.raises(ValueError, match="do not fit"):  # (elements of another size)
        copy_array(wp.zeros(12, dtype=wp.float64, device="cpu"), src)


@pytest.mark.skipif(not wp.is_cuda_available(), reason="a CUDA device")
def test_copy_array_between_host_and_device_is_wp_copy():
    dev = wp.get_cuda_device()
    host = wp.array(np.arange(2 * 5 * 7, dtype=np.float32).reshape(2, 5, 7), device="cpu", pinned=True)
    d1 = wp.zeros((2, 5, 7), dtype=wp.float32, device=dev)
    d2 = wp.zeros((2, 5, 7), dtype=wp.float32, device=dev)
    copy_array(d1, host, 40)
    wp.copy(d2, host, 0, 0, 40)
    back1 = wp.zeros((2, 5, 7), dtype=wp.float32, device="cpu", pinned=True)
    back2 = wp.zeros((2, 5, 7), dtype=wp.float32, device="cpu", pinned=True)
    copy_array(back1, d1)
    wp.copy(back2, d2)
    wp.synchronize_device(dev)
    assert np.array_equal(back1.numpy(), back2.numpy())
    assert back1.numpy().ravel()[39] == 39 and back1.numpy().ravel()[40] == 0
