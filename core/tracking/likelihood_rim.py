"""The likelihood final stage's band at the edge of the usable image (:attr:`core.tracking.final_stage.
FinalModel.rim_sigmas`).

Outside the intensifier's round field (and on saturated pixels, or where a given mask says so) a
frame's pixels are unusable (:func:`~core.tracking.cost.prepare_frame`): their weight is 0, but their
line integrals stay in the region, and the black field's ``-log(floor)`` (8.3 against the bones' and
tissue's 1-3) is a step that the stage's high-pass (a Gaussian of σ ``highpass_px``, truncated at
4 σ) spreads into the usable pixels over about 3 σ — hundreds of times a bone's own high-passed
signal (:mod:`core.studies.tracking.border_frames`). :func:`rim_keep` gives the region's pixels
farther than ``rim_sigmas · σ`` (Euclidean) from every black pixel of the frame (a quarter of the
valid range's low end or less: outside the round field, the collimator; not the saturated ones,
whose line integral is the air's, nor dense overlaps of bones just below the range: no step), and
:func:`apply_rim` sets the stage's weights 0 elsewhere right after
:meth:`~core.tracking.engine_likelihood.LikelihoodEngine.set_frame` (in the weights that
:meth:`~core.tracking.engine_likelihood.LikelihoodEngine.reset_weights` goes back to, so the robust
rounds and the support keep the band). A region that no black pixel comes near costs a comparison
of its window and is left as it is, to the bit; a view whose whole region would be in the band
keeps its weights (its steps would have nothing to go by). The distance is computed on the host
(OpenCV's 5×5 Euclidean distance transform, within 0.8 px of the exact one near a round field's
rim) over the black pixels' bounding box grown by the band, the band uploaded from a pinned buffer
without a wait: 2.7 ms for two 400 × 480 regions at a 1024² rim on this 2-core CPU machine.

Measured
--------
From the true poses (:mod:`core.studies.tracking.rim_band`, this 2-core CPU machine, 512², 1 mm
voxels, 5 noisy frames 0-80, the stage at 4 px — the trial's 8 px —, ``rim_sigmas=3``;
``resources/benchmarks/tracking_rim_band_cpu.json``; × the bound mm/°): the tibia 1.96/1.28 →
1.67/1.21, its sandwich σ 13.3/7.5 → 2.8/1.8× the bound; the calcaneus's region reaches the rim
too (below the heel): 1.09/0.80 → 1.08/0.79, σ 10.8/10.5 → 1.9/1.8×; the talus's region has no
black pixel near: the same to the bit.

Tracked (:mod:`core.studies.tracking.tissue_tibia`'s ``_rim`` runs, one NVIDIA H200, the acceptance
trial at 1024², 100 frames, grid correction, the 2 mm tissue for every bone, 8 px;
``resources/benchmarks/tracking_rim_band_h200.json``), with a band that ALSO grew 24 px around
the dense overlap just below the valid range inside the field of view 1 (fixed since:
:data:`BLACK_FRACTION`; not re-measured on the GPU): three bones jointly tibia 1.54/1.36 →
1.43/1.34 (frames over 4× the bound, silent: 1 → 0), talus 1.15/1.19 → 1.21/1.21, calcaneus
1.12/1.30 → 1.15/1.34; the tibia alone 1.70/1.62 → 1.44/1.66 (3 silent → 1); with the tibia's
stage at 4 px no change (1.54/1.41 → 1.55/1.42; alone 1.47/1.53 → 1.46/1.53). The 2σ coverage
falls where the band takes the step out of the residual (tibia jointly 100 → 61 % of frames, 92 %
of its axes; calcaneus 100 → 59 %, 91 %): the step had widened the sandwich σ over the tibia's
bias. The stage 20.2 → 22.8 ms per bone-frame jointly (set-up 4.6 → 8.3 ms), the tibia alone
30.8 → 35.4 ms. Opt-in until measured again on the GPU (``FinalModel(rim_sigmas=3.0)``, or for
the tibia alone ``bones={tibia: BoneStage(rim_sigmas=3.0)}``).
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from .cost import FrameImages

__all__ = ["apply_rim", "rim_keep"]


#: the relative fluence at or below which an unusable pixel is black (its line integral near
#: ``-log(floor)``: the step the high-pass spreads) where the frame gives no valid range
DARK = 0.02
#: black: at or below this fraction of the valid range's low end (a step of 1.4 or more in the
#: line integral at the edge of the usable pixels). Not the dense overlaps of bones inside the
#: field: on the acceptance trial's view 1 (frame 30, 1024²) 1,850 pixels where the talus, the
#: calcaneus and the tibia overlap have a relative fluence of 0.017-0.020, just below the valid
#: range (their line integral a step of 0.1 or less from their usable neighbours')
BLACK_FRACTION = 0.25


@wp.kernel
def _keep_kernel(w: wp.array3d(dtype=wp.float32), keep: wp.array3d(dtype=wp.uint8)):
    """w = 0 where keep is 0. dim = items, H, W."""
    k, r, c = wp.tid()
    if keep[k, r, c] == wp.uint8(0):
        w[k, r, c] = 0.0


def _dark(frame: FrameImages, view: int, r0: int, r1: int, c0: int, c1: int) -> np.ndarray | None:
    """The frame's black pixels of ``view`` over rows ``r0:r1`` and columns ``c0:c1`` (relative
    fluence at or below :data:`BLACK_FRACTION` of the valid range's low end, :data:`DARK` without
    one; outside the intensifier's round field, the collimator), or None where there are none."""
    lo = frame._valid[0] if frame._valid is not None else DARK
    dark = frame._fluence[view][r0:r1, c0:c1] <= BLACK_FRACTION * lo
    return dark if dark.any() else None


def rim_keep(frame, views, roi, radius_px: float, cap: tuple[int, int]) -> np.ndarray | None:
    """``(views, *cap)`` uint8: 1 where a pixel of view ``views[i]``'s region ``roi[i] = (u0, v0, w,
    h)`` (the padded layout of the engine, region at the top left) lies farther than ``radius_px``
    from every black pixel of ``frame`` (:func:`_dark`), 0 where it lies within; None where no
    region has such a pixel within ``radius_px`` (nothing to change), ``frame`` is not a
    :class:`~core.tracking.cost.FrameImages` or a region is not inside its image."""
    import cv2

    if not isinstance(frame, FrameImages) or not radius_px > 0:
        return None
    r = math.ceil(radius_px)
    out = None
    for i, v in enumerate(views):
        u0, v0, w, h = (int(a) for a in roi[i])
        H, W = frame.shapes[v]
        if w <= 0 or h <= 0 or u0 < 0 or v0 < 0 or u0 + w > W or v0 + h > H:
            return None
        R0, R1, C0, C1 = max(v0 - r, 0), min(v0 + h + r, H), max(u0 - r, 0), min(u0 + w + r, W)
        dark = _dark(frame, v, R0, R1, C0, C1)
        if dark is None:
            continue
        # the distance over the black pixels' bounding box grown by the band (none beyond it)
        rows, cols = np.flatnonzero(dark.any(axis=1)), np.flatnonzero(dark.any(axis=0))
        b0, b1 = max(rows[0] - r, 0), min(rows[-1] + r + 1, R1 - R0)
        a0, a1 = max(cols[0] - r, 0), min(cols[-1] + r + 1, C1 - C0)
        d = cv2.distanceTransform((~dark[b0:b1, a0:a1]).view(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5)
        keep = np.ones((h, w), bool)
        y0, x0 = v0 - R0, u0 - C0  # (the region in the window)
        sy0, sy1, sx0, sx1 = max(b0, y0), min(b1, y0 + h), max(a0, x0), min(a1, x0 + w)
        if sy0 < sy1 and sx0 < sx1:
            keep[sy0 - y0:sy1 - y0, sx0 - x0:sx1 - x0] = d[sy0 - b0:sy1 - b0, sx0 - a0:sx1 - a0] > radius_px
        if keep.all() or not keep.any():
            continue
        if out is None:
            out = np.ones((len(views), *cap), np.uint8)
        out[i, :h, :w] = keep
    return out


def apply_rim(eng, frame, radius_px: float) -> bool:
    """The weights of ``eng`` (a :class:`~core.tracking.engine_likelihood.LikelihoodEngine` after its
    :meth:`~core.tracking.engine_likelihood.LikelihoodEngine.set_frame` of ``frame``) 0 where
    :func:`rim_keep` of its regions is, in the expected counts its later weights start from (uploaded
    from a pinned buffer, no wait); True where any weight changed."""
    keep = rim_keep(frame, eng.views, eng.roi, radius_px, eng._cap)
    if keep is None:
        return False
    nv, (Hc, Wc) = eng.n_views, eng._cap
    n = nv * Hc * Wc
    host = eng._pinned("rim", (math.ceil(n / 65536.0) * 65536,), wp.uint8)
    host.numpy()[:n] = keep.ravel()
    f = eng._buffer("rim", (nv, Hc, Wc), wp.uint8)
    wp.copy(f, host, 0, 0, n)
    eng._uploaded()  # (set_frame waits for this copy before writing the pinned buffers again)
    for w in (eng._w, eng._w0) if eng._w0_set else (eng._w,):
        wp.launch(_keep_kernel, dim=(nv, Hc, Wc), inputs=[w, f], device=eng.device)
    return True
