"""The likelihood stage's two moments kernels (the full table and its upper triangle) build their
``z`` vector with one function (likelihood_fast.moments_z): on Warp's CPU device the triangle's
entries are the full table's to the bit, and both are Σ w z zᵀ of the pixels (float64 check)."""

from __future__ import annotations

import numpy as np
import warp as wp


def test_moments_kernels_share_z_and_agree():
    from core.tracking.likelihood_fast import design_diff_kernel, wls_moments_tri_kernel
    from core.tracking.likelihood_kernels import NZ, wls_moments_kernel

    g = np.random.default_rng(3)
    nv, H, W = 2, 24, 40
    hw = np.array([[24, 37], [19, 40]], np.int32)
    img13 = g.normal(size=(13 * nv, H, W)).astype(np.float32)
    low13 = (0.1 * g.normal(size=img13.shape)).astype(np.float32)
    y = g.normal(size=(nv, H, W)).astype(np.float32)
    w = g.uniform(0.0, 2.0, size=(nv, H, W)).astype(np.float32)
    w[w < 0.3] = 0.0
    o = g.normal(size=(nv, H, W)).astype(np.float32)
    dev = "cpu"
    ref = wp.array(hw, dtype=wp.vec2i, device=dev)
    A = {k: wp.array(v, dtype=wp.float32, device=dev) for k, v in
         {"img": img13, "low": low13, "y": y, "w": w, "o": o}.items()}
    dd = wp.zeros((7 * nv, H, W), dtype=wp.float32, device=dev)
    wp.launch(design_diff_kernel, dim=dd.shape, inputs=[A["img"], nv, ref, dd, 0], device=dev)
    low7 = wp.array(low13[:7 * nv], dtype=wp.float32, device=dev)
    for img, low, diff in ((A["img"], A["low"], 0), (dd, low7, 1)):
        tabs = []
        for kernel in (wls_moments_kernel, wls_moments_tri_kernel):
            acc = wp.zeros((nv, NZ * NZ), dtype=wp.float64, device=dev)
            wp.launch_tiled(kernel, dim=(nv, 3), block_dim=32, device=dev,
                            inputs=[img, low, 1.0, A["y"], A["w"], A["o"], ref, nv, 400, acc, diff])
            tabs.append(acc.numpy().reshape(nv, NZ, NZ))
        iu = np.triu_indices(NZ)
        np.testing.assert_array_equal(tabs[0][:, iu[0], iu[1]], tabs[1][:, iu[0], iu[1]])
        assert np.all(np.tril(tabs[1], -1) == 0)
        # against Σ w z zᵀ in float64 over each view's region
        im, lo = img.numpy().astype(np.float64), low.numpy().astype(np.float64)
        hi = im - lo
        for v in range(nv):
            h, wd = hw[v]
            Z = np.zeros((NZ, h, wd))
            Z[0] = y[v, :h, :wd]
            Z[1] = hi[v, :h, :wd]
            for j in range(6):
                Z[2 + j] = (hi[(j + 1) * nv + v, :h, :wd] if diff else
                            hi[(2 * j + 1) * nv + v, :h, :wd] - hi[(2 * j + 2) * nv + v, :h, :wd])
            Z[8] = 1.0
            Z[9] = (np.arange(wd) * (2.0 / max(wd - 1, 1)) - 1.0)[None, :]
            Z[10] = (np.arange(h) * (2.0 / max(h - 1, 1)) - 1.0)[:, None]
            Z[11] = o[v, :h, :wd]
            ww = np.where(w[v, :h, :wd] > 0, w[v, :h, :wd], 0.0)
            M = np.einsum("ihw,jhw,hw->ij", Z, Z, ww)
            np.testing.assert_allclose(tabs[0][v], M, rtol=2e-4, atol=2e-3)


def test_regressor_moments_kernel_extends_the_full_table():
    """The moments kernel with extra regressors (likelihood_kernels.regressor_kernels, q = 1): its first
    12 × 12 entries are wls_moments_kernel's table to the bit (the same z through moments_z), the last
    row and column Σ w z t (float64 check)."""
    from core.tracking.likelihood_kernels import NZ, regressor_kernels, wls_moments_kernel

    g = np.random.default_rng(5)
    nv, H, W = 2, 20, 32
    hw = np.array([[20, 29], [17, 32]], np.int32)
    dev = "cpu"
    ref = wp.array(hw, dtype=wp.vec2i, device=dev)
    img = wp.array(g.normal(size=(13 * nv, H, W)).astype(np.float32), device=dev)
    low = wp.array((0.1 * g.normal(size=(13 * nv, H, W))).astype(np.float32), device=dev)
    y, o, t = (g.normal(size=(nv, H, W)).astype(np.float32) for _ in range(3))
    w = g.uniform(0.0, 2.0, size=(nv, H, W)).astype(np.float32)
    w[w < 0.3] = 0.0
    Y, O, T, Wt = (wp.array(a, dtype=wp.float32, device=dev) for a in (y, o, t, w))
    acc = wp.zeros((nv, NZ * NZ), dtype=wp.float64, device=dev)
    wp.launch_tiled(wls_moments_kernel, dim=(nv, 2), block_dim=32, device=dev,
                    inputs=[img, low, 1.0, Y, Wt, O, ref, nv, 400, acc, 0])
    nz = NZ + 1
    acc1 = wp.zeros((nv, nz * nz), dtype=wp.float64, device=dev)
    wp.launch_tiled(regressor_kernels(1)[0], dim=(nv, 2), block_dim=32, device=dev,
                    inputs=[img, low, 1.0, Y, Wt, O, T, ref, nv, 400, acc1, 0])
    full, ext = acc.numpy().reshape(nv, NZ, NZ), acc1.numpy().reshape(nv, nz, nz)
    np.testing.assert_array_equal(ext[:, :NZ, :NZ], full)
    for v in range(nv):
        h, wd = hw[v]
        ww = np.where(w[v, :h, :wd] > 0, w[v, :h, :wd], 0.0).astype(np.float64)
        np.testing.assert_allclose(ext[v, NZ, NZ], np.sum(ww * t[v, :h, :wd].astype(np.float64) ** 2),
                                   rtol=1e-4)
        np.testing.assert_allclose(ext[v, 0, NZ], np.sum(ww * y[v, :h, :wd] * t[v, :h, :wd]), rtol=1e-4,
                                   atol=1e-3)
