"""The device preparation of the engine's fluoroscope regions (:mod:`core.tracking.engine`).

At a pyramid level the host prepares the regions (:func:`pyramid_rois`, OpenCV's Gaussian).
At full resolution :meth:`~core.tracking.engine.GaussNewtonCost.set_frame` uploads each view's
region of the fluence as it is (grown by the usable-pixel mask's erosion; :func:`staged_shapes`)
and :func:`stage` computes the line integrals, the eroded mask and their statistics on the
device (:func:`~core.tracking.engine_kernels.fluoro_roi_kernel`: the values of
:meth:`core.tracking.cost.FrameImages.region`). A region already on the device (the same frame
and regions: the next round of joint tracking, the restarts) is not uploaded again.
"""

from __future__ import annotations

import math
import os
import threading
import weakref

import numpy as np
import warp as wp

from .cost import FrameImages, OutsideViewError, padded_region
from .engine_buffers import copy_array
from .engine_kernels import _LANES, fluoro_roi_kernel, fluoro_shift_kernel, keep_kernel

__all__ = ["PYRAMID_AHEAD", "apply_rim_band", "host_stage", "pyramid_ahead", "pyramid_rois", "stage",
           "staged_shapes"]


def pyramid_rois(frame: FrameImages, views, roi, scale: float) -> tuple[list, list]:
    """The fluoroscope's search regions of ``views`` at pyramid ``scale`` > 1 and their
    usable-pixel masks, as :func:`core.tracking.cost.fluoro_rois` prepares them (without
    neighbours to subtract: the engine subtracts them on the device): each region low-passed by
    a Gaussian of σ = scale / 2 — OpenCV's (borders replicated, the kernel truncated at 4σ), the
    values of ``scipy.ndimage.gaussian_filter(mode="nearest")`` within float32 rounding (7e-7 on
    line integrals up to 3) in a fifth to a sixth of its time (about 1 ms per 400 × 500 region
    and pass on the H100 machine's host: a first frame's three pyramid preparations took 13 of
    its 65 ms) — then sampled at the DRR's rays. The regions are read in the calling thread, then
    low-passed and sampled side by side, a thread a view (the same arrays as one after another).
    Raises OutsideViewError like it."""
    from concurrent.futures import wait

    s = float(scale)
    roi = np.asarray(roi, dtype=np.int64).reshape(len(views), 4)
    got = _AHEAD.pop(threading.get_ident(), None)
    if got is not None:
        wait(got[2])  # (started with other inputs: finished before anything else is given to the pool)
        if (got[0][0]() is frame and got[0][1:] == (tuple(int(v) for v in views), roi.tobytes(), s)
                and all(f.exception() is None for f in got[2])):  # (else prepared here: raised in order)
            return _checked(got[1], [f.result() for f in got[2]])
    # the regions read in this thread, in order (the frame's region cache is not shared between threads)
    regions = [(int(v), *padded_region(frame, v, roi[i], s)) for i, v in enumerate(views)]
    if len(regions) < 2:
        out = [_pyramid_view(*a, s) for a in regions]
    else:
        pool = _view_pool()
        futs = [pool.submit(_pyramid_view, *a, s) for a in regions[1:]]
        try:
            first = _pyramid_view(*regions[0], s)
        finally:
            wait(futs)  # every thread done before anything is raised
        out = [first] + [f.result() for f in futs]
    return _checked(regions, out)


def _checked(regions: list, out: list) -> tuple[list, list]:
    """:func:`pyramid_rois`'s regions and masks from its views' ``out``; OutsideViewError where a view
    has no usable pixel."""
    for (v, *_), (_, mask) in zip(regions, out, strict=True):
        if not mask.any():
            raise OutsideViewError(f"frame: no usable fluoroscope pixel in the search region of view {v}")
    return [o[0] for o in out], [o[1] for o in out]


#: A pyramid level's regions prepared ahead (:func:`pyramid_ahead`): the global search
#: (:func:`core.tracking.register.register`, ``"global_newton"``) has the next level's regions low-passed
#: and sampled in the view threads while its CMA-ES stage runs, and that level's preparation
#: (:func:`pyramid_rois`, the same inputs) takes them: the same function on the same regions, the same
#: arrays. Off: each level prepares its own when it starts.
PYRAMID_AHEAD = True

_AHEAD: dict = {}  # registering thread -> ((weak reference to the frame, views, roi bytes, scale), regions,
# futures)


class _Uncached:
    """A frame's shapes and its regions read without its region cache (which is not shared between
    threads): :meth:`~core.tracking.cost.FrameImages.region`'s values, not kept."""

    def __init__(self, frame) -> None:
        self.shapes = frame.shapes
        self.region = frame._region


def _ahead_view(frame, v: int, row, s: float):
    """One view's :func:`_pyramid_view` of :func:`pyramid_ahead`, its padded region read here (a view
    thread; :func:`~core.tracking.cost.padded_region` of the frame's uncached regions)."""
    sub, m, r = padded_region(_Uncached(frame), v, row, s)
    return _pyramid_view(v, sub, m, r, s)


def pyramid_ahead(frame, views, roi, scale: float) -> None:
    """:func:`pyramid_rois` of these inputs started now in the view threads (:data:`PYRAMID_AHEAD`), the
    regions read there too; the calling thread's next :func:`pyramid_rois` takes the result where its
    inputs are the same (else it waits for it and prepares its own; also where a view raised, e.g. a
    region outside its view: its own preparation raises it). Nothing where the switch is off, the scale
    is not a pyramid level or the frame is not a :class:`~core.tracking.cost.FrameImages`."""
    s = float(scale)
    if not (PYRAMID_AHEAD and s > 1 and isinstance(frame, FrameImages)):
        return
    roi = np.asarray(roi, dtype=np.int64).reshape(len(views), 4)
    pool = _view_pool()
    futs = [pool.submit(_ahead_view, frame, int(v), roi[i], s) for i, v in enumerate(views)]
    regions = [(int(v),) for v in views]
    old = _AHEAD.pop(threading.get_ident(), None)
    if old is not None:
        from concurrent.futures import wait

        wait(old[2])
    key = (weakref.ref(frame), tuple(int(v) for v in views), roi.tobytes(), s)
    _AHEAD[threading.get_ident()] = (key, regions, futs)


_POOL = None


def _view_pool():
    """The threads :func:`pyramid_rois` prepares the views after the first in (made once a process:
    a forked child makes its own, :func:`_forget_pool`)."""
    global _POOL
    if _POOL is None:
        from concurrent.futures import ThreadPoolExecutor

        _POOL = ThreadPoolExecutor(3, thread_name_prefix="talus-pyramid")
    return _POOL


def _forget_pool() -> None:
    """In a forked child: the parent's pool, whose threads the child does not have (work handed to it
    would never run), forgotten."""
    global _POOL
    _POOL = None
    _AHEAD.clear()


if hasattr(os, "register_at_fork"):  # (Unix only: Windows has no fork)
    os.register_at_fork(after_in_child=_forget_pool)


def _pyramid_view(v: int, sub, m, r, s: float):
    """One view's low-passed, sampled region and usable-pixel mask of :func:`pyramid_rois` from its
    padded region (:func:`~core.tracking.cost.padded_region`; OpenCV releases the GIL)."""
    import cv2

    from ..similarity import sample_roi

    sig = 0.5 * s
    k = 2 * int(4.0 * sig + 0.5) + 1
    sub = cv2.GaussianBlur(sub, (k, k), sig, sigmaY=sig, borderType=cv2.BORDER_REPLICATE)
    img = sample_roi(sub, r, scale=s)
    mm = None if m is None else sample_roi(m.astype(np.float32), r, scale=s) > 0.999
    return img, (np.ones(img.shape, bool) if mm is None else np.ascontiguousarray(mm))


def staged_shapes(self, frame) -> list | None:
    """Per view of the :class:`~core.tracking.engine.GaussNewtonCost` ``self``:
    ``(r0, r1, c0, c1, erode)``, the image rows and columns to upload for the device preparation
    of the ROIs (each grown by the mask's erosion), or None where the host prepares them (a
    pyramid level, an ROI reaching outside its image, not a
    :class:`~core.tracking.cost.FrameImages`). Raises OutsideViewError for an empty ROI."""
    if self.scale != 1.0 or not isinstance(frame, FrameImages):
        return None
    p = frame._erode if frame._valid is not None else 0
    out = []
    shapes = frame.shapes
    for v, (u0, v0, w, h) in zip(self.views, self.roi.tolist(), strict=True):  # (Python integers)
        if w <= 0 or h <= 0:
            raise OutsideViewError(f"roi: the search region of view {v} is empty (outside the image)")
        H, W = shapes[v]
        if u0 < 0 or v0 < 0 or u0 + w > W or v0 + h > H:
            return None
        out.append((max(v0 - p, 0), min(v0 + h + p, H), max(u0 - p, 0), min(u0 + w + p, W), p))
    return out

def host_stage(self, rois: list, masks: list) -> None:
    """For the :class:`~core.tracking.engine.GaussNewtonCost` ``self``: upload the regions
    ``rois`` and usable-pixel ``masks`` prepared on the host (a pyramid level, a region reaching
    outside its image) into its buffers, with their statistics."""
    nv = self.n_views
    Hc, Wc = self._cap
    if self._host_raw_wp is None:
        pinned = self.device.is_cuda
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
    wp.copy(self._raw0, self._host_raw_wp)
    wp.copy(self._fmask, self._host_mask_wp)
    self._put("fshift", self._fshift, shift)
    self._put("fmax", self._fmax, fmax)
    self._stage_done = None  # the statistics are these regions'


def stage(self, frame: FrameImages, staged: list) -> bool:
    """For the :class:`~core.tracking.engine.GaussNewtonCost` ``self``: upload each view's
    region of the fluence (and the frame's own masks) and prepare the line integrals, masks and
    their statistics on the device (:func:`fluoro_roi_kernel`). The same regions of the same
    frame again, in the same buffers, their usable pixels already counted and found (joint
    tracking's second round, which subtracts the neighbours at new poses): nothing to do, and
    False (else True: the count is to be checked)."""
    from .engine_upload import frame_rows, holding

    dev = self.device
    nv = self.n_views
    p = staged[0][4]
    Hc, Wc = self._cap
    key = (tuple(staged), tuple(self.views))
    lo, hi = frame._valid if frame._valid is not None else (0.0, 0.0)
    up = holding(dev, frame) if self.views == tuple(range(frame.n_views)) else None
    if up is not None:  # the whole frame on the device, shared by the frame's engines (engine_upload)
        done = (key, self._bufs.serial, float(lo), float(hi), int(p), frame._valid is not None)
        last = self._stage_done
        if self._stage_checked and last is not None and last[0]() is frame and last[1] == done:
            return False  # raw0, the masks and the statistics on the device are these regions'
        _prepare(self, frame, frame_rows(frame, self.views, self.roi), up.src, up.given, done)
        return True
    self._flush()  # (this engine's own rows: uploaded as they are asked for, not recorded)
    need = (nv, Hc + 2 * p, Wc + 2 * p)
    given = any(frame._given[v] is not None for v in self.views)
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
    info = np.zeros((nv, 8), dtype=np.int32)
    for i, v in enumerate(self.views):
        r0, r1, c0, c1, _ = staged[i]
        u0, v0, w, h = (int(a) for a in self.roi[i])
        g = frame._given[v]
        if upload:
            self._host_stage[i, :r1 - r0, :c1 - c0] = frame._fluence[v][r0:r1, c0:c1]
            if g is not None:
                self._host_gstage[i, :r1 - r0, :c1 - c0] = g[r0:r1, c0:c1]
        info[i] = (h, w, v0 - r0, u0 - c0, r1 - r0, c1 - c0, int(g is not None), 0)
    if upload:  # up to the last view's first hs rows (whole rows of the buffer: one contiguous block)
        _, Hs, Ws = self._stage_src.shape
        n = (nv - 1) * Hs * Ws + int(info[nv - 1, 4]) * Ws
        copy_array(self._stage_src, self._host_stage_wp, n)
        if given:
            copy_array(self._stage_given, self._host_gstage_wp, n)
        self._staged_last = (weakref.ref(frame), key)
    done = (key, self._bufs.serial, float(lo), float(hi), int(p), frame._valid is not None)
    last = self._stage_done
    if not upload and self._stage_checked and last is not None and last[0]() is frame and last[1] == done:
        return False  # raw0, the masks and the statistics on the device are these regions'
    _prepare(self, frame, info, self._stage_src, self._stage_given, done)
    return True


def _prepare(self, frame: FrameImages, info: np.ndarray, src, given, done: tuple) -> None:
    """:func:`stage`'s launches: the regions ``info`` (:func:`fluoro_roi_kernel`'s rows) of the fluence
    ``src`` and masks ``given`` on the device prepared into the engine ``self``'s buffers, with their
    statistics and the usable pixels' count (copied to the host); ``done`` its key of what was prepared."""
    nv = self.n_views
    Hc, Wc = self._cap
    p = done[4]
    lo, hi = done[2], done[3]
    last = self._info_last  # (int32 rows: equal arrays are equal bytes)
    if last is None or last.shape != info.shape or last.tobytes() != info.tobytes():
        self._host_info_np[:] = info
        self._copy(self._info, self._host_info)
        self._info_last = info
    elif self._rec is not None:  # (recorded: copied again, the same rows: one graph either way)
        self._copy(self._info, self._host_info)
    self._zero(self._fmax)
    self._zero(self._msum)
    chunk = 4096
    self._launch("roi", fluoro_roi_kernel, (nv, math.ceil(Hc * Wc / chunk), _LANES),
                 [src, given, self._info, float(lo), float(hi), int(p),
                  int(frame._valid is not None), chunk, self._raw0, self._fmask, self._fmax, self._msum])
    self._launch("shift", fluoro_shift_kernel, (nv,), [self._msum, self.mode, self._fshift, self._count])
    self._copy(self._host_count, self._count)
    self._stage_done = (weakref.ref(frame), done)
    self._stage_checked = False


def apply_rim_band(self, frame, radius_px: float) -> bool:
    """For the :class:`~core.tracking.engine.GaussNewtonCost` ``self`` (its regions just prepared):
    the usable pixels within ``radius_px`` of a black pixel of ``frame`` taken out of the domain
    (:data:`core.tracking.cost.RIM_OPTION`; the band of
    :func:`core.tracking.likelihood_rim.rim_keep`, kept between frames in the engine's
    :class:`~core.tracking.likelihood_rim.RimCache`: the round field does not move), uploaded from
    a pinned buffer without a wait. A region no black pixel comes near is left as it is, to the
    bit; True where a band was applied."""
    from .likelihood_rim import rim_cache, rim_keep

    keep = rim_keep(frame, self.views, self.roi, radius_px, self._cap, cache=rim_cache(self))
    if keep is None:
        return False
    nv, (Hc, Wc) = self.n_views, self._cap
    if self._rim_dev is None or self._rim_dev.shape != (nv, Hc, Wc):
        self._rim_dev = wp.zeros((nv, Hc, Wc), dtype=wp.uint8, device=self.device)
    self._put("rim", self._rim_dev, keep)
    self._launch("rim", keep_kernel, (nv, Hc, Wc), [self._fmask, self._rim_dev])
    return True
