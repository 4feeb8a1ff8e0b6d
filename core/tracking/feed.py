"""Frames for :func:`core.tracking.trial.track`, prepared one frame ahead.

:class:`FrameFeed` hands the tracker each frame's images and their
:func:`~core.tracking.cost.prepare_frame` (which checks the whole images: two 1024² views took
about 1 ms of host time per frame in a profiled run on the H100 machine, where tracking the talus
alone took about 5.4 ms per frame); the next frame is read in the calling thread and prepared in
a worker thread while the current one registers — numpy's reductions release the GIL, and the
host otherwise waits on the device there. A frame whose preparation raises raises when its turn
comes, as it would without the look-ahead. A ``frames`` callable that refills the same buffer
for every frame (a video reader's habit) is noticed at the first look-ahead — the next frame's
images share memory with the current one's — and then the current frame is read again and
nothing more is read ahead: each frame is read at its turn, as without the look-ahead.

A view the callable gives None for has no image; a callable with a ``reason(frame, view)`` method
(or attribute) says why — asked right after the frame is read, for those views only: a reason
such as ``"<file>: <error>"``, or None where the view simply has no frame. The feed hands such a
view on as a :class:`MissingView` carrying the reason (a callable may give one itself), and
:func:`core.tracking.frame_step.track_frame` puts it in the frame's flag
(:func:`~core.tracking.frame_step.missing_flags`).

The worker also draws the next frame's noise samples (the noise correction's ``E₁`` estimate,
:meth:`~core.tracking.cost.FrameImages.prepare_noise`) for the views and patch sizes the frames
before it drew them for, each in a thread of its own — one set per view and patch radius (1.2 ms
per 1024² view on the H200 machine's host, 2.0 ms on the H100 machines'; two radii per view when
three bones are tracked jointly) — so the registration finds them drawn; the values are those it
would draw itself. On one H100 (1024², 20 frames) that took three bones jointly from 22.8 to
19.7 ms per frame with the correction (13.5 without); one bone stayed at 9.0-9.5 ms (3.8-5.1
without): the threads' numpy work still slows the registering thread (the GIL), and the worker
does not finish within a 5 ms registration (``resources/benchmarks/tracking_noise_speed_h100.json``).
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from .cost import prepare_frame

__all__ = ["FrameFeed", "MissingView"]


@dataclass(frozen=True)
class MissingView:
    """A view of a frame without its image, and why (its file and the reader's error), in place
    of None: the frame's flag gives the reason (:func:`core.tracking.frame_step.missing_flags`)."""

    reason: str


def _missing(im) -> bool:
    return im is None or isinstance(im, MissingView)


class FrameFeed:
    """The frames in tracking order, each prepared (:func:`~core.tracking.cost.prepare_frame`:
    the full-image checks) in a worker thread while the frame before it is registered; the
    user's ``frames`` callable itself runs in the calling thread, in order."""

    def __init__(self, frames: Callable[[int], Sequence], valid_range, erode_px: int) -> None:
        self.frames, self.valid_range, self.erode_px = frames, valid_range, erode_px
        self.pool = None
        self.ahead = None  # (frame, images, future of the prepared frame)
        self.current: tuple[int, list] | None = None  # the frame being registered and its images
        self.refills = False  # the callable refills one buffer: no look-ahead
        # the prepared frame handed out last and the noise samples the one before it drew: those
        # are drawn for the next frame in the worker thread (FrameImages.prepare_noise); only the
        # keys of the one before are kept, not the frame
        self.current_frame = None
        self.previous_keys: tuple = ()
        self.noise_pool = None
        self.before = None  # the frame handed out before current_frame

    def _prepare(self, imgs: list, noise=(), pin: tuple = ()):
        if any(_missing(im) for im in imgs):
            return None
        frame = prepare_frame(imgs, valid_range=self.valid_range, erode_px=self.erode_px)
        if len(pin) > 1:  # its pinned copy for joint registration's shared upload (engine_upload)
            from .engine_upload import pin_ahead

            try:
                pin_ahead(frame, after=pin[1:], owner=pin[0])
            except Exception:  # (the registration then makes the copy itself)
                pass
        if noise:
            try:  # a thread per view and radius (numpy releases the GIL in their large steps)
                if len(noise) > 1:
                    from concurrent.futures import wait

                    if self.noise_pool is None:
                        from concurrent.futures import ThreadPoolExecutor

                        self.noise_pool = ThreadPoolExecutor(4, thread_name_prefix="talus-noise")
                    futs = [self.noise_pool.submit(frame.prepare_noise, [k]) for k in noise]
                    # every draw finished, failed or not, before the frame is handed over: the
                    # registering thread then fills its noise dict alone
                    wait(futs)
                    for fut in futs:
                        fut.result()
                else:
                    frame.prepare_noise(noise)
            except Exception:  # a failed draw is drawn again, and raised there, when the cost asks for it
                pass
        return frame

    def _read(self, f: int) -> list:
        """Frame ``f``'s images; a view without one whose source says why is a :class:`MissingView`."""
        imgs = list(self.frames(f))
        ask = getattr(self.frames, "reason", None)
        if ask is not None:
            for v, im in enumerate(imgs):
                if im is None and (r := ask(f, v)):
                    imgs[v] = MissingView(str(r))
        return imgs

    def get(self, f: int) -> tuple[list, object]:
        """``(images, prepared frame or None where a view has no frame)`` of frame ``f``; a view
        without its image is None, or a :class:`MissingView` with the source's reason."""
        if self.current_frame is not None:  # its registrations are done: what they drew is final
            self.previous_keys = tuple(self.current_frame.noise_sample_keys)
            self.before = self.current_frame  # (kept: the shared upload's check, pin_ahead)
        if self.ahead is not None and self.ahead[0] == f:
            _, imgs, fut = self.ahead
            self.ahead = None
            self.current = (f, imgs)
            self.current_frame = fut.result()
            return imgs, self.current_frame
        imgs = self._read(f)
        self.current = (f, imgs)
        self.current_frame = self._prepare(imgs)
        return imgs, self.current_frame

    def _noise_keys(self) -> tuple:
        """The noise samples (view, patch radius) the frames handed out last have drawn."""
        keys = set(self.previous_keys)
        if self.current_frame is not None:
            keys.update(self.current_frame.noise_sample_keys)
        return tuple(sorted(keys))

    def prefetch(self, f: int) -> None:
        """Read frame ``f`` now and prepare it in the worker thread (unless the callable refills
        one buffer: then nothing, and ``f`` is read at its turn)."""
        from concurrent.futures import ThreadPoolExecutor

        if self.refills:
            return
        try:
            imgs = self._read(f)
        except Exception:  # raised again when the frame's turn comes, as without the look-ahead
            self.ahead = None
            return
        if self.current is not None and _share(imgs, self.current[1]):
            self.refills, self.ahead = True, None
            self.frames(self.current[0])  # the buffer back to the frame being registered
            return
        if self.pool is None:
            self.pool = ThreadPoolExecutor(1, thread_name_prefix="talus-frames")
        # (this thread and the frames handed out last: the next one pinned ahead where they were shared)
        pin = (threading.get_ident(), *(a for a in (self.current_frame, self.before) if a is not None))
        self.ahead = (f, imgs, self.pool.submit(self._prepare, imgs, self._noise_keys(), pin))

    def upload_ahead(self, device) -> bool:
        """The frame read ahead (:meth:`prefetch`) put on ``device`` now
        (:func:`core.tracking.engine_upload.share`; on CUDA on a stream of its own, beside the work the
        device is given meanwhile) where the worker has prepared it; nothing (False) where it has not
        yet, or could not (its turn then raises or flags as before)."""
        a = self.ahead
        if a is None or not a[2].done() or a[2].exception() is not None or a[2].result() is None:
            return False
        from .engine_upload import share

        return share(device, a[2].result(), ahead=True) is not None

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)
        if self.noise_pool is not None:
            self.noise_pool.shutdown(wait=True, cancel_futures=True)


def _share(a: Sequence, b: Sequence) -> bool:
    """Whether an image of ``a`` shares memory with one of ``b``."""
    return any(isinstance(x, np.ndarray) and isinstance(y, np.ndarray) and np.may_share_memory(x, y)
               for x in a for y in b)
