"""The likelihood final stage's band at the edge of the usable image (:attr:`core.tracking.final_stage.
FinalModel.rim_sigmas`).

Outside the intensifier's round field (and on saturated pixels, or where a given mask says so) a
frame's pixels are unusable (:func:`~core.tracking.cost.prepare_frame`): their weight is 0, but their
line integrals stay in the region, and the black field's ``-log(floor)`` (8.3 against the bones' and
tissue's 1-3) is a step that the stage's high-pass (a Gaussian of σ ``highpass_px``, truncated at
4 σ) spreads into the usable pixels over about 3 σ — hundreds of times a bone's own high-passed
signal (:mod:`core.studies.tracking.border_frames`). :func:`rim_keep` gives the region's pixels
farther than ``rim_sigmas · σ`` (Euclidean) from every unusable pixel of the frame, and
:func:`apply_rim` multiplies the stage's weights by it right after
:meth:`~core.tracking.engine_likelihood.LikelihoodEngine.set_frame` (the weights that
:meth:`~core.tracking.engine_likelihood.LikelihoodEngine.reset_weights` goes back to, so the robust
rounds and the support keep the band). A region that no unusable pixel comes near (the talus and
the calcaneus of the acceptance trial; the tibia reaches the rim) costs a comparison of its window
and nothing else; a view whose whole region would be in the band keeps its weights (its steps would
have nothing to go by). The distance is computed on the host (OpenCV's 5×5 Euclidean distance
transform, within 0.8 px of the exact one near a round field's rim, over the region grown by the
band), only where the window has an unusable pixel: on this 2-core CPU machine 1.3 ms for a
448 × 528 window (the exact transform 5.8 ms), 0.5 ms for two regions far from the rim.
"""

from __future__ import annotations

import math

import numpy as np
import warp as wp

from .cost import FrameImages
from .likelihood_kernels import _times_kernel

__all__ = ["apply_rim", "rim_keep"]


def _usable(frame: FrameImages, view: int, r0: int, r1: int, c0: int, c1: int) -> np.ndarray | None:
    """The frame's usable pixels of ``view`` over rows ``r0:r1`` and columns ``c0:c1`` before the
    erosion of :func:`~core.tracking.cost.prepare_frame` (its valid range and given mask), or None
    where every pixel is."""
    ok = None
    if frame._valid is not None:
        lo, hi = frame._valid
        sub = frame._fluence[view][r0:r1, c0:c1]
        ok = (sub > lo) & (sub < hi)
    g = frame._given[view]
    if g is not None:
        ok = g[r0:r1, c0:c1] if ok is None else ok & g[r0:r1, c0:c1]
    return None if ok is None or ok.all() else ok


def rim_keep(frame, views, roi, radius_px: float, cap: tuple[int, int]) -> np.ndarray | None:
    """``(views, *cap)`` float32: 1 where a pixel of view ``views[i]``'s region ``roi[i] = (u0, v0, w,
    h)`` (the padded layout of the engine, region at the top left) lies farther than ``radius_px``
    from every unusable pixel of ``frame``, 0 where it lies within; None where no region has such a
    pixel within ``radius_px`` (nothing to change), ``frame`` is not a
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
        ok = _usable(frame, v, R0, R1, C0, C1)
        if ok is None:
            continue
        d = cv2.distanceTransform(ok.view(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5)  # (outside: far)
        keep = d[v0 - R0:v0 - R0 + h, u0 - C0:u0 - C0 + w] > radius_px
        if keep.all() or not keep.any():
            continue
        if out is None:
            out = np.ones((len(views), *cap), np.float32)
        out[i, :h, :w] = keep
    return out


def apply_rim(eng, frame, radius_px: float) -> bool:
    """The weights of ``eng`` (a :class:`~core.tracking.engine_likelihood.LikelihoodEngine` after its
    :meth:`~core.tracking.engine_likelihood.LikelihoodEngine.set_frame` of ``frame``) times
    :func:`rim_keep` of its regions, the expected counts its later weights start from; True where
    any weight changed."""
    keep = rim_keep(frame, eng.views, eng.roi, radius_px, eng._cap)
    if keep is None:
        return False
    nv, (Hc, Wc) = eng.n_views, eng._cap
    f = eng._buffer("rim", (nv, Hc, Wc))
    f.assign(keep)
    for w in (eng._w, eng._w0) if eng._w0_set else (eng._w,):
        wp.launch(_times_kernel, dim=(nv, Hc, Wc), inputs=[w, f, w], device=eng.device)
    return True
