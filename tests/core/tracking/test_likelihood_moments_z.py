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
