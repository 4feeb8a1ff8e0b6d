"""Similarity of a batch of DRRs with the fluoroscope ROIs, computed on the device (Warp).

The tracking hot path renders many candidate poses in one launch
(:meth:`core.render.DRRRenderer.render` → ``DRRBatch.images``, a device array ``(n_items, H, W)``
with items ordered (pose, view, bone)) and needs one number per pose. :class:`BatchedMetric`
holds one fluoroscope ROI per (view, bone) on the same device, compares every DRR item with its
ROI over Ω, reduces on the device and copies ``B + n_items`` floats to the host: one score per
pose (the weighted mean over its views and bones) and one per item.

Definitions are those of the numpy references (:mod:`core.similarity.intensity`,
``information``, ``gradient``; Ω and polarity: :mod:`core.similarity.domain`): ``ncc``, ``sid``,
``gc`` (of the gradient magnitudes, or with ``components=True`` of the gradient components),
``gd``, ``gi``, ``go``, ``mi``, ``nmi``. Agreement with the references (tested on the CPU
device, stated for any device): float32 pixel arithmetic with float64 accumulation, so NCC, SID,
GC, GD, GI, MI and NMI agree to ~1e-4 absolute; GO takes its two medians from 1024-bin
histograms (interpolated within the bin) instead of sorting, which moves a few pixels across the
threshold: ~1e-2 absolute.

Speed design: the fluoroscope ROIs, their gradients and masks are uploaded once; buffers are
allocated once per input array shape and reused (nothing allocates per call); pixel loops are
tiled block reductions (:mod:`core.similarity._kernels`); on CUDA the whole pipeline (zeroing,
2–4 kernels, finalisation, the copy to pinned host memory) is captured once in a CUDA graph and
replayed per call. The gradient of the DRR is computed on the fly (3 × 3 stencil, cached reads);
the fluoroscope's is precomputed.

Bad input: fluoroscope ROIs or masks of the wrong shape, non-finite fluoroscope pixels, an
operator without 3 × 3 kernels, or an input array on another device / of the wrong shape raise
``ValueError`` naming the argument. NaN DRR pixels count as 0 (outside Ω). Empty Ω and constant
images score 0.0, as in the references.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import warp as wp

from ..imaging.edges import derivative_kernels
from . import _kernels as K
from .domain import _nonneg_float, _nonneg_int
from .gradient import GO_RANDOM_WEIGHT, ZERO_GRADIENT, debiased_magnitude, noise_per_ref

__all__ = ["BATCHED_KINDS", "BatchedMetric", "BatchedScores"]

_KIND_CODES = {"ncc": K.K_NCC, "sid": K.K_SID, "gc": K.K_GC, "gd": K.K_GD, "gi": K.K_GI,
               "go": K.K_GO, "mi": K.K_MI, "nmi": K.K_NMI}
BATCHED_KINDS = tuple(_KIND_CODES)


@dataclass(frozen=True, eq=False)
class BatchedScores:
    """Scores of one batch: ``pose (B,)`` weighted means and ``item (B, n_views, n_bones)``."""

    pose: np.ndarray
    item: np.ndarray


def _as_refs(value, name: str, *, masks: bool = False) -> tuple[list[np.ndarray], int, int]:
    """Flatten per-view (or per-view, per-bone) 2-D arrays; returns (refs, n_views, n_bones)."""
    views = list(value)
    if not views:
        raise ValueError(f"{name}: expected one 2-D array per view (or a list per view of one per bone)")
    nested = [isinstance(v, (list, tuple)) for v in views]
    if any(nested) and not all(nested):
        raise ValueError(f"{name}: mix of arrays and per-bone lists")
    per_view = [list(v) for v in views] if all(nested) else [[v] for v in views]
    nb = len(per_view[0])
    if nb == 0 or any(len(v) != nb for v in per_view):
        raise ValueError(f"{name}: expected the same number of bones for every view")
    refs = []
    for vi, v in enumerate(per_view):
        for bi, a in enumerate(v):
            arr = np.asarray(a, dtype=bool if masks else np.float64)
            where = f"{name}[{vi}]" + (f"[{bi}]" if all(nested) else "")
            if arr.ndim != 2 or min(arr.shape) < 1:
                raise ValueError(f"{where}: expected a non-empty 2-D array, got shape {arr.shape}")
            if not masks and not np.all(np.isfinite(arr)):
                raise ValueError(f"{where}: contains NaN or infinite pixels (mask them with fluoro_masks)")
            refs.append(arr)
    return refs, len(per_view), nb


def _smooth(f: np.ndarray, sigma: float) -> np.ndarray:
    """The smoothing of :func:`_smooth_and_gradient` alone (float64; the noise correction's
    fluence, :func:`core.tracking.cost.noise_maps`)."""
    import cv2

    f = np.ascontiguousarray(f, dtype=np.float64)
    if sigma > 0:
        r = int(4.0 * sigma + 0.5)
        x = np.arange(-r, r + 1, dtype=np.float64)
        g = np.exp(-0.5 * (x / sigma) ** 2)
        g /= g.sum()
        f = cv2.sepFilter2D(f, cv2.CV_64F, g, g, borderType=cv2.BORDER_REPLICATE)
    return f


def _smooth_and_gradient(f: np.ndarray, sigma: float, ku: np.ndarray, kv: np.ndarray):
    """``(smoothed, E_u, E_v)`` (float64) of a fluoroscope ROI: the Gaussian of
    :func:`scipy.ndimage.gaussian_filter` (``mode="nearest"``, truncated at 4σ) and the 3 × 3
    correlation gradient of :func:`core.imaging.edges.gradient`, computed with OpenCV (the same
    kernels and replicated borders, several times faster; this runs for every search region)."""
    import cv2

    f = _smooth(f, sigma)
    gu = cv2.filter2D(f, cv2.CV_64F, np.asarray(ku, np.float64), borderType=cv2.BORDER_REPLICATE)
    gv = cv2.filter2D(f, cv2.CV_64F, np.asarray(kv, np.float64), borderType=cv2.BORDER_REPLICATE)
    return f, gu, gv


def gaussian_weights(sigma: float, truncate: float = 3.0) -> np.ndarray:
    """Normalised 1-D Gaussian taps of :class:`BatchedMetric`'s ``drr_sigma`` blur (radius
    ``int(truncate σ + 0.5)``, as :func:`scipy.ndimage.gaussian_filter1d` with that ``truncate``)."""
    rad = int(truncate * float(sigma) + 0.5)
    x = np.arange(-rad, rad + 1, dtype=float)
    w = np.exp(-0.5 * (x / float(sigma)) ** 2)
    return (w / w.sum()).astype(np.float32)


def _pad_stack(arrays: list[np.ndarray], shape: tuple[int, int], dtype) -> np.ndarray:
    out = np.zeros((len(arrays), *shape, *arrays[0].shape[2:]), dtype=dtype)
    for i, a in enumerate(arrays):
        out[i, : a.shape[0], : a.shape[1]] = a
    return out


class BatchedMetric:
    """One similarity metric of DRR batches against fixed fluoroscope ROIs, on a Warp device.

    Parameters
    ----------
    kind : str
        One of :data:`BATCHED_KINDS`.
    fluoro_rois : sequence
        One ``(h, w)`` ROI per view (single bone), or per view a sequence of one ROI per bone, in
        DRR polarity (:func:`core.similarity.line_integral_image`) and sampled at the DRR pixels
        (:func:`core.similarity.sample_roi`). DRR item ``k`` is compared with ROI ``k % (V·nb)``
        over its first ``h`` rows and ``w`` columns.
    device : str, optional
        Warp device (default: CUDA when present, else CPU); DRR arrays must live there.
    fluoro_masks : sequence, optional
        Boolean masks nested like ``fluoro_rois`` (True = usable pixel).
    threshold, dilate, fluoro_sigma :
        The domain options of :mod:`core.similarity.domain`.
    drr_sigma : float
        Gaussian blur (σ in DRR pixels, truncated at 3σ, replicated borders, NaN as 0) of every
        DRR on the device before the metric — with ``fluoro_sigma`` equal, both images are
        filtered alike, so smoothing against noise does not shift the optimum (one-sided
        smoothing does: a blurred fluoroscope matches a sharp DRR best elsewhere). Ω then comes
        from the blurred DRR.
    operator : str
        Gradient operator with 3 × 3 kernels (default ``"sobel"``; not ``"abdou"``).
    bins, binning :
        MI/NMI histogram (see :mod:`core.similarity.information`).
    n_lb_fraction : float
        GO's lower bound on |S| as a fraction of |Ω|.
    components : bool
        ``gc`` only: the mean of the correlations of the gradients' u and v components instead of
        the magnitudes' (:func:`core.similarity.gradient_correlation` ``components``; two
        statistics passes instead of one).
    noise_energy : sequence, optional
        ``gc`` of the magnitudes only: per fluoroscope ROI (nested like ``fluoro_rois``; arrays of
        its shape or numbers) the expected squared gradient magnitude of its noise after the
        ``fluoro_sigma`` smoothing (:func:`core.similarity.gradient_correlation`
        ``noise_energy``): the ROI's gradients are shortened to the debiased magnitude
        ``sqrt(max(|g|² - E, 0))`` on the host, the device metric is unchanged.
    weights : (V·nb,) array, optional
        Weights of the items of a pose in its score (default equal).
    block_dim, chunk : int
        CUDA threads per block (32–512) and pixels per block (a multiple of ``block_dim``) of the
        tiled reductions; the defaults 128 / 4096 were the fastest of a scan on an H100 (NCC,
        GC, MI; the spread was within 10 % except for chunks of 512 px, ~60 % slower).
    """

    def __init__(self, kind: str, fluoro_rois, *, device: str | None = None, fluoro_masks=None,
                 threshold: float = 0.0, dilate: int = 0, fluoro_sigma: float = 0.0,
                 drr_sigma: float = 0.0, operator: str = "sobel", bins: int = 32, binning: str = "linear",
                 n_lb_fraction: float = 0.25, weights=None, block_dim: int = 128,
                 chunk: int = 4096, components: bool = False, noise_energy=None) -> None:
        if kind not in _KIND_CODES:
            raise ValueError(f"kind: expected one of {BATCHED_KINDS}, got {kind!r}")
        if not isinstance(components, (bool, np.bool_)):
            raise ValueError(f"components: expected True or False, got {components!r}")
        if components and kind != "gc":
            raise ValueError(f"components: only the gc metric has a component form, not {kind!r}")
        if noise_energy is not None and (kind != "gc" or components):
            raise ValueError("noise_energy: only the gc metric of the gradient magnitudes takes it")
        self.kind = kind
        self.components = bool(components)
        refs, self.n_views, self.n_bones = _as_refs(fluoro_rois, "fluoro_rois")
        shapes = [r.shape for r in refs]
        noise = [None] * len(refs) if noise_energy is None else noise_per_ref(noise_energy, shapes)
        self.n_refs = len(refs)
        if fluoro_masks is None:
            masks = [np.ones(r.shape, bool) for r in refs]
        else:
            masks, nv, nb = _as_refs(fluoro_masks, "fluoro_masks", masks=True)
            if (nv, nb) != (self.n_views, self.n_bones) or any(
                    m.shape != r.shape for m, r in zip(masks, refs, strict=True)):
                raise ValueError("fluoro_masks: expected one mask of each fluoroscope ROI's shape")
        self.threshold = float(threshold)
        if not np.isfinite(self.threshold):
            raise ValueError(f"threshold: expected a finite number, got {threshold!r}")
        self.dilate = _nonneg_int(dilate, "dilate")
        sigma = _nonneg_float(fluoro_sigma, "fluoro_sigma")
        self.drr_sigma = _nonneg_float(drr_sigma, "drr_sigma")
        if binning not in ("linear", "nearest"):
            raise ValueError(f"binning: expected 'linear' or 'nearest', got {binning!r}")
        self.bins = _nonneg_int(bins, "bins")
        if not 2 <= self.bins <= K.MAX_BINS:
            raise ValueError(f"bins: the device MI takes 2 to {K.MAX_BINS} histogram bins, got {bins!r}")
        self.linear = int(binning == "linear")
        self.n_lb_fraction = float(n_lb_fraction)
        if not 0 <= self.n_lb_fraction <= 1:
            raise ValueError(f"n_lb_fraction: expected a fraction in [0, 1], got {n_lb_fraction!r}")
        w = np.ones(self.n_refs) if weights is None else np.asarray(weights, dtype=float)
        if w.shape != (self.n_refs,) or np.any(w < 0) or w.sum() <= 0 or not np.all(np.isfinite(w)):
            raise ValueError(f"weights: expected {self.n_refs} non-negative weights with a positive sum")
        try:
            ku, kv = derivative_kernels(operator)
        except ValueError as exc:
            raise ValueError(f"operator: {exc}") from exc
        if ku.shape != (3, 3):
            raise ValueError(f"operator: the device metrics need 3x3 kernels, {operator!r} has {ku.shape}")
        self.operator = operator
        self.block_dim = _nonneg_int(block_dim, "block_dim")
        self.chunk = _nonneg_int(chunk, "chunk")
        if not 32 <= self.block_dim <= 512 or self.chunk < 1 or self.chunk % self.block_dim:
            raise ValueError("block_dim, chunk: expected 32 <= block_dim <= 512 and a chunk of pixels "
                             "that is a positive multiple of block_dim")

        wp.init()
        from ..render import default_device

        self.device = wp.get_device(device or default_device())
        # host preparation, once: smoothing, shift, gradients (as the numpy references do)
        prepared, grads, shifts = [], [], []
        for f, m, e in zip(refs, masks, noise, strict=True):
            f, gu, gv = _smooth_and_gradient(f, sigma, ku, kv)
            if e is not None:  # debiased magnitudes: the same direction, the shorter length
                mag = np.hypot(gu, gv)
                k = np.divide(debiased_magnitude(gu, gv, e), mag, out=np.zeros_like(mag), where=mag > 0)
                gu, gv = gu * k, gv * k
            flat = np.hypot(gu, gv) <= ZERO_GRADIENT * max(1.0, float(np.abs(f).max()))
            grads.append(np.stack([np.where(flat, 0, gu), np.where(flat, 0, gv)], axis=-1))
            shifts.append(float(f[m].mean()) if m.any() else 0.0)
            prepared.append(f)
        self.roi_shapes = tuple(f.shape for f in prepared)
        hmax = max(s[0] for s in self.roi_shapes)
        wmax = max(s[1] for s in self.roi_shapes)
        dev = self.device
        self._fluoro = wp.array(_pad_stack(prepared, (hmax, wmax), np.float32), dtype=wp.float32, device=dev)
        self._fgrad = wp.array(_pad_stack(grads, (hmax, wmax), np.float32), dtype=wp.vec2f, device=dev)
        self._fmask = wp.array(_pad_stack([m.astype(np.uint8) for m in masks], (hmax, wmax), np.uint8),
                               dtype=wp.uint8, device=dev)
        self._ref_hw = wp.array(np.array(self.roi_shapes, dtype=np.int32), dtype=wp.vec2i, device=dev)
        self._fshift = wp.array(np.array(shifts, dtype=np.float32), dtype=wp.float32, device=dev)
        self._weights = wp.array(w.astype(np.float32), dtype=wp.float32, device=dev)
        self._ku = wp.mat33f(*ku.astype(np.float32).ravel())
        self._kv = wp.mat33f(*kv.astype(np.float32).ravel())
        self._blur = None
        if self.drr_sigma > 0:
            self._blur = wp.array(gaussian_weights(self.drr_sigma), dtype=wp.float32, device=dev)
        self._plans: dict[tuple, _Plan] = {}

    # ------------------------------------------------------------------ evaluation
    def _check(self, images) -> wp.array:
        from ..render import DRRBatch

        if isinstance(images, DRRBatch):
            if images.shape[1:] != (self.n_views, self.n_bones):
                raise ValueError(f"images: a batch of {images.shape[1:]} (views, bones) items, "
                                 f"expected ({self.n_views}, {self.n_bones})")
            images = images.images
        if not isinstance(images, wp.array) or images.ndim != 3 or images.dtype != wp.float32:
            raise ValueError("images: expected a DRRBatch or a float32 Warp array (n_items, H, W)")
        if images.device != self.device:
            raise ValueError(f"images: on device {images.device}, the metric's ROIs are on {self.device}")
        n, H, W = images.shape
        if n == 0 or n % self.n_refs:
            raise ValueError(f"images: {n} items is not a positive multiple of views x bones = {self.n_refs}")
        if H < max(s[0] for s in self.roi_shapes) or W < max(s[1] for s in self.roi_shapes):
            raise ValueError(f"images: items of {H}x{W} are smaller than the fluoroscope ROIs "
                             f"{self.roi_shapes}")
        if not images.is_contiguous:
            raise ValueError("images: expected a contiguous array")
        return images

    def evaluate(self, images) -> BatchedScores:
        """Scores of a batch: ``images`` is a :class:`~core.render.DRRBatch` or its ``.images``."""
        arr = self._check(images)
        key = (arr.ptr, arr.shape)
        plan = self._plans.get(key)
        if plan is None:
            if len(self._plans) >= 4:
                self._plans.pop(next(iter(self._plans)))
            plan = self._plans[key] = _Plan(self, arr)
        out = plan.run()
        B = arr.shape[0] // self.n_refs
        return BatchedScores(out[:B].astype(np.float64),
                             out[B:].reshape(B, self.n_views, self.n_bones).astype(np.float64))

    def __call__(self, images) -> np.ndarray:
        """``(B,)`` pose scores (see :meth:`evaluate`)."""
        return self.evaluate(images).pose


class RecordedWork:
    """Buffers to zero, recorded launches and device-to-host copies (``zero``, ``launches``,
    ``copies`` as ``(host, device)`` pairs), replayed as one CUDA graph on a CUDA device
    (:meth:`capture`, then :meth:`replay`); shared by the batched metric's plans and the
    tracking engine's pipelines."""

    zero: list
    launches: list
    copies: list
    graph = None

    def capture(self, device) -> None:
        self.graph = None
        if device.is_cuda:
            with wp.ScopedCapture(device=device) as cap:
                self._enqueue()
            self.graph = cap.graph

    def _enqueue(self) -> None:
        for a in self.zero:
            a.zero_()
        for cmd in self.launches:
            cmd.launch()
        for host, dev_arr in self.copies:
            wp.copy(host, dev_arr)

    def replay(self) -> None:
        """Enqueue the work: the graph where captured, the launches one by one otherwise."""
        if self.graph is not None:
            wp.capture_launch(self.graph)
        else:
            self._enqueue()


class _Plan(RecordedWork):
    """Buffers and recorded launches for one input array (pointer and shape)."""

    def __init__(self, m: BatchedMetric, images: wp.array) -> None:
        dev = m.device
        n, H, W = images.shape
        B = n // m.n_refs
        self.device = dev
        kind = m.kind
        self.stats = wp.zeros((n, 6), dtype=wp.float64, device=dev)
        self.extra = wp.zeros((n, 6), dtype=wp.float64, device=dev)
        self.count = wp.zeros(n, dtype=wp.float64, device=dev)
        self.out = wp.zeros(B * (1 + m.n_refs), dtype=wp.float32, device=dev)
        self.host = wp.zeros(self.out.shape, dtype=wp.float32, device="cpu", pinned=dev.is_cuda)
        n_chunks = math.ceil(H * W / m.chunk)
        common = [m._fmask, m._ref_hw]
        zero: list[wp.array] = [self.stats, self.extra, self.count]
        launches = []

        def tiled(kernel, inputs):
            launches.append(wp.launch_tiled(kernel, dim=(n, n_chunks), inputs=inputs, block_dim=m.block_dim,
                                            device=dev, record_cmd=True))

        def plain(kernel, dim, inputs):
            launches.append(wp.launch(kernel, dim=dim, inputs=inputs, device=dev, record_cmd=True))

        if m._blur is not None:  # blurred copies of the DRRs; the metric reads those
            self.tmp = wp.zeros(images.shape, dtype=wp.float32, device=dev)
            self.blurred = wp.zeros(images.shape, dtype=wp.float32, device=dev)
            plain(K.blur_kernel, (n, H, W), [images, self.tmp, m._blur, m._ref_hw, m.n_refs, 1])
            plain(K.blur_kernel, (n, H, W), [self.tmp, self.blurred, m._blur, m._ref_hw, m.n_refs, 0])
            images = self.blurred
        geo = [m.n_refs, m.threshold, m.dilate]
        code = _KIND_CODES[kind]
        if m.components:  # the u components' sums in stats, the v components' in extra
            code = K.K_GCC
            for mode, acc in ((2, self.stats), (3, self.extra)):
                tiled(K.stats_kernel, [images, m._fluoro, m._fgrad, *common, m._fshift, *geo, mode, m._ku,
                                       m._kv, m.chunk, acc])
        elif kind in ("ncc", "sid", "gc", "gd", "gi"):
            mode = 0 if kind in ("ncc", "sid") else 1
            tiled(K.stats_kernel, [images, m._fluoro, m._fgrad, *common, m._fshift, *geo, mode, m._ku, m._kv,
                                   m.chunk, self.stats])
            if kind == "gi":
                tiled(K.gi_kernel, [images, m._fgrad, *common, *geo, m._ku, m._kv, m.chunk, self.stats,
                                    self.extra])
        else:
            mode = 1 if kind == "go" else 0
            self.rng = wp.zeros((n, 4), dtype=wp.float32, device=dev)
            plain(K.init_range_kernel, n, [self.rng])
            tiled(K.range_kernel, [images, m._fluoro, m._fgrad, *common, m._fshift, *geo, mode, m._ku, m._kv,
                                   m.chunk, self.rng, self.count])
            if kind == "go":
                self.hist = wp.zeros(n * 2 * K.MEDIAN_BINS, dtype=wp.int32, device=dev)
                self.med = wp.zeros((n, 2), dtype=wp.float32, device=dev)
                zero.append(self.hist)
                tiled(K.magnitude_hist_kernel, [images, m._fgrad, *common, *geo, m._ku, m._kv, m.chunk,
                                                self.rng, self.hist])
                plain(K.median_kernel, (n, 2), [self.hist, self.rng, self.count, self.med])
                tiled(K.go_kernel, [images, m._fgrad, *common, *geo, m._ku, m._kv, m.chunk,
                                    float(GO_RANDOM_WEIGHT), self.med, self.extra])
            else:
                mb = K.MAX_BINS
                self.joint = wp.zeros(n * mb * mb, dtype=wp.float32, device=dev)
                self.selfd = wp.zeros(n * 2 * mb, dtype=wp.float32, device=dev)
                self.selff = wp.zeros(n * 2 * mb, dtype=wp.float32, device=dev)
                zero += [self.joint, self.selfd, self.selff]
                tiled(K.joint_hist_kernel, [images, m._fluoro, *common, m._fshift, *geo, m.bins, m.linear,
                                            m.chunk, self.rng, self.joint, self.selfd, self.selff])
                plain(K.entropy_kernel, n, [self.joint, self.selfd, self.selff, m.bins, self.count,
                                            self.extra])
        plain(K.finalize_kernel, B, [code, m.n_refs, self.stats, self.extra, self.count,
                                     m._fshift, m.n_refs, m.n_lb_fraction, m._weights, self.out])
        self.zero = zero
        self.launches = launches
        self.copies = [(self.host, self.out)]
        self.capture(dev)

    def run(self) -> np.ndarray:
        self.replay()
        if self.graph is not None:
            wp.synchronize_device(self.device)
        return self.host.numpy().copy()
