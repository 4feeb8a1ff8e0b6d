"""Kernels that make the likelihood final stage's steps cheaper (:mod:`core.tracking.engine_likelihood`,
its flags ``DIFF_IMAGES`` and ``BLOCK_BLUR``; :data:`core.tracking.likelihood_kernels.MEDIAN_BISECT`).

Where the stage's time went (:mod:`core.studies.tracking.stage_speed`, one NVIDIA H100, the
acceptance trial at 1024², 30 frames, three bones jointly, the default model with its robust round;
``resources/benchmarks/tracking_stage_speed_h100.json``): 15.8 ms per bone-frame at a 4 px
high-pass, 23.5 ms at 8 px (8.6-8.7 steps). The device's share (Warp's CUDA activity timing over 12
frames, per bone-frame, 4 / 8 px): 10.8 / 17.3 ms — the high-pass's blurs 3.86 / 6.81 ms (their taps
grow with σ, 33 / 65), the DRRs 3.32 / 3.41 (13 poses a step), the moments 1.32 / 1.37, the
sandwich's meat 0.73 / 2.70 and autocovariance 0.52 / 1.88 (its lag window is 2σ: the lags grow with
σ²), the robust median's keys 0.35 (an atomic a pixel), copies and memsets ~0.45. The rest of the wall
time the device waits for the host: the set-up (the regions cut on the host; 3.3 ms with a
synchronisation around it), the solves (0.16 ms a step), the launches.

* :func:`design_diff_kernel`: the high-pass is linear, so the moments need the low-pass of the
  design's centre and of its six central differences only — 7 images a view blurred instead of 13
  (``DIFF_IMAGES``, the default). Same call: 13.9 ms at 4 px and 18.6 ms at 8 px per bone-frame
  (device 8.9 / 14.4 ms; blurs 2.13 / 3.88 ms). The moments differ by float32 rounding (the
  differences' the more accurate: Rounding, below); through the tracking that moved poses by up to
  0.018 mm / 0.037° on those 30 frames (the refinements' uphill test tipped by it, since changed:
  Rounding), and the errors over the
  Cramér–Rao bound by at most 0.03 either way (tibia, talus, calcaneus mm/°, 4 px: 1.68/1.46,
  1.46/1.39, 1.38/1.30 before, 1.70/1.46, 1.45/1.38, 1.37/1.29 after; 8 px: 1.71/1.49, 1.35/1.45,
  1.31/1.19 before, 1.71/1.52, 1.35/1.44, 1.31/1.18 after; the same tibia frame over 4× its bound,
  unflagged, in both; 2σ coverage within 0.03).
* :func:`blur_block_kernel`: the separable blur with 8 outputs a thread along the blurred axis, each
  input read once for all of them (``BLOCK_BLUR``); every output the same sum in the same order.
* :func:`_median_keys_only_kernel` and :func:`_median_sorted_kernel`: the robust factors' median
  with each view's keys sorted on their own (a device-wide radix sort each, instead of one
  segmented sort, which gives each view's 10⁵ keys to one thread block) and its count of used
  pixels found in them by bisection instead of an atomic a pixel (``MEDIAN_BISECT``; the same
  sorted values, so the same median).

The last two keep every value (on this 2-core CPU machine's Warp device, to the bit: the stage's
poses and covariances on a 128² trial) and are on by default since measured on one NVIDIA H100
(the study's variants, same trial and call, two repeats alternated, median, 4 / 8 px;
``resources/benchmarks/tracking_stage_speed_fast_h100.json``): every flag off (``plain``) 15.7 / 21.2
ms per bone-frame; ``BLOCK_BLUR`` and ``MEDIAN_BISECT`` (``exact``) 12.5 / 17.5 ms; with
``DIFF_IMAGES`` too (``fast``, the default) 11.1 / 16.0 ms, where ``DIFF_IMAGES`` alone had measured
13.9 / 18.6 ms on another H100. The blurs took 3.96 → 2.83 ms and 6.66 → 4.71 ms a bone-frame of the
device's time (1.63 / 2.80 ms with the differences); the robust factors, timed serially, 2.37 → 0.84
ms (the keys' atomic kernel 0.35 ms, the rest the segmented sort, which Warp's timing does not see).
``exact`` against ``plain``: poses within 10⁻¹² mm and degrees, the confidences' σ within 4 · 10⁻¹⁴
relative (unlike on the CPU, not equal to the last bit; not traced); ``fast`` against ``plain``
moved poses by the very amounts ``DIFF_IMAGES`` alone had (0.018 mm / 0.031° at 4 px, 0.009 mm /
0.037° at 8 px) and the σ by up to 11 % / 8 % relative on the worst of the 90 bone-frames' six axes;
errors over the bound as above (why, and what changed since: Rounding).
The device now spends per bone-frame 8.1 / 12.8 ms (DRRs 3.3, blurs 1.6 / 2.8, moments 1.1, meat and
autocovariance 1.2 / 4.6 ms), the stage's wall 11.8 / 18.4 ms over those 8 frames.

Rounding: why ``DIFF_IMAGES`` moved the confidences' σ by up to 10 %
--------------------------------------------------------------------
Not through its own rounding. At one design the two paths agree to float32 rounding (Warp's CPU
device, the talus in 128² fluoroscope views, 1.5 mm voxels, 4 px): the sandwich's and the
independent-pixel σ within 6 · 10⁻⁶ relative, χ² equal to the bit (the centre's image is blurred
alike). The differences are the more accurate: against the same rendered images high-passed in
float64, their δ_k are within 3-5 · 10⁻⁸ of their RMS, the plain path's within 5 · 10⁻⁶-6 · 10⁻⁵ (two
float32 high-passes subtracted, each rounded on the scale of the image, not of the difference).

What moved σ was :meth:`~core.tracking.engine_likelihood.LikelihoodEngine.refine`'s uphill test
(χ² rose: the pose before kept). The stage starts at the tracker's optimum, and most of its steps
are shorter than the independent-pixel σ (their predicted decrease of χ², ``Jrᵀδ``, below χ²/N, N
the used pixels), where χ² cannot tell the poses apart: poses 10⁻⁵ mm and degrees apart (a true
change ~10⁻⁵ χ²/N) gave χ² differing by 0.03-0.09 χ²/N rms at 128², 0.08-0.2 at 256² (1 mm voxels)
and 0.12-0.2 at 512² (0.5 mm; at most 0.36) — the float32 images (rendered, blurred) more than the
table's float32 sums (summed in float64 on the host: 0.06 instead of 0.08-0.13 at 256²) — and
Gauss–Newton steps differing by 1-3 % of the independent σ. So rounding decided whether χ² "rose",
and that decided whether a whole step stood: on one 128² frame the robust refinement's first step
(0.017°) was kept by one path and rejected by the other. With the confidence the sandwich plus the
stage's move (``sandwich+move``), a pose change of a fraction of σ moves σ as much: 0.018 mm against
σ of a few hundredths of a mm at 1024².

Since then the uphill test is for steps the data resolve
(:data:`~core.tracking.engine_likelihood.UPHILL_RESOLVED`): a step whose predicted decrease is below
4 χ²/N (two independent-pixel σ) stands whatever χ² did, and a rise after it ends the refinement as
converged (that step's Gauss–Newton estimate taken, as for a step below ``tol``; the same number
of steps but for the paths that then differ). The largest difference from the plain path (pose
over σ / σ relative, over frames and axes; Warp's CPU device, the talus alone registered from the
truth with the stage's default model: 128² 1.5 mm voxels, frames 1-5, 2 and 4 px; 256² 1 mm and 512²
0.5 mm, frames 1-3, 4 px), every rise tested → now:

* ``DIFF_IMAGES``: 128² 4.0e-3 / 9.4e-4 → 1.1e-3 / 8.8e-4; 256² 7.2e-2 / 3.1e-2 → 1.2e-2 / 6.1e-3;
  512² 3.5e-2 / 2.3e-2 → 1.2e-2 / 8.5e-3;
* the plain path with its first refinement started 10⁻⁶ off (rounding's size): 128² 1.8e-2 /
  1.4e-3 → 1.4e-3 / 1.3e-3; 256² 1.6e-2 / 1.4e-2 → 1.8e-2 / 9.3e-3; 512² 3.8e-1 / 2.2e-1 → 2.0e-2 /
  1.4e-2;
* tibia, talus and calcaneus jointly (their stages side by side after a joint search from the
  truth, 256², 1 mm, frames 1-2, 4 px): ``DIFF_IMAGES`` 1.3e-3 / 8.5e-4 either way; started 10⁻⁶ off
  6.5e-3 / 2.9e-3 → 1.4e-3 / 1.0e-3 (10.3 steps a bone either way).

The errors against the truth stayed (RMS over both paths' frames, mm / °: 128² 2 px 0.0205 / 0.0798 →
0.0205 / 0.0799, 4 px 0.0255 / 0.0974 → 0.0255 / 0.0980; 256² 0.0202 / 0.0668 → 0.0202 / 0.0669).

So the differences now move the stage no more than any perturbation of rounding's size does. What
remains is the stage's own floor: the Gauss–Newton step as a function of the pose is noisy at the
images' rounding (it moved by 1-3 % of the independent σ for 10⁻⁵ moves at 256² and 512²; at 256² as
much with the table summed in float64 on the host), 10⁻³ σ at 128² and 1-2 · 10⁻² σ at 256²-512². It
is the DRR's: a 10⁻⁵ mm or degree move changed a 256² DRR (1 mm voxels) by 2-28× its linear change
(~10⁻⁶ rms where the gradient is, 100× float32's rounding of the values) or, for some translations,
not at all (the source's position in the volume's indices, ~1000 voxels away, the same float32
number) — the renderer's rays start at the source in float32 (its samples ``org + t · d`` at ~10³
from it: ~10⁻⁴ voxel of rounding), which blurs the pose by ~3 · 10⁻⁵ mm and ~2 · 10⁻⁴° there (each
ray's entry point in float64 would take most of that away; not tried). The steps per stage 6.7-6.9 →
6.9-7.0 (128²), 6.25 → 6.42 (256²), 7.17 → 7.33 (512²). At 1024² (one NVIDIA H100, the acceptance
trial, 30 frames, three bones jointly, 4 px, :mod:`core.studies.tracking.stage_speed` variants ``plain``,
``fast``, ``plain+jitter`` and, every rise tested as before, ``+strict``; the tracker carries each
frame's pose into the next; ``resources/benchmarks/tracking_stage_uphill_h100.json``), the worst pose
difference and σ relative over the 90 bone-frames' axes: ``fast`` against ``plain`` 0.014 mm / 0.025° /
7.6 %, ``plain+jitter`` against ``plain`` 0.011 mm / 0.031° / 8.5 % (the floor), the old rule's
``fast+strict`` against ``plain+strict`` 0.018 mm / 0.031° / 10.5 % (the earlier 10-11 %, reproduced).
So through the tracking the default kernels move the stage no more than a start 10⁻⁶ off does; the
floor of ~8 % in σ is the stage's sensitivity carried from frame to frame. Errors over the bound
(tibia, talus, calcaneus mm/°): ``plain`` 1.67/1.44, 1.47/1.39, 1.38/1.30; ``fast`` 1.67/1.43, 1.46/1.38,
1.38/1.31; 16.3 against 12.5 ms per bone-frame, 8.5 steps (one repeat).

What the stage would need to fit the speed goal (≤ 5 ms a frame for one bone, ≤ 20 ms for three jointly,
tracker included; the tracker alone took 4.3 ms and 13-17 ms on one H100,
``tracking_newton_h100_endcheck.json``): about 0.7 ms per bone-frame for one bone and 1-2 ms for three —
6-16× less than the 11.1 ms measured at 4 px. The device's floor of today's stage is ~0.8 ms a step
(13-pose DRRs 0.38, blurs 0.25, moments 0.13, differences 0.04 ms) plus per bone-frame the sandwich (1.2
ms at 4 px, 4.6 at 8 px), the robust factors (0.4 ms of Warp kernels and a sort not timed) and the
set-up; 8.3-8.7 steps. So it would need all of: one or two steps from the tracker's optimum instead of
two refinements (or its last design's images taken over: the tracker renders the same kind of 13-pose
design at its optimum), fewer poses a step (forward differences, 7 poses; or the DRR's pose derivatives
from one differentiable launch), a confidence that is not a full sandwich every frame (its lag window
grows as σ²: FFT-based autocovariance and meat would make it σ-independent, or computed every k-th
frame), the set-up on the device (``DEVICE_REGIONS``; 3.3 ms with a synchronisation around it) and a
step captured as one CUDA graph (the device waits for the host ~5 ms per bone-frame today) — or the
stage run only on the frames the tracker's checks single out.

Since then (:mod:`core.tracking.engine_likelihood`: Fewer steps): 3.2 steps instead of 8.5 (about 2.2
renders), the regions on the device, 4.99 ms per bone-frame at 4 px (8.55 at 8 px), the device's
share 4.19 ms: DRRs 1.20, the sandwich's meat 0.72 (0.36 with 512 pixels a block,
:data:`~core.tracking.likelihood_confidence.MEAT_CHUNK`, since the default) and autocovariance
0.51, blurs 0.62, moments 0.47 ms. Forward differences (7 poses a step) would save ~0.4 ms of DRRs
but bias the poses (~1 σ on a 256² CPU trial); a step captured as a CUDA graph, not tried.

Phase 2: a step as one CUDA graph (:mod:`core.tracking.likelihood_graph`,
:data:`~core.tracking.engine_likelihood.STEP_GRAPH`), the moments on and above the table's diagonal
(:func:`wls_moments_tri_kernel`), the autocovariance 9 lags of a row a thread (:func:`autocov_rows_kernel`)
and the meat over half the lags (:data:`~core.tracking.likelihood_confidence.MEAT_HALF`). One NVIDIA H100
(the acceptance trial at 1024², 30 frames, three bones jointly; ``stage_speed --variants prev,base,nograph``,
three repeats alternated; ``resources/benchmarks/tracking_stage_h2_h100.json``): 5.48 → 4.66 ms per
bone-frame at 4 px (the new kernels without the graphs 5.30), 7.99 → 6.01 ms at 8 px; the device's share
3.92 → 3.36 ms (4 px) and 6.64 → 4.93 ms (8 px); poses within 3 · 10⁻¹³ mm, σ within 7 · 10⁻⁸ relative, the
same steps, errors over the bound and flags. The graphs' device time is their kernels' (2.05 ms a
bone-frame: DRRs ~1.1, blurs ~0.5, moments ~0.26, differences ~0.1); they save host launches. What stands
between this and 2.5 ms (``tracking_stage_h2_host_h100.json``, a host profile): the set-up's copies of
the fluence regions into pinned memory and the region's projection (``search_roi``), each step's 6 × 6
solve's numpy calls (~0.2 ms), the robust factors' launches and sorts — the host's ~1.5 ms a bone-frame
beyond the device's — and on the device the DRRs and blurs, which scale with the region's area (the
bone's volume box projected, grown by 1 mm and 4 px: a box of the bone's outline would be smaller, not
tried: it changes the pixels and so the poses).

Phase 3 (``resources/benchmarks/tracking_stage_h3_h100.json``, one NVIDIA H100, the same trial): the
region's projection by the volume box's corners (:data:`core.tracking.roi.BOX_CORNERS`), the buffers and
step graphs kept per output size (:data:`core.tracking.likelihood_launches.BUFFERS_PER_SIZE`) and
:func:`~core.tracking.likelihood_solve.solve_moments`' index arrays made once: 5.17/4.74 → 4.05/4.35 ms per
bone-frame (set-up 2.01/1.81 → 1.37/1.48 ms), poses within 3 · 10⁻¹³ mm. The region of the bone's DRR
support instead of its box (:data:`core.tracking.final_stage.REGION_OUTLINE`, opt-in: grown by 8 σ it moves
poses by up to 0.0095 mm / 0.023°): 3.53/2.93 ms against 4.03/3.75, the device's time 3.46 → 2.74-2.80 ms.
"""

from __future__ import annotations

import warp as wp

from ..similarity import _kernels as K

__all__ = ["blur_block_dim", "blur_block_kernel", "design_diff_kernel"]


@wp.func
def _hp(img: wp.array3d(dtype=wp.float32), low: wp.array3d(dtype=wp.float32), hp: float, k: int, r: int,
        c: int) -> float:
    """The high-passed value of item k at (r, c): img - hp · low (hp 0: the image as it is)."""
    return K._val(img, k, r, c) - hp * low[k, r, c]


@wp.func
def _centre(drr: wp.array3d(dtype=wp.float32), low: wp.array3d(dtype=wp.float32), hp: float, v: int, r: int,
            c: int) -> float:
    """The high-passed DRR of view v at the design's centre (item v in either layout)."""
    return _hp(drr, low, hp, v, r, c)


@wp.func
def _delta(drr: wp.array3d(dtype=wp.float32), low: wp.array3d(dtype=wp.float32), hp: float, j: int,
           n_refs: int, v: int, r: int, c: int, diff: int) -> float:
    """The high-passed central difference δ_j of view v: of items 2j+1 and 2j+2 (the 13 poses'
    images, ``diff`` 0), or item j+1 itself (``diff`` 1: :func:`design_diff_kernel`'s layout)."""
    out = float(0.0)  # noqa: UP018
    if diff != 0:
        out = _hp(drr, low, hp, (j + 1) * n_refs + v, r, c)
    else:
        out = (_hp(drr, low, hp, (2 * j + 1) * n_refs + v, r, c)
               - _hp(drr, low, hp, (2 * j + 2) * n_refs + v, r, c))
    return out


BLUR_BLOCK = wp.constant(8)  # outputs a thread of blur_block_kernel computes along the blurred axis
vec8f = wp.types.vector(length=8, dtype=wp.float32)


@wp.kernel
def blur_block_kernel(src: wp.array3d(dtype=wp.float32), dst: wp.array3d(dtype=wp.float32),
                      weights: wp.array(dtype=wp.float32), ref_hw: wp.array(dtype=wp.vec2i), n_refs: int,
                      axis: int):
    """:func:`core.similarity._kernels.blur_kernel` (one pass of the separable blur within each
    item's (h, w) region, borders replicated, NaN read as 0, 0 outside) with :data:`BLUR_BLOCK`
    outputs a thread along ``axis``: each input read once for all of them instead of once a tap
    and output. Every output sums the same products in the same order (tap 0 first), so the
    values are those of ``blur_kernel``. dim = (items, ⌈H / BLUR_BLOCK⌉, W) for ``axis`` 0 (rows),
    (items, H, ⌈W / BLUR_BLOCK⌉) for ``axis`` 1 (columns)."""
    k, a, b = wp.tid()
    ref = k % n_refs
    h = ref_hw[ref][0]
    w = ref_hw[ref][1]
    r0 = a
    c0 = b
    n = w
    if axis == 0:
        r0 = a * BLUR_BLOCK
        n = h
    else:
        c0 = b * BLUR_BLOCK
    acc = vec8f()
    taps = weights.shape[0]
    rad = (taps - 1) // 2
    if r0 < h and c0 < w:
        p0 = c0
        if axis == 0:
            p0 = r0
        for t in range(taps + BLUR_BLOCK - 1):
            p = wp.clamp(p0 + t - rad, 0, n - 1)
            x = float(0.0)  # noqa: UP018
            if axis == 0:
                x = K._val(src, k, p, c0)
            else:
                x = K._val(src, k, r0, p)
            for m in range(BLUR_BLOCK):
                j = t - m
                if j >= 0 and j < taps:
                    acc[m] = acc[m] + weights[j] * x
    for m in range(BLUR_BLOCK):
        r = r0
        c = c0
        if axis == 0:
            r = r0 + m
        else:
            c = c0 + m
        if r < dst.shape[1] and c < dst.shape[2]:
            v = float(0.0)  # noqa: UP018
            if r < h and c < w:
                v = acc[m]
            dst[k, r, c] = v


def blur_block_dim(shape: tuple, axis: int) -> tuple:
    """The launch dimensions of :func:`blur_block_kernel` over arrays of ``shape`` (items, H, W)."""
    n, H, W = (int(x) for x in shape)
    B = int(BLUR_BLOCK)
    return (n, -(-H // B), W) if axis == 0 else (n, H, -(-W // B))


@wp.kernel
def design_diff_kernel(img: wp.array3d(dtype=wp.float32), n_refs: int, ref_hw: wp.array(dtype=wp.vec2i),
                       out: wp.array3d(dtype=wp.float32), forward: int):
    """The 13-pose design's images ``img`` (item ``b · n_refs + v``) as the centre and the six
    central differences (NaN read as 0): item v the centre's, item ``(j + 1) · n_refs + v`` the
    difference of poses 2j+1 and 2j+2; 0 outside view v's (h, w) region. The high-pass is linear,
    so the moments need only these seven images a view low-passed. ``forward`` 1: the 7-pose
    forward design (``x``, ``x + h_k e_k``; :data:`~core.tracking.engine_likelihood.FORWARD_DESIGN`),
    the differences twice those of poses j+1 and 0 (the central differences' scale).
    dim = (7 · n_refs, H, W)."""
    k, r, c = wp.tid()
    v = k % n_refs
    j = k // n_refs
    x = float(0.0)  # noqa: UP018
    if r < ref_hw[v][0] and c < ref_hw[v][1]:
        if j == 0:
            x = K._val(img, v, r, c)
        elif forward != 0:
            x = 2.0 * (K._val(img, j * n_refs + v, r, c) - K._val(img, v, r, c))
        else:
            x = K._val(img, (2 * j - 1) * n_refs + v, r, c) - K._val(img, 2 * j * n_refs + v, r, c)
    out[k, r, c] = x


@wp.kernel
def _median_keys_only_kernel(local: wp.array3d(dtype=wp.float32), stride: int,
                             keys: wp.array(dtype=wp.float32)):
    """The keys of :func:`~core.tracking.likelihood_kernels._median_keys_kernel` without the count
    (:func:`_median_sorted_kernel` finds it in the sorted keys: no atomic a pixel), view v's at
    ``v · stride`` (each view sorted on its own, with its scratch after it). dim = items, H, W."""
    v, r, c = wp.tid()
    x = local[v, r, c]
    i = v * stride + r * local.shape[2] + c
    if x >= 0.0:
        keys[i] = x
    else:
        keys[i] = wp.inf


@wp.func
def sorted_median(keys: wp.array(dtype=wp.float32), o: int, n: int, sg: float):
    """The median of the ``n`` sorted keys at ``o`` (each times ``sg``, ±1) before the first infinite
    one, found by bisection; 0 where there are none or the median is not finite and positive."""
    lo = int(0)  # noqa: UP018, RUF046 (a Warp variable, not a constant)
    hi = int(n)
    while lo < hi:
        mid = (lo + hi) // 2
        if sg * keys[o + mid] < wp.inf:
            lo = mid + 1
        else:
            hi = mid
    m = lo
    s = float(0.0)  # noqa: UP018
    if m > 0:
        x = (sg * keys[o + (m - 1) // 2] + sg * keys[o + m // 2]) * 0.5
        if wp.isfinite(x) and x > 0.0:
            s = x
    return s


@wp.kernel
def _median_sorted_kernel(keys: wp.array(dtype=wp.float32), n: int, stride: int,
                          scale: wp.array(dtype=wp.float32)):
    """:func:`~core.tracking.likelihood_kernels._median_kernel` with view v's count of used values
    found in its ``n`` sorted keys at ``v · stride`` (the keys before the first +inf, by bisection).
    dim = items."""
    v = wp.tid()
    scale[v] = sorted_median(keys, v * stride, n, 1.0)


AUTOCOV_GROUP = wp.constant(9)  # lags of one row of the window a thread of autocov_rows_kernel sums
vec9d = wp.types.vector(length=9, dtype=wp.float64)


@wp.kernel
def autocov_rows_kernel(e: wp.array3d(dtype=wp.float32), wgt: wp.array3d(dtype=wp.float32),
                        ref_hw: wp.array(dtype=wp.vec2i), lag: int, groups: int, chunk: int,
                        acc: wp.array3d(dtype=wp.float64)):
    """:func:`~core.tracking.likelihood_kernels.autocov_kernel`'s sums (``acc[v, l]`` += the products
    ``e_i e_{i+Δ_l}`` and the count of the pairs of usable pixels at lag ``Δ_l``, the first
    ``(2 lag + 1)² // 2 + 1`` lags) with :data:`AUTOCOV_GROUP` lags of one row of the window a
    thread: each pixel's value and weight read once for them, its neighbours along the row next to
    each other. The same pairs and products (float32, summed in float64), in another order.
    dim = (views, (lag + 1) · groups, chunks): row ``Δ_r = q // groups - lag`` (≤ 0), the lags
    ``Δ_c`` of group ``q % groups`` of that row (row 0: ``Δ_c`` ≤ 0)."""
    v, q, ch, lane = wp.tid()
    bd = wp.block_dim()
    h = ref_hw[v][0]
    w = ref_hw[v][1]
    n = 2 * lag + 1
    a = q // groups
    g0 = (q - a * groups) * AUTOCOV_GROUP
    dr = a - lag
    last = n  # (exclusive) the row's last lag: row 0 stops at Δ_c = 0
    if dr == 0:
        last = lag + 1
    W = e.shape[2]
    start = ch * chunk
    stop = wp.min(e.shape[1] * W, start + chunk)
    s = vec9d()
    m = vec9d()
    for p in range(start + lane, stop, bd):
        r = p // W
        c = p - r * W
        rr = r + dr
        if r < h and c < w and rr >= 0 and rr < h:
            if wgt[v, r, c] > 0.0:
                x = e[v, r, c]
                for k in range(AUTOCOV_GROUP):
                    b = g0 + k
                    cc = c + b - lag
                    if b < last and cc >= 0 and cc < w:
                        if wgt[v, rr, cc] > 0.0:
                            s[k] = s[k] + wp.float64(x * e[v, rr, cc])
                            m[k] = m[k] + wp.float64(1.0)
    ts = wp.tile_sum(wp.tile(s, preserve_type=True))
    tm = wp.tile_sum(wp.tile(m, preserve_type=True))
    if lane == 0:
        xs = ts[0]
        xm = tm[0]
        for k in range(AUTOCOV_GROUP):
            b = g0 + k
            if b < last:
                wp.atomic_add(acc, v, a * n + b, 0, xs[k])
                wp.atomic_add(acc, v, a * n + b, 1, xm[k])


def autocov_rows_dim(n_views: int, lag: int, n_chunks: int) -> tuple:
    """``(dim, groups)`` of :func:`autocov_rows_kernel` for a lag window of ``lag``."""
    groups = -(-(2 * int(lag) + 1) // int(AUTOCOV_GROUP))
    return (int(n_views), (int(lag) + 1) * groups, int(n_chunks)), groups


NTRI = 78  # the 12 × 12 table's entries on and above the diagonal
vec78f = wp.types.vector(length=78, dtype=wp.float32)
_vec12f = wp.types.vector(length=12, dtype=wp.float32)


@wp.func
def moments_z(drr: wp.array3d(dtype=wp.float32), low: wp.array3d(dtype=wp.float32), hp: float,
              y: wp.array3d(dtype=wp.float32), oth: wp.array3d(dtype=wp.float32), n_refs: int, v: int, r: int,
              c: int, su: float, sv: float, diff: int) -> _vec12f:
    """A moments kernel's ``z = (y, D, δ_1 … δ_6, 1, u, v, O)`` of view v at (r, c) (``u = c · su - 1``,
    ``v = r · sv - 1``; :func:`~core.tracking.likelihood_kernels.wls_moments_kernel` and
    :func:`wls_moments_tri_kernel` both)."""
    z = _vec12f()
    z[0] = y[v, r, c]
    z[1] = _centre(drr, low, hp, v, r, c)
    for j in range(6):
        z[2 + j] = _delta(drr, low, hp, j, n_refs, v, r, c, diff)
    z[8] = 1.0
    z[9] = float(c) * su - 1.0
    z[10] = float(r) * sv - 1.0
    z[11] = oth[v, r, c]
    return z


@wp.kernel
def wls_moments_tri_kernel(drr: wp.array3d(dtype=wp.float32), low: wp.array3d(dtype=wp.float32), hp: float,
                           y: wp.array3d(dtype=wp.float32), wgt: wp.array3d(dtype=wp.float32),
                           oth: wp.array3d(dtype=wp.float32), ref_hw: wp.array(dtype=wp.vec2i), n_refs: int,
                           chunk: int, acc: wp.array2d(dtype=wp.float64), diff: int):
    """:func:`~core.tracking.likelihood_kernels.wls_moments_kernel` with the table's entries on and
    above the diagonal only (78 of 144; each the same products summed in the same order): ``acc[v,
    i · 12 + j]`` for ``i <= j``, the others left as they were (0: the host mirrors them). Half the
    registers, the block's reduction and the atomics. dim = (views, chunks)."""
    v, ch, lane = wp.tid()
    bd = wp.block_dim()
    h = ref_hw[v][0]
    w = ref_hw[v][1]
    W = y.shape[2]
    start = ch * chunk
    stop = wp.min(y.shape[1] * W, start + chunk)
    su = 2.0 / float(wp.max(w - 1, 1))
    sv = 2.0 / float(wp.max(h - 1, 1))
    s = vec78f()
    for p in range(start + lane, stop, bd):
        r = p // W
        c = p - r * W
        if r < h and c < w:
            wt = wgt[v, r, c]
            if wt > 0.0:
                z = moments_z(drr, low, hp, y, oth, n_refs, v, r, c, su, sv, diff)
                for i in range(12):  # (constant ranges: unrolled, every index a constant)
                    for j in range(12):
                        if j >= i:
                            k = i * 12 - (i * (i - 1)) // 2 + j - i
                            s[k] = s[k] + wt * (z[i] * z[j])
    t = wp.tile_sum(wp.tile(s, preserve_type=True))
    if lane == 0:
        x = t[0]
        for i in range(12):
            for j in range(12):
                if j >= i:
                    wp.atomic_add(acc, v, i * 12 + j, wp.float64(x[i * 12 - (i * (i - 1)) // 2 + j - i]))
