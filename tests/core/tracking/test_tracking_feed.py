"""Frames prepared one frame ahead (core.tracking.feed)."""

from __future__ import annotations

import numpy as np
import pytest


def test_frames_are_read_in_order_and_prepared_ahead():
    from core.tracking.cost import FrameImages
    from core.tracking.feed import FrameFeed

    imgs = {0: [np.full((8, 8), 0.5, np.float32)] * 2, 1: [np.full((8, 8), 0.4, np.float32), None],
            2: [np.full((8, 8), np.nan, np.float32)] * 2}
    calls = []

    def frames(f):
        calls.append(f)
        if f == 3:
            raise OSError("frame 3 is unreadable")
        return imgs[f]

    feed = FrameFeed(frames, (0.02, 0.999), 3)
    try:
        im, fr = feed.get(0)
        assert isinstance(fr, FrameImages) and im[0] is imgs[0][0]
        feed.prefetch(1)
        im, fr = feed.get(1)  # a view without a frame: nothing to prepare
        assert fr is None and im[1] is None
        feed.prefetch(2)  # a frame that cannot be prepared raises when its turn comes
        with pytest.raises(ValueError, match="NaN"):
            feed.get(2)
        feed.prefetch(3)  # a frame the callable cannot read: read (and raised) again at its turn
        with pytest.raises(OSError, match="unreadable"):
            feed.get(3)
        assert calls == [0, 1, 2, 3, 3]
    finally:
        feed.close()



def test_a_reader_that_refills_one_buffer_is_read_at_each_frames_turn():
    from core.tracking.feed import FrameFeed

    buf = [np.zeros((8, 8), np.float32), np.zeros((8, 8), np.float32)]
    calls = []

    def frames(f):  # a reader that refills the same buffers for every frame
        calls.append(f)
        for b in buf:
            b[:] = 0.1 * (f + 1)
        return buf

    feed = FrameFeed(frames, (0.02, 0.999), 3)
    try:
        im0, _ = feed.get(0)
        feed.prefetch(1)  # noticed: the buffer is refilled with frame 0 again, no look-ahead
        assert float(im0[0][0, 0]) == pytest.approx(0.1) and feed.refills
        im1, _ = feed.get(1)
        assert float(im1[0][0, 0]) == pytest.approx(0.2)
        feed.prefetch(2)  # nothing read ahead any more
        assert float(im1[1][0, 0]) == pytest.approx(0.2)
        assert calls == [0, 1, 0, 1]
    finally:
        feed.close()


def test_noise_draws_all_finish_before_the_frame_is_handed_over(monkeypatch):
    """A failed noise draw (view, radius) does not hand the frame over while another view's draw
    still writes its noise samples from a worker thread."""
    import threading
    import time

    from core.tracking.cost import FrameImages
    from core.tracking.feed import FrameFeed

    done = threading.Event()

    def prepare_noise(self, keys):
        (v, _r), = keys
        if v == 0:
            raise RuntimeError("draw failed")
        time.sleep(0.2)
        done.set()

    monkeypatch.setattr(FrameImages, "prepare_noise", prepare_noise)
    feed = FrameFeed(lambda f: [np.full((8, 8), 0.5, np.float32)] * 2, (0.02, 0.999), 0)
    try:
        frame = feed._prepare(feed.frames(0), ((0, 2), (1, 2)))
        assert isinstance(frame, FrameImages) and done.is_set()
    finally:
        feed.close()
