"""Gauss–Newton registration engine: the cost's gradient and curvature from 13 poses per step.

The similarity of :data:`core.tracking.cost.DEFAULT_TERMS` (gradient correlation, GC) and NCC
are Pearson correlations ``r = cov(a, b) / sqrt(var a · var b)`` over the domain Ω of the
fluoroscope quantity ``a`` (GC: the gradient magnitude of the smoothed fluoroscope ROI; NCC: its
intensity) and the DRR quantity ``b(x)`` at pose parameters ``x`` (mm, degrees; see
:mod:`core.tracking.cost`). With ``â``, ``b̂`` the centred, unit-length vectors,
``1 - r = ½ ‖â - b̂(x)‖²``: a least-squares problem in the pixels, solved by Gauss–Newton /
Levenberg–Marquardt steps.

One step (:meth:`GaussNewtonCost.step`)
---------------------------------------
One DRR launch renders the 13 poses ``x``, ``x ± h_k e_k`` (both views); the DRRs are smoothed on
the device as the metric smooths them; one pass over the pixels of Ω (that of the centre DRR)
accumulates, per view, the 9 × 9 moment matrix of ``z = (1, a, b(x), δ_1 … δ_6)`` with
``δ_k = b(x + h_k e_k) - b(x - h_k e_k)`` (per-pixel central differences: ``∂b/∂x_k ≈ δ_k / 2h_k``).
From it, in float64 on the host (6 × 6 arithmetic)::

    ∂r/∂x_k = cov(a, D_k) / sqrt(var a var b) - r cov(b, D_k) / var b          D_k = δ_k / 2h_k
    (JᵀJ)_kl = [cov(D_k, D_l) - cov(b, D_k) cov(b, D_l) / var b] / var b

(covariances as centred sums over Ω). The cost ``Σ_v w_v (1 - r_v)`` (mean over views) has the
gradient ``g = -Σ w_v ∂r_v/∂x`` and the Gauss–Newton Hessian ``H = Σ w_v (JᵀJ)_v`` — the whole
6 × 6 curvature, couplings included, from 13 poses (a fitted quadratic needs ≥ 28). The same
launch also scores the 13 poses with the ordinary cost (per-pose Ω, as
:class:`~core.tracking.cost.RegistrationCost` scores them), so a step needs no other launch.

Search (:func:`gauss_newton_search`)
------------------------------------
Levenberg–Marquardt: the step ``d = -(H + λ diag H)⁻¹ g`` (clipped to a trust box and the
search box) is taken when the cost at the new centre is not worse than the old one by more than
the cost's roughness; otherwise λ grows ×10 and the step is recomputed from the old centre's
``g``, ``H`` (no extra launch). Converged (``"tol_x"``) when every coordinate of a step from an
accepted centre is below ``tol_x``; the result is that centre plus the step (the model's
minimum). A fixed point of the iteration is a stationary point of the cost: the gradient is the
cost's own (central differences of the images), only the curvature is approximated.

The last step's 13 cost values, fitted by ``c0 + gᵀd + ½ dᵀHd`` with ``H`` fixed (7 free
coefficients, 6 residual degrees of freedom), give the cost's roughness ``σ_c`` at the scale of
``h``; :func:`core.tracking.confidence.confidence_from_fit` turns ``(H, σ_c)`` into the pose
uncertainty as it does for the quadratic-model search's fit.

Speed design
------------
:class:`GaussNewtonCost` keeps its device buffers, the DRR output buffer (a fixed output size,
:meth:`core.render.DRRRenderer.render` ``out_shape``, the ROIs' size rounded up to 32 pixels)
and, on CUDA, one graph of the metric pipeline (2 blur passes, scores, moments, copies to
pinned host memory) from frame to frame. At full resolution :meth:`~GaussNewtonCost.set_frame`
uploads each view's region of the fluence as it is (grown by the usable-pixel mask's erosion)
and :func:`fluoro_roi_kernel` computes the line integrals, the eroded mask and their statistics
on the device (the same values as :meth:`core.tracking.cost.FrameImages.region`; the regions
stay on the device for the next round of joint tracking in the same frame); at a pyramid level
the host prepares them. Smoothing and gradients run on the device. The engine fills the DRR
item table of its own (rigid) poses itself and launches the renderer's recorded launch.
:func:`engine_cost` caches one per (renderer, bone, views, scale, terms). A step is one DRR
launch, one graph launch and one synchronisation; a frame's set-up one more synchronisation
(the usable pixels counted).
"""

from __future__ import annotations

import math
import time
import weakref
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..render._kernels import ITEM_COLS
from ..similarity import _kernels as K
from .cost import CostTimer, FrameImages, MetricTerm, OutsideViewError, _in_pixels, fluoro_rois, mm_per_pixel
from .optimize import OptimizeResult
from .quadratic import QuadraticFit

__all__ = ["ENGINE_KINDS", "GaussNewtonCost", "GaussNewtonFit", "GaussNewtonStep", "engine_cost",
           "gauss_newton_search", "moments_to_newton", "step_design", "supports"]

#: Similarity kinds the engine handles (Pearson correlations of a per-pixel quantity).
ENGINE_KINDS = ("gc", "ncc")
_MODE = {"ncc": 0, "gc": 1}
_KIND = {"ncc": K.K_NCC, "gc": K.K_GC}
_OPTIONS = ("fluoro_sigma", "drr_sigma", "fluoro_sigma_mm", "drr_sigma_mm", "threshold", "dilate", "operator")
_N = 13  # poses per step: the centre and ±h_k e_k

vec9f = wp.types.vector(length=9, dtype=wp.float32)
mat99f = wp.types.matrix(shape=(9, 9), dtype=wp.float32)


@wp.func
def _bq(mode: int, img: wp.array3d(dtype=wp.float32), k: int, r: int, c: int, h: int, w: int,
        ku: wp.mat33f, kv: wp.mat33f) -> float:
    """The DRR quantity b of item k at (r, c): intensity (mode 0) or gradient magnitude (1)."""
    out = float(0.0)  # noqa: UP018 (a Warp variable, not a constant)
    if mode == 0:
        out = K._val(img, k, r, c)
    else:
        out = wp.length(K._grad(img, k, r, c, h, w, ku, kv))
    return out


@wp.kernel
def moments_kernel(drr: wp.array3d(dtype=wp.float32), fluoro: wp.array3d(dtype=wp.float32),
                   fgrad: wp.array3d(dtype=wp.vec2f), fmask: wp.array3d(dtype=wp.uint8),
                   ref_hw: wp.array(dtype=wp.vec2i), fshift: wp.array(dtype=wp.float32), n_refs: int,
                   thr: float, dil: int, mode: int, ku: wp.mat33f, kv: wp.mat33f, chunk: int,
                   acc: wp.array2d(dtype=wp.float64)):
    """acc[v] += Σ_Ω z zᵀ (row-major 9 × 9), z = (1, a, b_0, b_1 - b_2, …, b_11 - b_12) of view v;
    item j of view v is j · n_refs + v; Ω is that of the centre item (j = 0). dim = (views, chunks)."""
    v, ch, lane = wp.tid()
    bd = wp.block_dim()
    h = ref_hw[v][0]
    w = ref_hw[v][1]
    W = drr.shape[2]
    start = ch * chunk
    stop = wp.min(drr.shape[1] * W, start + chunk)
    s = mat99f()
    for p in range(start + lane, stop, bd):
        r = p // W
        c = p - r * W
        if r < h and c < w:
            if K._in_omega(drr, fmask, v, v, r, c, h, w, thr, dil):
                a = float(0.0)  # noqa: UP018
                if mode == 0:
                    a = fluoro[v, r, c] - fshift[v]
                else:
                    a = wp.length(fgrad[v, r, c])
                z = vec9f()
                z[0] = 1.0
                z[1] = a
                z[2] = _bq(mode, drr, v, r, c, h, w, ku, kv)
                for j in range(6):
                    bp = _bq(mode, drr, (2 * j + 1) * n_refs + v, r, c, h, w, ku, kv)
                    bm = _bq(mode, drr, (2 * j + 2) * n_refs + v, r, c, h, w, ku, kv)
                    z[3 + j] = bp - bm
                s += wp.outer(z, z)
    t = wp.tile_sum(wp.tile(s, preserve_type=True))
    if lane == 0:
        x = t[0]
        for i in range(9):
            for j in range(9):
                wp.atomic_add(acc, v, i * 9 + j, wp.float64(x[i, j]))


@wp.kernel
def subtract_kernel(drr: wp.array3d(dtype=wp.float32), n_bones: int, out: wp.array3d(dtype=wp.float32)):
    """out[v] -= Σ_n drr[v · n_bones + n] (one pose's items, ordered view, bone). dim = (views, H, W)."""
    v, r, c = wp.tid()
    acc = float(0.0)  # noqa: UP018
    for n in range(n_bones):
        acc += K._val(drr, v * n_bones + n, r, c)
    out[v, r, c] = out[v, r, c] - acc


@wp.kernel
def fluoro_gradient_kernel(f: wp.array3d(dtype=wp.float32), ref_hw: wp.array(dtype=wp.vec2i),
                           fmax: wp.array(dtype=wp.float32), ku: wp.mat33f, kv: wp.mat33f,
                           out: wp.array3d(dtype=wp.vec2f)):
    """3 × 3 gradient of each fluoroscope ROI (replicated borders), 0 where its length is below
    ``ZERO_GRADIENT · max(1, max |f|)`` (as :class:`core.similarity.BatchedMetric` prepares it on
    the host) and outside the ROI. dim = (views, H, W)."""
    v, r, c = wp.tid()
    h = ref_hw[v][0]
    w = ref_hw[v][1]
    g = wp.vec2f(0.0, 0.0)
    if r < h and c < w:
        gu = float(0.0)  # noqa: UP018
        gv = float(0.0)  # noqa: UP018
        for a in range(3):
            rr = wp.clamp(r + a - 1, 0, h - 1)
            for b in range(3):
                cc = wp.clamp(c + b - 1, 0, w - 1)
                x = f[v, rr, cc]
                gu += ku[a, b] * x
                gv += kv[a, b] * x
        g = wp.vec2f(gu, gv)
        if wp.length(g) <= K.ZERO_GRADIENT * wp.max(1.0, fmax[v]):
            g = wp.vec2f(0.0, 0.0)
    out[v, r, c] = g


_LANES = 128  # threads per (view, chunk) of fluoro_roi_kernel
LI_FLOOR = wp.constant(1.0 / 4096.0)  # core.tracking.cost's line-integral floor


@wp.kernel
def fluoro_roi_kernel(src: wp.array3d(dtype=wp.float32), given: wp.array3d(dtype=wp.uint8),
                      info: wp.array2d(dtype=wp.int32), lo: float, hi: float, p: int, check: int, chunk: int,
                      raw: wp.array3d(dtype=wp.float32), fmask: wp.array3d(dtype=wp.uint8),
                      fmax: wp.array(dtype=wp.float32), msum: wp.array2d(dtype=wp.float64)):
    """Each view's search region in DRR polarity ``-ln clip(I, 1/4096, 1)`` and its usable pixels,
    as :meth:`core.tracking.cost.FrameImages.region` computes them on the host: ``src[v]`` holds
    the fluence of the region grown by ``p`` pixels (clipped to the image) and ``given[v]`` the
    frame's own mask there; ``info[v] = (h, w, oy, ox, hs, ws, has_given, _)`` (the region's size,
    its offset in ``src``, the staged size). With ``check``, a pixel is usable when every pixel
    within L1 distance ``p`` inside the image lies in ``(lo, hi)`` (the cross erosion iterated
    ``p`` times, outside the image counted usable). ``fmax[v]`` = max over the region,
    ``msum[v] = (usable pixels, Σ usable values)``. dim = (views, chunks, _LANES)."""
    v, ch, lane = wp.tid()
    h = info[v, 0]
    w = info[v, 1]
    oy = info[v, 2]
    ox = info[v, 3]
    hs = info[v, 4]
    ws = info[v, 5]
    W = raw.shape[2]
    start = ch * chunk
    stop = wp.min(raw.shape[1] * W, start + chunk)
    n = float(0.0)  # noqa: UP018 (Warp variables, not constants)
    s = float(0.0)  # noqa: UP018
    mx = float(0.0)  # noqa: UP018
    for q in range(start + lane, stop, _LANES):
        r = q // W
        c = q - r * W
        x = float(0.0)  # noqa: UP018
        ok = int(0)  # noqa: UP018, RUF046
        if r < h and c < w:
            rr = r + oy
            cc = c + ox
            x = -wp.log(wp.clamp(src[v, rr, cc], LI_FLOOR, 1.0))
            ok = int(1)  # noqa: UP018, RUF046
            if check != 0:
                for dr in range(-p, p + 1):
                    y = rr + dr
                    if y >= 0 and y < hs:
                        a = p - wp.abs(dr)
                        for dc in range(-a, a + 1):
                            z = cc + dc
                            if z >= 0 and z < ws:
                                u = src[v, y, z]
                                if not (u > lo and u < hi):
                                    ok = int(0)  # noqa: UP018, RUF046
            if info[v, 6] != 0:
                if given[v, rr, cc] == wp.uint8(0):
                    ok = int(0)  # noqa: UP018, RUF046
            mx = wp.max(mx, x)
            if ok != 0:
                n += 1.0
                s += x
        raw[v, r, c] = x
        fmask[v, r, c] = wp.uint8(ok)
    if mx > 0.0:
        wp.atomic_max(fmax, v, mx)
    if n > 0.0:
        wp.atomic_add(msum, v, 0, wp.float64(n))
        wp.atomic_add(msum, v, 1, wp.float64(s))


@wp.kernel
def fluoro_shift_kernel(msum: wp.array2d(dtype=wp.float64), mode: int, fshift: wp.array(dtype=wp.float32),
                        count: wp.array(dtype=wp.int32)):
    """NCC: the mean of each view's usable values (0 for GC); the usable pixels' count. dim = views."""
    v = wp.tid()
    n = msum[v, 0]
    m = float(0.0)  # noqa: UP018
    if mode == 0 and n > wp.float64(0.0):
        m = float(msum[v, 1] / n)
    fshift[v] = m
    count[v] = int(n)


def _poses(X: np.ndarray, base: np.ndarray, center: np.ndarray) -> np.ndarray:
    """:func:`core.geometry.transforms.pose_from_params` of ``(mm, degrees)`` rows ``X``."""
    r = np.radians(X[:, 3:])
    th = np.linalg.norm(r, axis=1)
    small = th < 1e-8
    k = r / np.where(small, 1.0, th)[:, None]
    Kx = np.zeros((len(X), 3, 3))
    Kx[:, 0, 1], Kx[:, 0, 2], Kx[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    Kx[:, 1, 0], Kx[:, 2, 0], Kx[:, 2, 1] = k[:, 2], -k[:, 1], k[:, 0]
    s, c = np.sin(th)[:, None, None], (1.0 - np.cos(th))[:, None, None]
    Rd = np.eye(3) + s * Kx + c * (Kx @ Kx)
    Rd[small] = np.eye(3)
    Rb, tb = base[:3, :3], base[:3, 3]
    c_lab = Rb @ center + tb
    R = Rd @ Rb
    out = np.zeros((len(X), 4, 4))
    out[:, :3, :3] = R
    out[:, :3, 3] = c_lab + X[:, :3] - R @ center
    out[:, 3, 3] = 1.0
    return out


def step_design(x, h) -> np.ndarray:
    """``(13, 6)`` poses of a step: ``x``, then ``x + h_k e_k``, ``x - h_k e_k`` for k = 1…6."""
    x = np.asarray(x, dtype=float)
    h = np.asarray(h, dtype=float)
    X = np.repeat(x[None], _N, axis=0)
    for k in range(6):
        X[1 + 2 * k, k] += h[k]
        X[2 + 2 * k, k] -= h[k]
    return X


def moments_to_newton(M, h, weights=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(r (n_views,), g (6,), H (6, 6))`` from the moment matrices ``M (n_views, 9, 9)`` of
    :func:`moments_kernel` and the half-steps ``h (6,)``: each view's correlation, and the
    gradient and Gauss–Newton Hessian of the cost ``Σ_v w_v (1 - r_v)`` (``weights`` default
    equal, normalised) in x units (see the module docs). A view without contrast in Ω
    contributes r = 0 and nothing to g and H."""
    M = np.asarray(M, dtype=np.float64).reshape(-1, 9, 9)
    h = np.asarray(h, dtype=float)
    nv = len(M)
    w = np.full(nv, 1.0 / nv) if weights is None else np.asarray(weights, float) / np.sum(weights)
    r_out = np.zeros(nv)
    g = np.zeros(6)
    H = np.zeros((6, 6))
    scale = np.r_[1.0, 1.0, 1.0, 1.0 / (2 * h)]  # z -> (1, a, b, D_1..D_6)
    for v in range(nv):
        S = M[v]
        n = S[0, 0]
        if n < 2:
            continue
        m = S[0] / n
        C = (S - n * np.outer(m, m)) * np.outer(scale, scale)  # centred sums of (., a, b, D)
        caa, cbb, cab = C[1, 1], C[2, 2], C[1, 2]
        if caa <= 0 or cbb <= 0:
            continue
        r = cab / math.sqrt(caa * cbb)
        cad, cbd, cdd = C[1, 3:], C[2, 3:], C[3:, 3:]
        dr = cad / math.sqrt(caa * cbb) - r * cbd / cbb
        jtj = (cdd - np.outer(cbd, cbd) / cbb) / cbb
        r_out[v] = r
        g -= w[v] * dr
        H += w[v] * max(r, 0.05) * jtj
    return r_out, g, 0.5 * (H + H.T)


@dataclass(frozen=True, eq=False)
class GaussNewtonStep:
    """One step's evaluation at ``x`` with half-steps ``h``: ``costs (13,)`` of the design poses
    (:func:`step_design`, row 0 = x), ``view_scores (13, n_views)``, the Gauss–Newton gradient
    ``g`` and Hessian ``H`` of the cost at ``x`` (x units) and the per-view correlations ``r``
    over the centre's domain."""

    x: np.ndarray
    h: np.ndarray
    costs: np.ndarray
    view_scores: np.ndarray
    g: np.ndarray
    H: np.ndarray
    r: np.ndarray

    @property
    def cost(self) -> float:
        return float(self.costs[0])


class _Pipeline:
    """Device buffers and recorded launches of the metric for one DRR buffer (``n_poses``
    poses × views items of a fixed size); a CUDA graph on the GPU."""

    def __init__(self, c: GaussNewtonCost, images: wp.array, n_poses: int) -> None:
        dev = c.device
        n, H, W = images.shape
        nv = c.n_views
        self.images = images
        self.stats = wp.zeros((n, 6), dtype=wp.float64, device=dev)
        self.extra = wp.zeros((n, 5), dtype=wp.float64, device=dev)
        self.count = wp.zeros(n, dtype=wp.float64, device=dev)
        self.out = wp.zeros(n_poses * (1 + nv), dtype=wp.float32, device=dev)
        self.host_out = wp.zeros(self.out.shape, dtype=wp.float32, device="cpu", pinned=dev.is_cuda)
        self.gn = wp.zeros((nv, 81), dtype=wp.float64, device=dev) if n_poses == _N else None
        self.host_gn = (wp.zeros((nv, 81), dtype=wp.float64, device="cpu", pinned=dev.is_cuda)
                        if self.gn is not None else None)
        self.zero = [self.stats, self.extra, self.count] + ([self.gn] if self.gn is not None else [])
        launches = []
        img = images
        if c._blur is not None:
            self.tmp = wp.zeros(images.shape, dtype=wp.float32, device=dev)
            self.blurred = wp.zeros(images.shape, dtype=wp.float32, device=dev)
            for src, dst, axis in ((images, self.tmp, 1), (self.tmp, self.blurred, 0)):
                launches.append(wp.launch(K.blur_kernel, dim=(n, H, W), device=dev, record_cmd=True,
                                          inputs=[src, dst, c._blur, c._ref_hw, nv, axis]))
            img = self.blurred
        geo = [nv, c.threshold, c.dilate, c.mode, c._ku, c._kv, c.chunk]
        n_chunks = math.ceil(H * W / c.chunk)
        launches.append(wp.launch_tiled(K.stats_kernel, dim=(n, n_chunks), block_dim=c.block_dim, device=dev,
                                        inputs=[img, c._fluoro, c._fgrad, c._fmask, c._ref_hw, c._fshift,
                                                nv, c.threshold, c.dilate, c.mode, c._ku, c._kv, c.chunk,
                                                self.stats], record_cmd=True))
        launches.append(wp.launch(K.finalize_kernel, dim=n_poses, device=dev, record_cmd=True,
                                  inputs=[_KIND[c.kind], nv, self.stats, self.extra, self.count, c._fshift,
                                          nv, 0.25, c._weights, self.out]))
        if self.gn is not None:
            launches.append(wp.launch_tiled(moments_kernel, dim=(nv, n_chunks), block_dim=c.block_dim,
                                            device=dev, record_cmd=True,
                                            inputs=[img, c._fluoro, c._fgrad, c._fmask, c._ref_hw, c._fshift,
                                                    *geo, self.gn]))
        self.launches = launches
        self.graph = None
        if dev.is_cuda:
            with wp.ScopedCapture(device=dev) as cap:
                self._enqueue()
            self.graph = cap.graph

    def _enqueue(self) -> None:
        for a in self.zero:
            a.zero_()
        for cmd in self.launches:
            cmd.launch()
        wp.copy(self.host_out, self.out)
        if self.gn is not None:
            wp.copy(self.host_gn, self.gn)

    def run(self) -> tuple[np.ndarray, np.ndarray | None]:
        if self.graph is not None:
            wp.capture_launch(self.graph)
            wp.synchronize_device(self.images.device)
        else:
            self._enqueue()
        return self.host_out.numpy().copy(), None if self.gn is None else self.host_gn.numpy().copy()


class GaussNewtonCost:
    """The registration cost of one bone at one pyramid scale with Gauss–Newton steps (module
    docs), reusable from frame to frame.

    Parameters
    ----------
    renderer : core.render.DRRRenderer
    bone : int
        Volume index in ``renderer``.
    views : sequence of int
    scale : float
        Full-resolution pixels per DRR pixel.
    term : MetricTerm
        A single ``gc`` or ``ncc`` term (options as :class:`core.similarity.BatchedMetric`'s
        domain and smoothing options; ``*_sigma_mm`` in mm at the bone).

    :meth:`set_frame` must be called before the first evaluation of each frame.
    """

    def __init__(self, renderer, *, bone: int, views: Sequence[int], scale: float = 1.0,
                 term: MetricTerm, block_dim: int = 128, chunk: int = 4096) -> None:
        if term.kind not in ENGINE_KINDS:
            raise ValueError(f"term: the Gauss-Newton engine handles {ENGINE_KINDS}, got {term.kind!r}")
        bad = set(term.options) - set(_OPTIONS)
        if bad:
            raise ValueError(f"term: options {sorted(bad)} are not supported by the Gauss-Newton engine")
        from ..imaging.edges import derivative_kernels

        self._renderer = weakref.ref(renderer)  # the cache of engine_cost is keyed by the renderer
        self.device = renderer.device
        self.bone = int(bone)
        self.views = tuple(int(v) for v in views)
        self.n_views = len(self.views)
        self.scale = float(scale)
        self.term = term
        self.kind = term.kind
        self.mode = _MODE[term.kind]
        self.threshold = float(term.options.get("threshold", 0.0))
        self.dilate = int(term.options.get("dilate", 0))
        ku, kv = derivative_kernels(term.options.get("operator", "sobel"))
        if ku.shape != (3, 3):
            raise ValueError("term: the Gauss-Newton engine needs a 3x3 gradient operator")
        self._ku_np, self._kv_np = ku, kv
        self._ku = wp.mat33f(*ku.astype(np.float32).ravel())
        self._kv = wp.mat33f(*kv.astype(np.float32).ravel())
        self.block_dim, self.chunk = int(block_dim), int(chunk)
        self.timer = CostTimer()
        self.profile = False  # synchronise after each render (time DRR and metric apart)
        self.batches: dict[int, int] = {}  # launches per batch size since the timer was reset
        self._cap: tuple[int, int] | None = None  # (H, W) DRR pixels
        self._blur = None
        self._blur_taps: np.ndarray | None = None
        self._pipes: dict[int, _Pipeline] = {}
        dev = self.device
        nv = self.n_views
        self._weights = wp.array(np.full(nv, 1.0, np.float32), dtype=wp.float32, device=dev)
        self._ref_hw = wp.zeros(nv, dtype=wp.vec2i, device=dev)
        self._fshift = wp.zeros(nv, dtype=wp.float32, device=dev)
        self._fmax = wp.zeros(nv, dtype=wp.float32, device=dev)
        self._fblur = None
        self._fblur_taps: np.ndarray | None = None
        self._taps_cache: dict = {}
        pinned = dev.is_cuda
        self._host_hw = wp.zeros(nv, dtype=wp.vec2i, device="cpu", pinned=pinned)
        # device preparation of the fluoroscope ROIs (set_frame): per-view geometry, sums, counts
        self._host_info = wp.zeros((nv, 8), dtype=wp.int32, device="cpu", pinned=pinned)
        self._info = wp.zeros((nv, 8), dtype=wp.int32, device=dev)
        self._msum = wp.zeros((nv, 2), dtype=wp.float64, device=dev)
        self._count = wp.zeros(nv, dtype=wp.int32, device=dev)
        self._host_count = wp.zeros(nv, dtype=wp.int32, device="cpu", pinned=pinned)
        self._count_event = wp.Event(dev) if dev.is_cuda else None
        self._stage_src = None
        self._tables: dict = {}  # DRR item tables per (batch, bones) (_render)
        self._staged_last = None  # (the frame, its regions) now on the device
        self.device_frames = True  # full-resolution ROIs prepared on the device (set_frame)
        self.base = self.center = self.roi = None

    @property
    def renderer(self):
        r = self._renderer()
        if r is None:
            raise RuntimeError("renderer: the renderer of this cost no longer exists")
        return r

    # ------------------------------------------------------------------ per frame
    def set_frame(self, frame: FrameImages, *, base_pose, center, roi, others=None) -> None:
        """Take the fluoroscope ROIs ``roi (n_views, 4)`` of ``frame`` (the DRRs of ``others``
        subtracted, see :func:`core.tracking.cost.fluoro_rois`) and the parameterisation
        ``base_pose``, ``center`` for the next evaluations. The ROIs are smoothed and
        differentiated on the device; at full resolution (``scale`` 1, the ROIs inside the
        images) the line integrals and usable-pixel masks are computed there too, from the
        fluence uploaded as it is (:attr:`device_frames`). Raises
        :class:`~core.tracking.cost.OutsideViewError` like :class:`RegistrationCost`."""
        t0 = time.perf_counter()
        self.base = np.asarray(base_pose, dtype=float)
        self.center = np.asarray(center, dtype=float)
        self.roi = np.asarray(roi, dtype=np.int64).reshape(self.n_views, 4)
        px_mm = self.scale * mm_per_pixel(self.renderer, self.base, self.center, self.views)
        taps, ftaps = self._taps(px_mm)
        staged = self._staged_shapes(frame) if self.device_frames else None
        if staged is None:
            rois, masks = fluoro_rois(self.renderer, frame, views=self.views, roi=self.roi, scale=self.scale)
            shapes = [r.shape for r in rois]
        else:
            shapes = [(int(r[3]), int(r[2])) for r in self.roi]
        need = (max(sh[0] for sh in shapes), max(sh[1] for sh in shapes))
        same_taps = (taps is None and self._blur_taps is None) or (
            taps is not None and self._blur_taps is not None and len(taps) == len(self._blur_taps))
        # the buffers' size depends on this frame alone (32-pixel steps), so a frame is scored
        # alike whatever came before it (a resumed run repeats an uninterrupted one)
        new = tuple(int(math.ceil(n / 32.0) * 32) for n in need)
        if new != self._cap or not same_taps:
            self._allocate(new, taps)
        elif taps is not None and not np.array_equal(taps, self._blur_taps):
            self._blur.assign(taps)
        self._blur_taps = taps
        Hc, Wc = self._cap
        nv = self.n_views
        dev = self.device
        hw = self._host_hw.numpy()
        hw[:] = np.array(shapes, dtype=np.int32)
        wp.copy(self._ref_hw, self._host_hw)
        if staged is None:
            if self._host_raw_wp is None:
                pinned = dev.is_cuda
                self._host_raw_wp = wp.zeros((nv, Hc, Wc), dtype=wp.float32, device="cpu", pinned=pinned)
                self._host_mask_wp = wp.zeros((nv, Hc, Wc), dtype=wp.uint8, device="cpu", pinned=pinned)
            raw, fm = self._host_raw_wp.numpy(), self._host_mask_wp.numpy()
            shift = np.zeros(nv, np.float32)
            fmax = np.zeros(nv, np.float32)
            for i, (f, m) in enumerate(zip(rois, masks, strict=True)):
                h, w = f.shape
                raw[i, :h, :w] = f
                raw[i, h:] = 0.0
                raw[i, :h, w:] = 0.0
                fm[i, :h, :w] = m
                fm[i, h:] = 0
                fm[i, :h, w:] = 0
                if self.mode == 0:  # the intensities' mean (the Pearson scores do not depend on it)
                    shift[i] = float(f[m].mean()) if m.any() else 0.0
                fmax[i] = max(float(f.max()), -float(f.min()))
            wp.copy(self._raw, self._host_raw_wp)
            wp.copy(self._fmask, self._host_mask_wp)
            self._fshift.assign(shift)
            self._fmax.assign(fmax)
        else:
            self._stage(frame, staged)
        if others is not None and len(others[1]):  # subtracted on the device, at the fixed output size
            nb = len(others[1])
            images = self._render(np.asarray(others[0], dtype=float)[None], tuple(int(b) for b in others[1]))
            wp.launch(subtract_kernel, dim=(nv, Hc, Wc), inputs=[images, nb, self._raw], device=dev)
        if ftaps is not None:
            if self._fblur is None or len(self._fblur) != len(ftaps):
                self._fblur = wp.array(ftaps, dtype=wp.float32, device=dev)
                self._fblur_taps = ftaps
            elif not np.array_equal(ftaps, self._fblur_taps):
                self._fblur.assign(ftaps)
                self._fblur_taps = ftaps
            for src, dst, axis in ((self._raw, self._ftmp, 1), (self._ftmp, self._fluoro, 0)):
                wp.launch(K.blur_kernel, dim=(nv, Hc, Wc), device=dev,
                          inputs=[src, dst, self._fblur, self._ref_hw, nv, axis])
        else:
            wp.copy(self._fluoro, self._raw)
        wp.launch(fluoro_gradient_kernel, dim=(nv, Hc, Wc), device=dev,
                  inputs=[self._fluoro, self._ref_hw, self._fmax, self._ku, self._kv, self._fgrad])
        if staged is not None:  # the usable pixels counted on the device
            if self._count_event is not None:
                wp.synchronize_event(self._count_event)
            else:
                wp.synchronize_device(dev)
            for i, n in enumerate(self._host_count.numpy()):
                if n <= 0:
                    raise OutsideViewError(f"frame: no usable fluoroscope pixel in the search region of view "
                                           f"{self.views[i]}")
        self.timer.host += time.perf_counter() - t0

    def _taps(self, px_mm: float):
        """The DRR and fluoroscope blur taps at this pixel size (kept for the next frames)."""
        from ..similarity.batched import gaussian_weights

        opts = _in_pixels({k: v for k, v in self.term.options.items()
                           if k in ("fluoro_sigma", "drr_sigma", "fluoro_sigma_mm", "drr_sigma_mm")}, px_mm)
        key = (float(opts.get("fluoro_sigma", 0.0)), float(opts.get("drr_sigma", 0.0)))
        hit = self._taps_cache.get(key)
        if hit is None:
            f_sig, d_sig = key
            taps = gaussian_weights(d_sig) if d_sig > 0 else None
            ftaps = gaussian_weights(f_sig, truncate=4.0) if f_sig > 0 else None  # as the host preparation
            if len(self._taps_cache) >= 64:
                self._taps_cache.pop(next(iter(self._taps_cache)))
            hit = self._taps_cache[key] = (taps, ftaps)
        return hit

    def _staged_shapes(self, frame) -> list | None:
        """Per view ``(r0, r1, c0, c1, erode)``: the image rows and columns to upload for the device
        preparation of the ROIs (each grown by the mask's erosion), or None where the host
        prepares them (a pyramid level, an ROI reaching outside its image, not a
        :class:`~core.tracking.cost.FrameImages`). Raises OutsideViewError for an empty ROI."""
        if self.scale != 1.0 or not isinstance(frame, FrameImages):
            return None
        p = frame._erode if frame._valid is not None else 0
        out = []
        for i, v in enumerate(self.views):
            u0, v0, w, h = (int(a) for a in self.roi[i])
            if w <= 0 or h <= 0:
                raise OutsideViewError(f"roi: the search region of view {v} is empty (outside the image)")
            H, W = frame.shapes[v]
            if u0 < 0 or v0 < 0 or u0 + w > W or v0 + h > H:
                return None
            out.append((max(v0 - p, 0), min(v0 + h + p, H), max(u0 - p, 0), min(u0 + w + p, W), p))
        return out

    def _stage(self, frame: FrameImages, staged: list) -> None:
        """Upload each view's region of the fluence (and the frame's own masks) and prepare the
        line integrals, masks and their statistics on the device (:func:`fluoro_roi_kernel`)."""
        dev = self.device
        nv = self.n_views
        p = staged[0][4]
        Hc, Wc = self._cap
        need = (nv, Hc + 2 * p, Wc + 2 * p)
        given = any(frame._given[v] is not None for v in self.views)
        key = (tuple(staged), tuple(self.views))
        last = self._staged_last
        upload = not (last is not None and last[0]() is frame and last[1] == key)  # else on the device
        if self._stage_src is None or any(a < b for a, b in zip(self._stage_src.shape, need, strict=True)):
            # grown only, in 64-pixel steps: pinned host memory is slow to allocate, and the kernel
            # reads each view's (hs, ws) corner alone
            need = (nv, *(int(math.ceil(n / 64.0) * 64) for n in need[1:]))
            if self._stage_src is not None:
                need = (nv, *(max(a, b) for a, b in zip(self._stage_src.shape[1:], need[1:], strict=True)))
            upload = True
            pinned = dev.is_cuda
            self._host_stage_wp = wp.zeros(need, dtype=wp.float32, device="cpu", pinned=pinned)
            self._host_stage = self._host_stage_wp.numpy()
            self._stage_src = wp.zeros(need, dtype=wp.float32, device=dev)
            self._host_gstage_wp = wp.zeros(need, dtype=wp.uint8, device="cpu", pinned=pinned)
            self._host_gstage = self._host_gstage_wp.numpy()
            self._stage_given = wp.zeros(need, dtype=wp.uint8, device=dev)
        info = self._host_info.numpy()
        info[:] = 0
        for i, v in enumerate(self.views):
            r0, r1, c0, c1, _ = staged[i]
            u0, v0, w, h = (int(a) for a in self.roi[i])
            g = frame._given[v]
            if upload:
                self._host_stage[i, :r1 - r0, :c1 - c0] = frame._fluence[v][r0:r1, c0:c1]
                if g is not None:
                    self._host_gstage[i, :r1 - r0, :c1 - c0] = g[r0:r1, c0:c1]
            info[i] = (h, w, v0 - r0, u0 - c0, r1 - r0, c1 - c0, int(g is not None), 0)
        if upload:  # each view's first hs rows (whole rows of the buffer: one contiguous block)
            _, Hs, Ws = self._stage_src.shape
            for i in range(nv):
                n = int(info[i, 4]) * Ws
                wp.copy(self._stage_src, self._host_stage_wp, i * Hs * Ws, i * Hs * Ws, n)
                if given:
                    wp.copy(self._stage_given, self._host_gstage_wp, i * Hs * Ws, i * Hs * Ws, n)
            self._staged_last = (weakref.ref(frame), key)
        wp.copy(self._info, self._host_info)
        self._fmax.zero_()
        self._msum.zero_()
        lo, hi = frame._valid if frame._valid is not None else (0.0, 0.0)
        chunk = 4096
        wp.launch(fluoro_roi_kernel, dim=(nv, math.ceil(Hc * Wc / chunk), _LANES), device=dev,
                  inputs=[self._stage_src, self._stage_given, self._info, float(lo), float(hi), int(p),
                          int(frame._valid is not None), chunk, self._raw, self._fmask, self._fmax,
                          self._msum])
        wp.launch(fluoro_shift_kernel, dim=nv, device=dev,
                  inputs=[self._msum, self.mode, self._fshift, self._count])
        wp.copy(self._host_count, self._count)
        if self._count_event is not None:
            wp.record_event(self._count_event)

    def _allocate(self, cap: tuple[int, int], taps) -> None:
        dev = self.device
        nv = self.n_views
        self._cap = cap
        self._host_raw_wp = self._host_mask_wp = None  # the host preparation's (allocated when used)
        self._raw = wp.zeros((nv, *cap), dtype=wp.float32, device=dev)
        self._ftmp = wp.zeros((nv, *cap), dtype=wp.float32, device=dev)
        self._fluoro = wp.zeros((nv, *cap), dtype=wp.float32, device=dev)
        self._fgrad = wp.zeros((nv, *cap), dtype=wp.vec2f, device=dev)
        self._fmask = wp.zeros((nv, *cap), dtype=wp.uint8, device=dev)
        self._blur = None if taps is None else wp.array(taps, dtype=wp.float32, device=dev)
        self._pipes = {}

    # ------------------------------------------------------------------ mapping
    def poses(self, X) -> np.ndarray:
        """``(B, 4, 4)`` poses of parameter rows ``X (B, 6)`` (mm, degrees): those of
        :func:`core.geometry.transforms.pose_from_params` (Rodrigues' formula here, without its
        checks: the optimiser's own parameters)."""
        X = np.atleast_2d(np.asarray(X, dtype=float))
        return _poses(X, self.base, self.center)

    # ------------------------------------------------------------------ evaluation
    def _render(self, P: np.ndarray, bones: tuple) -> wp.array:
        """The DRRs of ``bones`` at poses ``P (B, n_bones, 4, 4)`` in this cost's views and ROIs
        at its output size: the images of :meth:`core.render.DRRRenderer.render` (item
        ``(b · n_views + v) · n_bones + n``), its item table filled here without the checks of
        poses the engine made rigid itself (the inverse in closed form), one launch."""
        r = self.renderer
        B, nb = P.shape[:2]
        nv = self.n_views
        key = (B, bones)
        table = self._tables.get(key)
        if table is None:
            table = np.zeros((B, nv, nb, ITEM_COLS), dtype=np.float32)
            table[..., 0] = np.array(self.views, dtype=np.float32)[None, :, None]
            table[..., 1] = np.array(bones, dtype=np.float32)[None, None, :]
            if len(self._tables) >= 8:
                self._tables.pop(next(iter(self._tables)))
            self._tables[key] = table
        Rt = np.swapaxes(P[..., :3, :3], -1, -2)
        inv = np.zeros(P.shape)
        inv[..., :3, :3] = Rt
        inv[..., :3, 3] = -np.einsum("bnij,bnj->bni", Rt, P[..., :3, 3])
        inv[..., 3, 3] = 1.0
        Tidx = np.einsum("nij,bnjk->bnik", r._T_idx[list(bones)], inv)
        table[..., 2:5] = np.einsum("bnij,vj->bvni", Tidx[..., :3, :], r._src_h[list(self.views)])
        table[..., 5:14] = Tidx[:, None, :, :3, :3].reshape(B, 1, nb, 9)
        table[..., 14:18] = self.roi[None, :, None, :]
        Hc, Wc = self._cap
        H = max(Hc, math.ceil(int(self.roi[:, 3].max()) / self.scale))
        W = max(Wc, math.ceil(int(self.roi[:, 2].max()) / self.scale))
        return r._launch(table.reshape(B * nv * nb, ITEM_COLS), H, W, self.scale)

    def _evaluate(self, X: np.ndarray):
        if self._cap is None:
            raise RuntimeError("set_frame: no frame set")
        t0 = time.perf_counter()
        P = self.poses(X)
        t1 = time.perf_counter()
        images = self._render(P[:, None], (self.bone,))
        if self.profile:
            wp.synchronize_device(self.device)
        t2 = time.perf_counter()
        B = len(P)
        pipe = self._pipes.get(B)
        if pipe is None or pipe.images.ptr != images.ptr:
            pipe = self._pipes[B] = _Pipeline(self, images, B)
        out, gn = pipe.run()
        t3 = time.perf_counter()
        tm = self.timer
        tm.host += t1 - t0
        tm.render += t2 - t1
        tm.metric += t3 - t2
        tm.calls += 1
        tm.evaluations += B
        self.batches[B] = self.batches.get(B, 0) + 1
        scores = np.nan_to_num(out[:B].astype(np.float64), nan=-1.0)
        views = np.nan_to_num(out[B:].astype(np.float64).reshape(B, self.n_views), nan=-1.0)
        return 1.0 - scores, views, gn

    def __call__(self, X) -> np.ndarray:
        """``(B,)`` costs ``1 - score`` (B = 1 or 13 poses per launch are cached; any B works)."""
        return self._evaluate(np.atleast_2d(np.asarray(X, dtype=float)))[0]

    def score_and_views(self, x) -> tuple[float, np.ndarray]:
        """Similarity at ``x`` and per view, from one launch."""
        c, v, _ = self._evaluate(np.asarray(x, dtype=float)[None])
        return float(1.0 - c[0]), v[0]

    def step(self, x, h) -> GaussNewtonStep:
        """Evaluate the 13-pose design about ``x`` with half-steps ``h`` (6,): costs, gradient and
        Gauss–Newton Hessian (one DRR launch, one metric graph)."""
        x = np.asarray(x, dtype=float)
        h = np.asarray(h, dtype=float)
        c, v, gn = self._evaluate(step_design(x, h))
        t0 = time.perf_counter()
        r, g, H = moments_to_newton(gn.reshape(self.n_views, 9, 9), h)
        self.timer.host += time.perf_counter() - t0
        return GaussNewtonStep(x, h, c, v, g, H, r)


_TRACE: list | None = None


def gauss_newton_search(cost: GaussNewtonCost, x0, *, step, lower, upper, tol_x: float = 0.02,
                        tol_noise: float = 0.1, max_generations: int = 8, trust=None, lam: float = 1e-3,
                        cancel: Callable[[], bool] | None = None) -> OptimizeResult:
    """Levenberg–Marquardt search of ``cost`` from ``x0`` inside ``[lower, upper]`` (module docs).

    ``step``: the central-difference half-steps ``h`` (6,) (x units); ``trust`` (6,): the largest
    move per step (default ``8 h``); ``tol_x``: converged when every coordinate of the step from
    an accepted centre is below it, or ``tol_noise``: when the step's predicted decrease
    ``½ dᵀHd`` is below ``tol_noise`` × the cost's roughness (a move the data cannot confirm, as
    in :func:`~core.tracking.quadratic.quadratic_search`); ``max_generations``: launches of 13
    poses. The Gauss–Newton curvature is rescaled along the way by a secant estimate (the
    gradient's change along an accepted step of at most ``4 h`` over the model's, within
    [0.5, 1.5]); a rejected step raises λ to at least 0.5 (about half the Newton step). ``model`` of
    the result is a :class:`~core.tracking.quadratic.QuadraticFit` with the last accepted step's
    rescaled Hessian and the cost's roughness (6 residual degrees of freedom).
    """
    t_start = time.perf_counter()
    lo = np.asarray(lower, dtype=float)
    hi = np.asarray(upper, dtype=float)
    h = np.broadcast_to(np.asarray(step, dtype=float), (6,)).copy()
    tr = 8.0 * h if trust is None else np.broadcast_to(np.asarray(trust, dtype=float), (6,)).copy()
    if np.any(h <= 0) or np.any(tr <= 0):
        raise ValueError(f"step, trust: expected positive (mm, degrees) values, got {step!r}, {trust!r}")
    # keep the design inside the box
    x = np.clip(np.asarray(x0, dtype=float), lo + h, hi - h)
    best = None  # the accepted step
    evals = gens = 0
    reason = "max_generations"
    final_x = None
    lam = float(lam)
    noise = 0.0

    alpha = 1.0  # true curvature / Gauss-Newton curvature along the steps (secant estimate)

    def solve(s: GaussNewtonStep, lam_: float) -> np.ndarray:
        Hs = alpha * s.H
        D = np.diag(np.maximum(np.diag(Hs), 1e-12))
        try:
            d = np.linalg.solve(Hs + lam_ * D, -s.g)
        except np.linalg.LinAlgError:
            d = -s.g / np.diag(D)
        u = np.max(np.abs(d) / tr)
        return d / u if u > 1 else d

    while True:
        if cancel is not None and cancel():
            reason = "cancelled"
            break
        if gens >= max_generations:
            break
        s = cost.step(x, h)
        evals += _N
        gens += 1
        if _TRACE is not None:
            _TRACE.append(("eval", s.x.copy(), s.cost))
        if best is not None and not s.cost <= best.cost + max(noise, 1e-7):
            lam = max(10.0 * lam, 0.5)  # worse: a shorter, more gradient-like step from the accepted centre
            if lam > 1e4:
                reason = "stalled"
                break
            d = solve(best, lam)
            x = np.clip(best.x + d, lo + h, hi - h)
            continue
        if best is not None:  # secant: the gradient's change along the step against the model's
            dx = s.x - best.x
            den = float(dx @ best.H @ dx)
            num = float((s.g - best.g) @ dx)
            if den > 0 and num > 0 and np.all(np.abs(dx) <= 4 * h):  # a short step: near quadratic
                alpha = float(np.clip(num / den, 0.5, 1.5))
        best = s
        noise = _roughness(s, alpha)
        lam = max(lam / 10.0, 1e-7)
        d = solve(s, lam)
        if _TRACE is not None:
            _TRACE.append((s.x.copy(), s.cost, noise, d.copy(), alpha))
        if np.all(np.abs(d) < tol_x) or 0.5 * alpha * d @ s.H @ d < tol_noise * noise:
            reason = "tol_x"
            final_x = np.clip(s.x + d, lo, hi)
            break
        x = np.clip(s.x + d, lo + h, hi - h)
    if best is None:
        return OptimizeResult(np.asarray(x0, float), float("inf"), evals, gens, time.perf_counter() - t_start,
                              False, reason, "gauss_newton", None)
    if final_x is None:
        final_x = best.x
    fit = _fit(best, noise, alpha)
    fun = fit.predict(final_x - best.x)
    return OptimizeResult(final_x, float(fun), evals, gens, time.perf_counter() - t_start, reason == "tol_x",
                          reason, "gauss_newton", fit)


def _residuals(s: GaussNewtonStep, alpha: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares ``(c0, g)`` of the 13 costs with the Hessian fixed (``alpha H``), and the
    residuals. The design's columns (1, ±h_k at rows 2k+1, 2k+2) are orthogonal: the fit is
    the mean and the central differences, in closed form."""
    h = np.asarray(s.h, dtype=float)
    q = np.zeros(_N)
    q[1:] = np.repeat(0.5 * alpha * h * h * np.diag(s.H), 2)
    y = np.asarray(s.costs, dtype=float) - q
    c0 = y.mean()
    g = (y[1::2] - y[2::2]) / (2.0 * h)
    fitted = np.full(_N, c0)
    fitted[1::2] += h * g
    fitted[2::2] -= h * g
    return np.r_[c0, g], y - fitted


def _roughness(s: GaussNewtonStep, alpha: float = 1.0) -> float:
    """RMS residual (6 degrees of freedom) of the 13 costs about the quadratic with the
    Gauss–Newton Hessian: the cost's roughness at the scale of the step."""
    _, res = _residuals(s, alpha)
    return float(np.sqrt(res @ res / 6.0))


@dataclass(frozen=True, eq=False)
class GaussNewtonFit(QuadraticFit):
    """The :class:`~core.tracking.quadratic.QuadraticFit` of a search's last accepted step, with
    the per-view similarities at its centre (``view_scores (n_views,)``)."""

    view_scores: np.ndarray | None = None


def _fit(s: GaussNewtonStep, noise: float, alpha: float = 1.0) -> GaussNewtonFit:
    coef, _ = _residuals(s, alpha)
    return GaussNewtonFit(np.array(s.x), np.array(s.h), float(coef[0]), np.array(s.g), alpha * np.array(s.H),
                          float(noise), 6, np.array(s.costs), np.array(s.view_scores[0]))


_CACHE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def supports(terms: Sequence[MetricTerm]) -> bool:
    """Whether the engine can run a cost of these terms (one ``gc`` or ``ncc`` term with domain
    and smoothing options)."""
    terms = tuple(terms)
    return (len(terms) == 1 and terms[0].kind in ENGINE_KINDS
            and set(terms[0].options) <= set(_OPTIONS))


def engine_cost(renderer, *, bone: int, views: Sequence[int], scale: float,
                term: MetricTerm) -> GaussNewtonCost:
    """The :class:`GaussNewtonCost` of ``renderer`` for this bone, views, scale and term, kept for
    the renderer's lifetime (its buffers and graphs serve every later frame)."""
    per = _CACHE.setdefault(renderer, {})
    key = (int(bone), tuple(views), float(scale), term.kind, tuple(sorted(term.options.items())))
    c = per.get(key)
    if c is None:
        c = per[key] = GaussNewtonCost(renderer, bone=bone, views=views, scale=scale, term=term)
    return c
