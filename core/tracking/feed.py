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
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from .cost import prepare_frame

__all__ = ["FrameFeed"]


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

    def _prepare(self, imgs: list):
        if any(im is None for im in imgs):
            return None
        return prepare_frame(imgs, valid_range=self.valid_range, erode_px=self.erode_px)

    def get(self, f: int) -> tuple[list, object]:
        """``(images, prepared frame or None where a view has no frame)`` of frame ``f``."""
        if self.ahead is not None and self.ahead[0] == f:
            _, imgs, fut = self.ahead
            self.ahead = None
            self.current = (f, imgs)
            return imgs, fut.result()
        imgs = list(self.frames(f))
        self.current = (f, imgs)
        return imgs, self._prepare(imgs)

    def prefetch(self, f: int) -> None:
        """Read frame ``f`` now and prepare it in the worker thread (unless the callable refills
        one buffer: then nothing, and ``f`` is read at its turn)."""
        from concurrent.futures import ThreadPoolExecutor

        if self.refills:
            return
        try:
            imgs = list(self.frames(f))
        except Exception:  # raised again when the frame's turn comes, as without the look-ahead
            self.ahead = None
            return
        if self.current is not None and _share(imgs, self.current[1]):
            self.refills, self.ahead = True, None
            self.frames(self.current[0])  # the buffer back to the frame being registered
            return
        if self.pool is None:
            self.pool = ThreadPoolExecutor(1, thread_name_prefix="talus-frames")
        self.ahead = (f, imgs, self.pool.submit(self._prepare, imgs))

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)


def _share(a: Sequence, b: Sequence) -> bool:
    """Whether an image of ``a`` shares memory with one of ``b``."""
    return any(isinstance(x, np.ndarray) and isinstance(y, np.ndarray) and np.may_share_memory(x, y)
               for x in a for y in b)
