"""One upload of a frame's fluence shared by the Gauss–Newton engines of its bones (joint tracking).

Each engine (:class:`core.tracking.engine.GaussNewtonCost`) prepares its full-resolution search regions
on the device from the fluence of the frame (:func:`core.tracking.engine_frames.stage`): on its own it
copies each view's region (grown by the usable-pixel mask's erosion) into pinned memory and uploads it —
three bones tracked jointly copied three overlapping regions of each view a frame, on the host's
critical path. :func:`share` instead puts the whole frame (every view's fluence, and the frame's own
masks where it has them) on the device once, from a pinned copy, and every engine of that frame reads
its regions there (:func:`holding`; each bone's region an offset into the whole image): the same pixels
through the same kernel, so the same line integrals, masks and statistics to the bit.

The pinned copy is made ahead where it can be: :class:`core.tracking.feed.FrameFeed` prepares the next
frame in a worker thread while the current one registers, and there copies its fluence into one of
:data:`PINNED_SETS` pinned buffer sets (:func:`pin_ahead`; numpy's copy releases the GIL), so that the
registering thread only enqueues the upload. A set whose upload may still be in flight is not written
again until the registering thread has waited for its event (the worker makes no CUDA call). Where no
pinned copy is ready (the first frame, a frame the feed did not prepare) :func:`share` makes it itself.

:func:`core.tracking.joint.register_together` calls
:func:`share` for its jobs' frame, and any registration of that frame afterwards (the fallback, the final
stage's passes, the frame's later rounds) reads the same device copy while it holds that frame. One bone's
registration shares its frame too (:data:`core.tracking.register.SHARE_FRAME`; its regions are an eighth of
the frame for the talus, but the device is idle while the host prepares the search, and the host copies go),
and with the final stage the next frame goes up while the device works on this frame's stage
(:data:`core.tracking.trial.NEXT_FRAME_AHEAD`): on CUDA on a stream of its own (``ahead``), after the
device's work so far (which may still read the frame held before) and beside the stage's later steps; the
device's stream waits for it only where the frame is read (:meth:`FrameUpload.ready`, in :func:`share` and
:func:`holding`). Each
registering thread has its own device copy and pinned sets (keyed by ``threading.get_ident()``; the feed's
worker fills those of the thread that asked it to prefetch): two trials started at once in one process
(two windows, a batch beside a window) never read or overwrite each other's frame; their registrations take
turns on a device (:func:`core.tracking.trial.device_lock`, held by ``track`` for its run).
"""

from __future__ import annotations

import itertools
import os
import threading
import weakref

import numpy as np
import warp as wp

from .engine_buffers import copy_array

__all__ = ["DEVICES", "FILL_ASIDE", "PINNED_SETS", "SHARED_UPLOAD", "Aside", "FrameUpload", "fill_aside",
           "holding", "pin_ahead", "share"]

#: Switch: joint registration's engines read their regions from one upload of the whole frame.
SHARED_UPLOAD = True

#: The device kinds it applies on ("cuda"; the tests add "cpu", where it runs the same code).
DEVICES = ("cuda",)

#: Pinned buffer sets per device: the frame being registered, the next one filled ahead, one spare.
PINNED_SETS = 3

_STAMP = itertools.count(1)


class _HostSet:
    """One pinned copy of a frame: its fluence (``(n_views, H, W)`` float32) and masks (uint8)."""

    def __init__(self, shape: tuple, pinned: bool) -> None:
        self.fluence = wp.zeros(shape, dtype=wp.float32, device="cpu", pinned=pinned)
        self.given = wp.zeros(shape, dtype=wp.uint8, device="cpu", pinned=pinned)
        self.fluence_np = self.fluence.numpy()
        self.given_np = self.given.numpy()
        self.frame = None  # weak reference to the frame it holds (None: nothing, or being filled)
        self.has_given = False
        self.filling = False  # being written (a thread of its own)
        self.event = None  # recorded after the last upload from it (CUDA)
        self.busy = False  # an upload from it may be in flight: not written until its event is waited for
        self.stamp = 0  # when it was filled (the least recently filled is written first)

    def fill(self, frame) -> None:
        """Copy ``frame``'s fluence and masks in (the caller has marked the set as filling)."""
        fl, gv = self.fluence_np, self.given_np
        has = False
        for v in range(frame.n_views):
            f = frame._fluence[v]
            h, w = f.shape
            fl[v, :h, :w] = f
            g = frame._given[v]
            if g is not None:
                gv[v, :h, :w] = g
                has = True
        self.has_given = has


class FrameUpload:
    """The whole frame on one device (``src`` fluence, ``given`` masks, ``(n_views, H, W)``), the frame it
    holds (:attr:`on_device`) and the pinned sets it is uploaded from."""

    def __init__(self, device, shape: tuple) -> None:
        self.device = device
        self.shape = tuple(int(a) for a in shape)
        pinned = device.is_cuda
        self.src = wp.zeros(self.shape, dtype=wp.float32, device=device)
        self.given = wp.zeros(self.shape, dtype=wp.uint8, device=device)
        self.sets = [_HostSet(self.shape, pinned) for _ in range(PINNED_SETS)]
        self.lock = threading.Lock()
        self.on_device = None  # weak reference to the frame whose fluence src holds
        self.given_on = False  # given holds that frame's masks
        self.uploads = 0  # uploads made (tests)
        self.filled_here = 0  # pinned copies made by share itself (not ahead)
        # (CUDA) an upload made ahead on a stream of its own (upload's ``ahead``): the event the device's
        # stream waits for before it reads the frame (ready), the stream and its start event
        self.pending = None
        self.side = None
        self.side_start = None
        self.coming = None  # weak reference to a frame being pinned aside before its upload (fill_aside)

    def fits(self, frame) -> bool:
        nv, H, W = self.shape
        return frame.n_views == nv and all(h <= H and w <= W for h, w in frame.shapes)

    def holds(self, frame) -> bool:
        return self.on_device is not None and self.on_device() is frame

    def _take(self, frame) -> _HostSet | None:
        """(Under the lock) a set to fill with ``frame``: the least recently filled of those not busy,
        not being filled and not holding the frame on the device; marked as filling. None: none free."""
        cur = self.on_device() if self.on_device is not None else None
        com = self.coming() if self.coming is not None else None
        keep = tuple(a for a in (cur, com) if a is not None)
        free = [s for s in self.sets if not s.busy and not s.filling
                and not (s.frame is not None and any(s.frame() is a for a in keep))]
        if not free:
            return None
        s = min(free, key=lambda a: a.stamp)
        s.filling, s.frame = True, None
        return s

    def pin_ahead(self, frame) -> bool:
        """Copy ``frame`` into a free pinned set (a worker thread: no CUDA call); False where none is
        free or it is already held."""
        with self.lock:
            if any(s.frame is not None and s.frame() is frame for s in self.sets):
                return False
            s = self._take(frame)
        if s is None:
            return False
        ok = False
        try:
            s.fill(frame)
            ok = True
        finally:
            with self.lock:  # (both at once: a set no longer filling is never seen without its frame)
                s.filling = False
                if ok:
                    s.frame, s.stamp = weakref.ref(frame), next(_STAMP)
        return True

    def ready(self) -> None:
        """(CUDA) The device's stream made to wait for an upload made ahead on the side stream before
        its next work (which reads the frame); nothing where none is pending."""
        if self.pending is not None:
            self.device.stream.wait_event(self.pending)
            self.pending = None

    def upload(self, frame, ahead: bool = False) -> None:
        """Put ``frame`` on the device (the registering thread): from the set holding it (filled ahead),
        else from a set filled here; the earlier uploads' events waited for first (done long since in a
        tracking run: the frames before this one have synchronised), so their sets may be written
        again. ``ahead`` (CUDA): the copy on a stream of its own, after the work the device's stream has
        been given so far (which may still read the frame held before) and beside what it is given next
        (another frame's final stage), the device's stream waiting for it only where the frame is read
        (:meth:`ready`: :func:`share`, :func:`holding`)."""
        if self.holds(frame):
            return
        cuda = self.device.is_cuda
        for s in self.sets:
            if s.busy:
                if cuda and s.event is not None:
                    wp.synchronize_event(s.event)
                s.busy = False
        with self.lock:
            s = next((a for a in self.sets if not a.filling and a.frame is not None and a.frame() is frame),
                     None)
            if s is None:
                s = self._take(frame)
            if s is None:  # (not in a tracking run: the worker fills one set at a time) one more set
                s = _HostSet(self.shape, cuda)
                s.filling = True
                self.sets.append(s)
            s.busy = True  # not written from here on, until the next upload has waited for its event
        if s.filling:
            ok = False
            try:
                s.fill(frame)
                ok = True
            finally:
                with self.lock:
                    s.filling = False
                    if ok:
                        s.frame, s.stamp = weakref.ref(frame), next(_STAMP)
                    else:
                        s.busy = False
            self.filled_here += 1
        side = cuda and ahead
        if side:
            if self.side is None:
                self.side = wp.Stream(self.device)
                self.side_start = wp.Event(self.device)
            self.device.stream.record_event(self.side_start)  # (the reads of the frame held before)
            self.side.wait_event(self.side_start)
            self.ready()  # (an earlier ahead upload: the stream's order, the side stream's after it)
        elif cuda:
            self.ready()  # (a copy over one still in flight on the side stream: after it)
        with wp.ScopedStream(self.side, sync_enter=False) if side else _nothing():
            copy_array(self.src, s.fluence)
            if s.has_given:
                copy_array(self.given, s.given)
        if cuda:
            stream = self.side if side else self.device.stream
            if s.event is None:
                s.event = wp.Event(self.device)
            stream.record_event(s.event)  # (the stream the copies went on)
            if side:
                self.pending = s.event
        self.on_device = weakref.ref(frame)
        if self.coming is not None and self.coming() is frame:
            self.coming = None
        self.given_on = s.has_given
        self.uploads += 1


_UPLOADS: dict = {}  # (device alias, registering thread) -> FrameUpload
_ACTIVE: dict = {}  # registering thread -> the FrameUpload it shared last (pin_ahead fills its sets)


def applies(device) -> bool:
    kind = "cuda" if device.is_cuda else "cpu"
    return SHARED_UPLOAD and kind in DEVICES


class _nothing:
    def __enter__(self):
        return None

    def __exit__(self, *a):
        return False


def share(device, frame, ahead: bool = False) -> FrameUpload | None:
    """Put the whole of ``frame`` (a :class:`~core.tracking.cost.FrameImages`) on ``device`` for the
    engines of its bones (module docs); None where it does not apply (switched off, another device kind,
    another kind of frame). Each registering thread has its own device copy and pinned sets (two windows
    or a window and a batch started at once in one process do not share them; their runs take turns on the
    device: :func:`core.tracking.trial.device_lock`)."""
    up = _upload_of(device, frame)
    if up is None:
        return None
    if ahead:
        up.upload(frame, ahead=True)
    else:
        up.upload(frame)
        up.ready()
    return up


def _upload_of(device, frame) -> FrameUpload | None:
    """The calling thread's :class:`FrameUpload` of ``device`` that fits ``frame`` (made or grown here),
    marked as the one it shares last; None where :func:`share` does not apply."""
    from .cost import FrameImages

    if not (applies(device) and isinstance(frame, FrameImages)) or frame.n_views == 0:
        return None
    key = (device.alias, threading.get_ident())
    up = _UPLOADS.get(key)
    if up is None or not up.fits(frame):
        nv = frame.n_views
        H = max(h for h, _ in frame.shapes)
        W = max(w for _, w in frame.shapes)
        if up is not None and up.shape[0] == nv:  # grown (the larger of the two)
            H, W = max(H, up.shape[1]), max(W, up.shape[2])
        alive = {t.ident for t in threading.enumerate()}  # (those of threads gone let go: their memory)
        for k in [k for k in list(_UPLOADS) if k[1] not in alive]:  # (a copy: another thread may add a key)
            _UPLOADS.pop(k, None)
        for k in [k for k in list(_ACTIVE) if k not in alive]:
            _ACTIVE.pop(k, None)
        up = _UPLOADS[key] = FrameUpload(device, (nv, H, W))
    _ACTIVE[key[1]] = up
    return up


#: A first frame's pinned copy made aside: :func:`core.tracking.register.register`'s global search
#: (``"global_newton"``: a first frame, a retry) has the copy made in a thread of its own (:func:`fill_aside`,
#: started once its CMA-ES stage's pyramid is prepared) and shares the frame (:func:`share`) only before its
#: first full-resolution preparation — the CMA-ES stage and the coarser Gauss–Newton levels read host
#: pyramids, not the upload — so that the copy (no frame before the first to pin it ahead) runs beside the
#: CMA-ES stage instead of before it. The same pixels
#: uploaded before anything reads them: the same results. Off: :func:`share` at the registration's start.
FILL_ASIDE = True

_PIN_POOL = None


class Aside:
    """A frame's pinned copy to be made aside (:func:`fill_aside`): :meth:`start` hands it to a thread of
    its own, :meth:`wait` waits for it (nothing where it was not started: :func:`share` then makes the
    copy itself; an error in it is left to :func:`share` likewise)."""

    def __init__(self, up: FrameUpload, frame) -> None:
        self.up, self.frame, self.future = up, weakref.ref(frame), None

    def start(self) -> None:
        global _PIN_POOL
        frame = self.frame()
        if self.future is not None or frame is None:
            return
        if _PIN_POOL is None:
            from concurrent.futures import ThreadPoolExecutor

            _PIN_POOL = ThreadPoolExecutor(1, thread_name_prefix="talus-pin")
        self.future = _PIN_POOL.submit(self.up.pin_ahead, frame)

    def wait(self) -> None:
        from concurrent.futures import wait

        if self.future is not None:
            wait((self.future,))

    def drop(self) -> None:
        """The registration stopped before sharing the frame (an error, a cancel): the copy waited for (a
        set it filled holds the frame, found again by a retry) and the frame no longer counted as coming."""
        self.wait()
        frame = self.frame()
        with self.up.lock:
            if self.up.coming is not None and self.up.coming() is frame:
                self.up.coming = None


def fill_aside(device, frame) -> Aside | None:
    """The pinned copy of ``frame`` for the calling thread's upload of ``device`` to be made in a thread of
    its own (:data:`FILL_ASIDE`): an :class:`Aside` to start when the caller's own host work leaves the
    machine room for it, and to wait for before :func:`share` of the frame, which then finds the copy
    made; None where there is nothing to do (the switch off, sharing does not apply, the frame already
    held or pinned). The frame is marked as coming from now on: it counts as held for :func:`pin_ahead`
    (the feed's worker pins the next frame meanwhile, as where the frame was shared here)."""
    if not FILL_ASIDE:
        return None
    up = _upload_of(device, frame)
    if up is None or up.holds(frame):
        return None
    with up.lock:
        if any(s.frame is not None and s.frame() is frame for s in up.sets):
            return None
        up.coming = weakref.ref(frame)
    return Aside(up, frame)


def holding(device, frame) -> FrameUpload | None:
    """The :class:`FrameUpload` of ``device`` and the calling thread that holds ``frame`` now, or None."""
    if not SHARED_UPLOAD:
        return None
    up = _UPLOADS.get((device.alias, threading.get_ident()))
    if up is None or not up.holds(frame):
        return None
    up.ready()
    return up


def pin_ahead(frame, after=(), owner: int | None = None) -> bool:
    """The pinned copy of ``frame`` made now (:class:`core.tracking.feed.FrameFeed`'s worker thread) for
    the registering thread ``owner`` (its ``threading.get_ident()``; None: the calling thread), in the
    sets of the device it shared a frame on last, where that device holds one of the frames ``after``
    (those handed out before it: the run shares its frames; one bone's run after joint tracking does
    not); False where not, or where it does not fit."""
    up = _ACTIVE.get(threading.get_ident() if owner is None else owner) if SHARED_UPLOAD else None
    if up is None or not up.fits(frame):
        return False
    com = up.coming() if up.coming is not None else None
    if not any(up.holds(a) or (com is not None and a is com) for a in after):
        return False
    return up.pin_ahead(frame)


def _forget() -> None:
    """In a forked child: the parent's device buffers, pinned memory and thread are not the child's."""
    global _PIN_POOL
    _UPLOADS.clear()
    _ACTIVE.clear()
    _PIN_POOL = None


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget)


def frame_rows(frame, views, roi) -> np.ndarray:
    """``info`` rows of :func:`~core.tracking.engine_kernels.fluoro_roi_kernel` for the regions ``roi``
    ``(n, 4)`` of ``views`` read from the whole images: ``(h, w, v0, u0, H, W, has_given, 0)``."""
    shapes, given = frame.shapes, frame._given
    rows = [(h, w, v0, u0, *shapes[v], int(given[v] is not None), 0)
            for v, (u0, v0, w, h) in zip(views, np.asarray(roi).tolist(), strict=False)]
    return np.array(rows, dtype=np.int32).reshape(len(views), 8)
