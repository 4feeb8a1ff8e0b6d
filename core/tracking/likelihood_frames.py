"""The likelihood final stage's frame set-up (:class:`core.tracking.engine_likelihood.LikelihoodEngine`'s
regions): which rows of the fluence go up for the device's preparation, the pinned host buffers,
the device's or the host's regions of line integrals and usable pixels, and the neighbours' DRRs
taken from them. A mixin of the engine's; the engine's module docs (Set-up) say what each costs."""

from __future__ import annotations

import math
import weakref

import numpy as np
import warp as wp

from .cost import FrameImages, OutsideViewError, fluoro_rois, padded_region
from .engine_buffers import copy_array
from .engine_kernels import _LANES, fluoro_roi_kernel
from .likelihood_kernels import highpass_kernel, others_kernel, psf_kernel

#: :meth:`_FrameRegions.prefetch`'s rows of the frame taken by the stage's set-up where they cover its
#: own (off: the stage uploads its rows whatever went up before). Tried before it and removed: the rows
#: the tracker's engine uploaded for the search taken instead (44159b4; never taken on ``talus bench
#: track``'s trial, 1024², the talus: the stage's region, snapped outwards, reaches past the search's
#: rows in every frame) and :func:`~core.tracking.engine_kernels.fluoro_roi_kernel` over 512-pixel
#: chunks (a6686da; 0.14 -> 0.37 ms of the device a bone-frame on one NVIDIA H100, its atomics;
#: ``tracking_stage_one_bone_1d5ed65_h100.json``).
PREFETCH = True
#: The stage's set-up reads its regions from the whole frame on the device where joint registration put
#: it there (:func:`core.tracking.engine_upload.holding`: the frame's engines share one upload of it) and
#: the engine's views are the frame's: no pinned copy and upload of its own rows, the same pixels through
#: the same kernel (the same regions to the bit). Off: the stage copies and uploads its rows, as before.
#: Not measured on a GPU (three bones jointly: one copy and upload a bone-frame fewer on the host).
HELD_FRAME = True
#: Tried and removed (c44087f, then its kernel): the regions made with the usable pixels counted per thread
#: block (one atomic a block instead of three a thread; exact): timed on one NVIDIA H100 (``stage_one_bone
#: --interleave 3``, ``resources/benchmarks/tracking_share_frame_h100.json``) the stage took 2.73 ms (median)
#: with it against 2.57 with :func:`~core.tracking.engine_kernels.fluoro_roi_kernel`.


def _covering(frame, rows, staged: list, src, gsrc):
    """``(src, gsrc, rows)`` where the uploaded ``rows`` (per view ``(r0, r1, c0, c1, erosion)``)
    cover ``staged``'s with the frame's erosion, else None."""
    p = frame._erode if frame._valid is not None else 0
    if len(rows) == len(staged) and all(
            int(q[4]) == p and q[0] <= a[0] and a[1] <= q[1] and q[2] <= a[2] and a[3] <= q[3]
            for q, a in zip(rows, staged, strict=True)):
        return src, gsrc, rows
    return None


class _FrameRegions:
    """:class:`~core.tracking.engine_likelihood.LikelihoodEngine`'s frame set-up steps (its
    attributes: ``views``, ``roi``, ``renderer``, ``device``, buffers)."""

    def _staged(self, frame, roi=None) -> list | None:
        """Per view ``(r0, r1, c0, c1)``, the image rows and columns to upload for the device's
        preparation of the regions ``roi`` (default the frame's, :attr:`roi`; each grown by the mask's
        erosion), or None where the host prepares them (not a :class:`~core.tracking.cost.FrameImages`,
        a region reaching outside its image: :func:`~core.tracking.cost.fluoro_rois`)."""
        if not isinstance(frame, FrameImages):
            return None
        p = frame._erode if frame._valid is not None else 0
        roi = self.roi if roi is None else np.asarray(roi, dtype=np.int64).reshape(self.n_views, 4)
        out = []
        for i, v in enumerate(self.views):
            u0, v0, w, h = (int(a) for a in roi[i])
            H, W = frame.shapes[v]
            if w <= 0 or h <= 0 or u0 < 0 or v0 < 0 or u0 + w > W or v0 + h > H:
                return None
            out.append((max(v0 - p, 0), min(v0 + h + p, H), max(u0 - p, 0), min(u0 + w + p, W)))
        return out

    def _pinned(self, name: str, shape: tuple, dtype=wp.float32, *, exact: bool = False):
        """A pinned host buffer of this engine's of at least ``shape`` (grown only: pinned memory
        is slow to allocate; 2-D and 3-D in 64-pixel steps; ``exact``: of that shape)."""
        b = self._host.get(name)
        if b is None or (tuple(b.shape) != tuple(shape) if exact else
                         any(a < n for a, n in zip(b.shape, shape, strict=True))):
            grown = tuple(shape)
            if not exact and len(grown) > 1:
                grown = grown[:1] + tuple(int(math.ceil(n / 64.0) * 64) for n in grown[1:])
            if b is not None and not exact:
                grown = tuple(max(a, n) for a, n in zip(b.shape, grown, strict=True))
            b = self._host[name] = wp.zeros(grown, dtype=dtype, device="cpu", pinned=self.device.is_cuda)
        return b

    def _uploaded(self) -> None:
        """Mark the uploads enqueued so far: the pinned buffers are written again after them."""
        if self.device.is_cuda:
            if self._up_event is None:
                self._up_event = wp.Event(self.device)
            self.device.stream.record_event(self._up_event)  # (the stream its copies went on)

    def prefetch(self, frame: FrameImages, roi) -> bool:
        """Upload the fluence (and the frame's own masks) of the regions ``roi (views, 4)`` of ``frame``,
        grown by the mask's erosion, ahead of :meth:`set_frame` (while the search of the frame runs:
        :func:`core.tracking.final_stage.stage_prefetch`): a later set-up of this frame whose rows they
        cover takes them on the device instead of copying and uploading its own (:data:`PREFETCH`; the
        same fluence: the same regions). Returns whether anything went up (False: regions the host
        prepares)."""
        rows = self._staged(frame, roi)
        if rows is None:
            return False
        ev = self.__dict__.get("_pre_event")
        if ev is not None:  # (the pinned rows written again after their last copy)
            wp.synchronize_event(ev)
        nv = self.n_views
        Hs = max(r1 - r0 for r0, r1, _, _ in rows)
        Ws = max(c1 - c0 for _, _, c0, c1 in rows)
        given = any(frame._given[v] is not None for v in self.views)
        host = self._pinned("pre", (nv, Hs, Ws))
        hg = self._pinned("pre_given", tuple(host.shape), wp.uint8) if given else None
        src, gsrc = self.__dict__.get("_pre_src"), self.__dict__.get("_pre_given")
        if src is None or tuple(src.shape) != tuple(host.shape):
            src = self._pre_src = wp.zeros(tuple(host.shape), dtype=wp.float32, device=self.device)
        if given and (gsrc is None or tuple(gsrc.shape) != tuple(host.shape)):
            gsrc = self._pre_given = wp.zeros(tuple(host.shape), dtype=wp.uint8, device=self.device)
        elif gsrc is None:
            gsrc = self._pre_given = wp.zeros((nv, 1, 1), dtype=wp.uint8, device=self.device)
        hn = host.numpy()
        gn = None if hg is None else hg.numpy()
        for i, v in enumerate(self.views):
            r0, r1, c0, c1 = rows[i]
            hn[i, :r1 - r0, :c1 - c0] = frame._fluence[v][r0:r1, c0:c1]
            g = frame._given[v]
            if g is not None:
                gn[i, :r1 - r0, :c1 - c0] = g[r0:r1, c0:c1]
        Ws_ = host.shape[2]
        n = (nv - 1) * host.shape[1] * Ws_ + (rows[-1][1] - rows[-1][0]) * Ws_
        copy_array(src, host, n)
        if given:
            copy_array(gsrc, hg, n)
        if self.device.is_cuda:
            if ev is None:
                ev = self._pre_event = wp.Event(self.device)
            self.device.stream.record_event(ev)
        p = frame._erode if frame._valid is not None else 0
        self._pre = (weakref.ref(frame), [(*r, p) for r in rows], src, gsrc)
        return True

    def _prefetched(self, frame: FrameImages, staged: list):
        """:meth:`prefetch`'s ``(src, given, rows)`` where it uploaded this frame's rows covering
        ``staged``'s, else None."""
        pre = self.__dict__.get("_pre")
        if pre is None or pre[0]() is not frame:
            return None
        return _covering(frame, pre[1], staged, pre[2], pre[3])

    def _held(self, frame: FrameImages):
        """The :class:`~core.tracking.engine_upload.FrameUpload` holding ``frame`` on the engine's device
        where the stage reads its regions there (:data:`HELD_FRAME`: the engine's views the frame's, in
        order), else None."""
        if not HELD_FRAME or self.views != tuple(range(frame.n_views)):
            return None
        from .engine_upload import holding

        return holding(self.device, frame)

    def _stage(self, frame: FrameImages, staged: list, li, mask, launch: bool = True):
        """Each view's region of the fluence uploaded as it is (or :meth:`prefetch`'s upload of it
        taken on the device: :data:`PREFETCH`) and its line integrals and usable pixels made on the
        device (:func:`~core.tracking.engine_kernels.fluoro_roi_kernel`, the
        values of :meth:`~core.tracking.cost.FrameImages.region`); the usable pixels counted there,
        taken at the next step's synchronisation. Read from the whole frame where joint registration
        put it on the device (:data:`HELD_FRAME`). ``launch`` False: the regions' kernel not launched, its
        arguments returned for :meth:`_roi_enqueue` (the item table written, the rows uploaded)."""
        nv = self.n_views
        p = frame._erode if frame._valid is not None else 0
        up = self._held(frame)
        if up is not None:  # the whole frame on the device (HELD_FRAME): the regions read there
            from .engine_upload import frame_rows

            self._view(self._host_info)[:] = frame_rows(frame, self.views, self.roi)
            return self._roi_made(frame, up.src, up.given, li, mask, p, launch)
        shared = self._prefetched(frame, staged) if PREFETCH else None
        if shared is not None:
            src, gsrc, rows = shared
            info = self._view(self._host_info)
            for i, v in enumerate(self.views):
                r0, r1, c0, c1 = (int(a) for a in rows[i][:4])
                u0, v0, w, h = (int(a) for a in self.roi[i])
                info[i] = (h, w, v0 - r0, u0 - c0, r1 - r0, c1 - c0, int(frame._given[v] is not None), 0)
            return self._roi_made(frame, src, gsrc, li, mask, p, launch)
        Hs = max(r1 - r0 for r0, r1, _, _ in staged)
        Ws = max(c1 - c0 for _, _, c0, c1 in staged)
        given = any(frame._given[v] is not None for v in self.views)
        host = self._pinned("stage", (nv, Hs, Ws))
        # (of the fluence's buffer's shape: both go up as one block in its layout, n elements; grown
        # only for frames with masks of their own, it would be smaller after a larger frame without)
        hg = self._pinned("stage_given", tuple(host.shape), wp.uint8) if given else None
        src = self._buffer("stage", tuple(host.shape))
        gsrc = self._buffer("stage_given", tuple(host.shape), wp.uint8) if given else \
            self._buffer("stage_given", (nv, 1, 1), wp.uint8)
        hn = host.numpy()
        gn = None if hg is None else hg.numpy()
        info = self._view(self._host_info)
        info[:] = 0
        for i, v in enumerate(self.views):
            r0, r1, c0, c1 = staged[i]
            u0, v0, w, h = (int(a) for a in self.roi[i])
            hn[i, :r1 - r0, :c1 - c0] = frame._fluence[v][r0:r1, c0:c1]
            g = frame._given[v]
            if g is not None:
                gn[i, :r1 - r0, :c1 - c0] = g[r0:r1, c0:c1]
            info[i] = (h, w, v0 - r0, u0 - c0, r1 - r0, c1 - c0, int(g is not None), 0)
        Ws_ = host.shape[2]
        n = (nv - 1) * host.shape[1] * Ws_ + (staged[-1][1] - staged[-1][0]) * Ws_
        copy_array(src, host, n)
        if given:
            copy_array(gsrc, hg, n)
        return self._roi_made(frame, src, gsrc, li, mask, p, launch)

    def _roi_made(self, frame: FrameImages, src, gsrc, li, mask, p: int, launch: bool):
        """:meth:`_roi_launch` (``launch``), or its :meth:`_roi_enqueue` arguments returned (not enqueued)."""
        if launch:
            self._roi_launch(frame, src, gsrc, li, mask, p)
            return None
        return self._roi_args(frame, src, gsrc, li, mask, p)

    def _roi_args(self, frame: FrameImages, src, gsrc, li, mask, p: int) -> tuple:
        """:meth:`_roi_enqueue`'s arguments (the count taken at the next step's synchronisation)."""
        lo, hi = frame._valid if frame._valid is not None else (0.0, 0.0)
        self._count_pending = True
        return (src, gsrc, li, mask, float(lo), float(hi), int(p), int(frame._valid is not None))

    def _roi_launch(self, frame: FrameImages, src, gsrc, li, mask, p: int) -> None:
        """:func:`~core.tracking.engine_kernels.fluoro_roi_kernel` on the staged fluence ``src`` (the
        item table in ``_host_info``) into ``li`` and ``mask``, the usable pixels' count copied back."""
        self._roi_enqueue(*self._roi_args(frame, src, gsrc, li, mask, p))

    def _roi_enqueue(self, src, gsrc, li, mask, lo: float, hi: float, p: int, valid: int) -> None:
        """:meth:`_roi_launch`'s device work."""
        Hc, Wc = self._cap
        copy_array(self._info, self._host_info)
        self._msum.zero_()
        chunk = self.chunk  # (the engine's 4096: smaller chunks were slower, PREFETCH's docs)
        self._launch("roi", fluoro_roi_kernel, (self.n_views, math.ceil(Hc * Wc / chunk), _LANES),
                     [src, gsrc, self._info, lo, hi, p, valid, chunk, li, mask, self._fmax, self._msum])
        copy_array(self._host_msum, self._msum)

    def _regions(self, frame) -> tuple[list, list]:
        """Per view the region's line integrals and usable pixels (views into the frame's cached
        regions where they can be, else copies: the values of
        :func:`~core.tracking.cost.fluoro_rois`); their usable pixels counted (``n_pixels``).
        Raises OutsideViewError like it."""
        rois, masks = [], []
        if not isinstance(frame, FrameImages):
            rois, masks = fluoro_rois(self.renderer, frame, views=self.views, roi=self.roi)
        else:
            for i, v in enumerate(self.views):
                sub, m, r = padded_region(frame, v, self.roi[i], 1.0)
                x0, y0, w, h = (int(a) for a in r)
                if x0 + w > sub.shape[1] or y0 + h > sub.shape[0]:  # (not at full resolution)
                    rois, masks = fluoro_rois(self.renderer, frame, views=self.views, roi=self.roi)
                    break
                rois.append(sub[y0:y0 + h, x0:x0 + w])
                masks.append(None if m is None else m[y0:y0 + h, x0:x0 + w])
                if masks[-1] is not None and not masks[-1].any():
                    raise OutsideViewError(f"frame: no usable fluoroscope pixel in the search region of "
                                           f"view {v}")
        self.n_pixels = int(sum(f.size if m is None else np.count_nonzero(m)
                                for f, m in zip(rois, masks, strict=True)))
        return rois, masks

    def _host_upload(self, rois: list, masks: list, li, mask) -> None:
        """The host's regions and usable pixels into the device's ``li`` and ``mask`` (padded
        layout, 0 beyond each view's region), through pinned buffers (flat, grown only: the
        regions' size changes from frame to frame and pinned memory is slow to allocate)."""
        n = li.size
        hl = self._pinned("li", (math.ceil(n / 65536.0) * 65536,))
        hm = self._pinned("mask", (math.ceil(n / 65536.0) * 65536,), wp.uint8)
        a, m_ = hl.numpy()[:n].reshape(li.shape), hm.numpy()[:n].reshape(li.shape)
        for i, (f, m) in enumerate(zip(rois, masks, strict=True)):
            h, w = f.shape
            a[i, :h, :w] = f
            a[i, h:] = 0.0
            a[i, :h, w:] = 0.0
            m_[i, :h, :w] = 1 if m is None else m
            m_[i, h:] = 0
            m_[i, :h, w:] = 0
        wp.copy(li, hl, 0, 0, n)
        wp.copy(mask, hm, 0, 0, n)
        self._count_pending = False

    def _frame_others(self, others, li) -> None:
        """The neighbours ``others = (poses, bones)`` rendered at their poses on the device (the
        PSF's blur after their sum, as the bone's DRRs): taken from the line integrals ``li`` into
        ``_y_raw``, or their own regressor ``_o_raw`` (``others_gain``); without neighbours
        ``_y_raw`` is ``li`` itself."""
        nv = self.n_views
        Hc, Wc = self._cap
        dev = self.device
        n = 0 if others is None else len(others[1])
        self._with_o = bool(n and self.others_gain)
        self._o_raw = None
        if not n:
            self._y_raw = li
            return
        P, bones = np.asarray(others[0], dtype=float)[None], tuple(int(b) for b in others[1])
        img = self._render_own(P, bones) if self._graph_step() else self._render(P, bones)
        y = self._y_raw = self._buffer("y_raw", (nv, Hc, Wc))
        o = self._buffer("o_raw", (nv, Hc, Wc))
        gain = self._with_o or self._psf is not None  # the PSF's blur before the subtraction
        self._launch("others", others_kernel, (nv, Hc, Wc), [img, n, li, self._ref_hw, int(gain), y, o])
        if self._psf is not None:
            ob = self._buffer("o_psf", (nv, Hc, Wc))
            wp.launch(psf_kernel, dim=(nv, Hc, Wc), inputs=[o, ob, self._psf, self._ref_hw, nv], device=dev)
            if self._with_o:
                o = ob
            else:  # y = li - psf ∗ others
                wp.launch(highpass_kernel, dim=(nv, Hc, Wc), inputs=[li, ob, 1.0, y], device=dev)
        if self._with_o:
            self._o_raw = o

    def _others_own(self, others, li) -> tuple:
        """:meth:`_frame_others`' host part where its DRRs go through the engine's own item table
        (:meth:`~core.tracking.likelihood_graph._StepGraphs._render_own`, no PSF): the table written, the
        buffers and settings set; the arguments of its device part (:meth:`_others_enqueue`) returned."""
        nv = self.n_views
        Hc, Wc = self._cap
        n = len(others[1])
        self._with_o = bool(n and self.others_gain)
        self._o_raw = None
        P, bones = np.asarray(others[0], dtype=float)[None], tuple(int(b) for b in others[1])
        host, _, items, img, cmd = self._render_own(P, bones, launch=False)
        y = self._y_raw = self._buffer("y_raw", (nv, Hc, Wc))
        o = self._buffer("o_raw", (nv, Hc, Wc))
        if self._with_o:
            self._o_raw = o
        return (host, items, cmd, img, n, li, int(self._with_o), y, o)

    def _others_enqueue(self, host, items, cmd, img, n: int, li, gain: int, y, o) -> None:
        """:meth:`_others_own`'s device part: the item table up, the DRRs, the neighbours taken out."""
        nv = self.n_views
        Hc, Wc = self._cap
        copy_array(items, host)
        cmd.launch()
        self._launch("others", others_kernel, (nv, Hc, Wc), [img, n, li, self._ref_hw, gain, y, o])

    def _take_count(self) -> None:
        """The usable pixels the device's preparation counted (copied before the last
        synchronisation); raises OutsideViewError for a view without any."""
        self._count_pending = False
        n = self._view(self._host_msum)[:, 0]
        self.n_pixels = round(float(n.sum()))
        for i, k in enumerate(n):
            if k <= 0:
                v = self.views[i]
                raise OutsideViewError(f"frame: no usable fluoroscope pixel in the search region of view {v}")
