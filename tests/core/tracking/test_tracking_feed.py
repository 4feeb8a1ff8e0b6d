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
