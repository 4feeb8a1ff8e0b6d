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
rim), the band uploaded from a pinned buffer without a wait. The round field does not move between
frames: each engine keeps a :class:`RimCache` (:func:`rim_cache`) — per view the whole image's
black pixels and band, built at its first frame —, compares a frame's black pixels over each
region grown by the band with the kept ones and recomputes the band only around those that
differ (a few noisy pixels at the rim's edge cross the black threshold from frame to frame: 0-4
per view and frame of the acceptance trial's 1024² views), the same band to the bit. On this
2-core CPU machine (shared, loaded; the trial's frames 0-5 at 1024², 1 mm voxels, the band 24 px)
the tibia's two 400 × 480 regions at the rim 1.2 ms afresh (2.7 ms in an earlier measurement) →
0.5 ms from the cache (95 of 120 regions unchanged, 25 updated), the calcaneus's two 480 × 400
regions below the heel 1.4 → 0.9 ms (60 / 60); the first frame builds the whole image's band (two
1024² distance transforms, 30 ms).

Measured
--------
From the true poses (:mod:`core.studies.tracking.rim_band`, this 2-core CPU machine, 512², 1 mm
voxels, 5 noisy frames 0-80, the stage at 4 px — the trial's 8 px —, ``rim_sigmas=3``;
``resources/benchmarks/tracking_rim_band_cpu.json``; × the bound mm/°): the tibia 1.96/1.28 →
1.67/1.21, its sandwich σ 13.3/7.5 → 2.8/1.8× the bound; the calcaneus's region reaches the rim
too (below the heel): 1.09/0.80 → 1.08/0.79, σ 10.8/10.5 → 1.9/1.8×; the talus's region has no
black pixel near: the same to the bit.

Tracked (:mod:`core.studies.tracking.tissue_tibia`'s ``_rim`` runs, ``rim_sigmas=3``, the acceptance
trial at 1024², 100 frames, grid correction, the 2 mm tissue for every bone; × the bound mm/°,
frames over 4× the bound, all silent, in brackets where any), after :data:`BLACK_FRACTION`'s fix,
one NVIDIA H100 (``resources/benchmarks/tracking_rim_band_fixed_h100.json``):

* the stage at 8 px, three bones jointly: tibia 1.54/1.36 (1) → 1.41/1.34, talus 1.15/1.19 →
  1.15/1.19, calcaneus 1.12/1.30 → 1.11/1.31; the tibia alone 1.70/1.62 (3) → 1.45/1.68 (1).
* the tibia's stage at 4 px (the stage's default high-pass): jointly tibia 1.54/1.41 → 1.53/1.40,
  talus and calcaneus within 0.01; alone 1.47/1.53 → 1.47/1.50; no frame over 4× either way.
* 2σ coverage, axes (frames with all six): the tibia jointly 100 → 92 % (62 %) at 8 px, 100 →
  89 % (49 %) at 4 px; alone 100 → 98 % (89 %) and 91 % (59 %); the calcaneus 100 → 91 % (58 %);
  the talus 96 % either way. The band leaves the tibia's errors at 4 px as they were (per-axis
  spread over the frames within 0.0004 mm / 0.002°) and narrows its σ: the black field's
  high-passed step in the residual had widened the sandwich σ (from the true poses 13.3/7.5 →
  2.8/1.8× the bound, above), and that width had covered the bias of the tibia and the calcaneus
  (the grid correction's leftover distortion, :mod:`core.studies.tracking.tissue_tibia`), which σ
  does not model.
* the stage per bone-frame jointly 20.5 → 20.7 ms at 8 px (set-up 4.6 → 5.9 ms), 18.3 → 18.7 ms
  with the tibia at 4 px; alone 33.8 → 31.5 and 26.2 → 25.8 ms (no cost measurable); of the
  timed runs' regions 505 of 600 jointly and 146 of 200 alone took their band from the
  :class:`RimCache` unchanged, the rest after a local update.

The first run (one NVIDIA H200, ``resources/benchmarks/tracking_rim_band_h200.json``) had also
banded 24 px around the dense overlap of the talus, calcaneus and tibia just below the valid range
inside view 1's field: the talus 1.15/1.19 → 1.21/1.21 there, the same now.

So the band stays opt-in (``FinalModel(rim_sigmas=3.0)``, or for one bone ``bones={tibia:
BoneStage(rim_sigmas=3.0)}``): at the stage's default 4 px it changes no ratio by more than 0.03
and takes the tibia's 2σ coverage to 89 % of its axes and 49 % of its frames (issue 20 asks 90 %
of frames within 2σ); at 8 px it takes the tibia's translation down by 8-15 % and its silent
frames from 1 to 0 jointly, 3 to 1 alone, but the tibia alone's rotation up (1.62 → 1.68; 1.66 in
the first run) and the calcaneus's by 1 %. Where the tibia's stage runs at 8 px, the band for that
bone alone buys its translation and silent frames for some of its rotation and coverage.
"""

from __future__ import annotations

import math
import weakref

import numpy as np
import warp as wp

from .cost import FrameImages

__all__ = ["RimCache", "apply_rim", "rim_cache", "rim_keep"]


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


def _black(frame: FrameImages, view: int, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
    """The frame's black pixels of ``view`` over rows ``r0:r1`` and columns ``c0:c1`` (relative
    fluence at or below :data:`BLACK_FRACTION` of the valid range's low end, :data:`DARK` without
    one; outside the intensifier's round field, the collimator)."""
    return frame._fluence[view][r0:r1, c0:c1] <= _threshold(frame)


def _threshold(frame: FrameImages) -> float:
    return BLACK_FRACTION * (frame._valid[0] if frame._valid is not None else DARK)


def _dark(frame: FrameImages, view: int, r0: int, r1: int, c0: int, c1: int) -> np.ndarray | None:
    """:func:`_black`, or None where there are none."""
    dark = _black(frame, view, r0, r1, c0, c1)
    return dark if dark.any() else None


def _band(dark: np.ndarray, radius_px: float) -> np.ndarray:
    """True where a pixel of ``dark``'s window lies farther than ``radius_px`` from its every black
    pixel (OpenCV's 5×5 Euclidean distance transform: fixed-point path sums, so a pixel's distance
    up to ``radius_px`` is the same in any window that holds it and its black pixels that near)."""
    import cv2

    return cv2.distanceTransform((~dark).view(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_5) > radius_px


class _Field:
    """One view's black pixels over the whole image and the band of them (``keep``: True farther
    than the radius from every black pixel), kept equal to each other as the black pixels change."""

    def __init__(self, dark: np.ndarray, radius_px: float) -> None:
        self.dark, self.radius = dark, float(radius_px)
        self.r = math.ceil(radius_px)
        self.keep = _band(dark, self.radius)

    def update(self, dark: np.ndarray, R0: int, C0: int) -> bool:
        """The window at ``(R0, C0)`` of the image has the black pixels ``dark``: where they differ
        from the kept ones, those and the band within the radius of each changed pixel recomputed
        (from the black pixels within twice the radius); True where any differed."""
        h, w = dark.shape
        old = self.dark[R0:R0 + h, C0:C0 + w]
        diff = dark != old
        if not diff.any():
            return False
        old[...] = dark
        idx = np.flatnonzero(diff)
        H, W = self.dark.shape
        r = self.r
        for y0, y1, x0, x1 in _boxes(idx // w + R0, idx % w + C0, r):
            a0, a1, b0, b1 = max(y0 - r, 0), min(y1 + r, H), max(x0 - r, 0), min(x1 + r, W)  # band moved
            A0, A1, B0, B1 = max(a0 - r, 0), min(a1 + r, H), max(b0 - r, 0), min(b1 + r, W)  # its black
            k = _band(self.dark[A0:A1, B0:B1], self.radius)
            self.keep[a0:a1, b0:b1] = k[a0 - A0:a1 - A0, b0 - B0:b1 - B0]
        return True


#: changed black pixels grouped into boxes up to this many (else one box around all)
_SPOTS = 64


def _boxes(ys: np.ndarray, xs: np.ndarray, r: int) -> list[tuple[int, int, int, int]]:
    """Boxes ``(y0, y1, x0, x1)`` (ends exclusive) around the pixels ``ys, xs``: a pixel within
    ``2 r`` of a box joins it (their recomputed windows would overlap), boxes that come that near
    each other merge; one box around all beyond :data:`_SPOTS` pixels."""
    if len(ys) > _SPOTS:
        return [(int(ys.min()), int(ys.max()) + 1, int(xs.min()), int(xs.max()) + 1)]
    out: list[list[int]] = []
    d = 2 * r
    for y, x in zip(ys.tolist(), xs.tolist(), strict=True):
        out.append([y, y + 1, x, x + 1])
        merged = True
        while merged and len(out) > 1:  # (the newest box against the others, until none is near)
            merged = False
            b = out[-1]
            for j in range(len(out) - 1):
                o = out[j]
                if o[0] - d <= b[1] and b[0] <= o[1] + d and o[2] - d <= b[3] and b[2] <= o[3] + d:
                    out[-1] = [min(o[0], b[0]), max(o[1], b[1]), min(o[2], b[2]), max(o[3], b[3])]
                    del out[j]
                    merged = True
                    break
    return [tuple(b) for b in out]


class RimCache:
    """The band's distance transform kept between frames (per engine, :func:`apply_rim`): per view,
    image size, radius and black threshold the whole image's black pixels and band (the round
    field does not move between frames), built at the first frame; a later frame's black pixels
    are compared over each region grown by the band, and where some differ (a rim pixel's noise
    taking it across the threshold) the band is recomputed around those only. The band of a
    region is then the same, to the bit, as :func:`rim_keep` computes without the cache.
    ``hits`` / ``patched`` / ``built``: regions served unchanged, after a local update, by a new
    whole-image band. At most ``size`` fields (least recently used dropped)."""

    def __init__(self, size: int = 8) -> None:
        self.size = int(size)
        self._fields: dict = {}
        self.hits = self.patched = self.built = 0

    def field(self, frame: FrameImages, view: int, radius_px: float) -> _Field:
        H, W = frame.shapes[view]
        key = (int(view), H, W, float(radius_px), _threshold(frame))
        f = self._fields.pop(key, None)
        if f is None:
            f = _Field(_black(frame, view, 0, H, 0, W), radius_px)
            self.built += 1
            while len(self._fields) >= self.size:
                self._fields.pop(next(iter(self._fields)))
        self._fields[key] = f  # (most recently used last)
        return f

    def stats(self) -> dict:
        return {"hits": self.hits, "patched": self.patched, "built": self.built}


def rim_keep(frame, views, roi, radius_px: float, cap: tuple[int, int],
             cache: RimCache | None = None) -> np.ndarray | None:
    """``(views, *cap)`` uint8: 1 where a pixel of view ``views[i]``'s region ``roi[i] = (u0, v0, w,
    h)`` (the padded layout of the engine, region at the top left) lies farther than ``radius_px``
    from every black pixel of ``frame`` (:func:`_dark`), 0 where it lies within; None where no
    region has such a pixel within ``radius_px`` (nothing to change), ``frame`` is not a
    :class:`~core.tracking.cost.FrameImages` or a region is not inside its image. ``cache``: a
    :class:`RimCache` the band is taken from and kept in (the same result)."""
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
        if cache is not None:
            fld = cache.built
            field = cache.field(frame, v, radius_px)
            if field.update(_black(frame, v, R0, R1, C0, C1), R0, C0):
                cache.patched += 1
            elif fld == cache.built:
                cache.hits += 1
            keep = field.keep[v0:v0 + h, u0:u0 + w]
        else:
            keep = _keep(frame, v, (u0, v0, w, h), (R0, R1, C0, C1), r, radius_px)
            if keep is None:
                continue
        if keep.all() or not keep.any():
            continue
        if out is None:
            out = np.ones((len(views), *cap), np.uint8)
        out[i, :h, :w] = keep
    return out


def _keep(frame, v: int, region, window, r: int, radius_px: float) -> np.ndarray | None:
    """One region's band without a cache: the distance over the black pixels' bounding box grown by
    the band (none beyond it) within the region's window grown by it; None where no black pixel."""
    (u0, v0, w, h), (R0, R1, C0, C1) = region, window
    dark = _dark(frame, v, R0, R1, C0, C1)
    if dark is None:
        return None
    rows, cols = np.flatnonzero(dark.any(axis=1)), np.flatnonzero(dark.any(axis=0))
    b0, b1 = max(rows[0] - r, 0), min(rows[-1] + r + 1, R1 - R0)
    a0, a1 = max(cols[0] - r, 0), min(cols[-1] + r + 1, C1 - C0)
    d = _band(dark[b0:b1, a0:a1], radius_px)
    keep = np.ones((h, w), bool)
    y0, x0 = v0 - R0, u0 - C0  # (the region in the window)
    sy0, sy1, sx0, sx1 = max(b0, y0), min(b1, y0 + h), max(a0, x0), min(a1, x0 + w)
    if sy0 < sy1 and sx0 < sx1:
        keep[sy0 - y0:sy1 - y0, sx0 - x0:sx1 - x0] = d[sy0 - b0:sy1 - b0, sx0 - a0:sx1 - a0]
    return keep


#: per engine its :class:`RimCache` (:func:`apply_rim`)
_CACHES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def rim_cache(eng) -> RimCache:
    """The :class:`RimCache` of engine ``eng`` (made at its first band)."""
    c = _CACHES.get(eng)
    if c is None:
        c = _CACHES[eng] = RimCache()
    return c


def apply_rim(eng, frame, radius_px: float) -> bool:
    """The weights of ``eng`` (a :class:`~core.tracking.engine_likelihood.LikelihoodEngine` after its
    :meth:`~core.tracking.engine_likelihood.LikelihoodEngine.set_frame` of ``frame``) 0 where
    :func:`rim_keep` of its regions is, in the expected counts its later weights start from (uploaded
    from a pinned buffer, no wait); True where any weight changed."""
    keep = rim_keep(frame, eng.views, eng.roi, radius_px, eng._cap, cache=rim_cache(eng))
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
    eng.count_weights()  # (χ²/N over the pixels still weighed)
    return True
