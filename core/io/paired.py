"""Two synchronised fluoro views of one trial, paired with a frame offset."""

from __future__ import annotations

import math

import numpy as np

from .sequences import FrameSequence

__all__ = ["TwoViewSequence"]


class TwoViewSequence:
    """Pairs view 0 and view 1 of a biplane trial: ``view 1 frame = view 0 frame + offset``.

    Trial frame ``t`` (``0 <= t < len(self)``) is frame ``t + s0`` of view 0 and
    ``t + s0 + offset`` of view 1, where ``s0 = max(0, -offset)``: the trial starts at the
    first frame both views hold.

    Parameters
    ----------
    view0, view1 : FrameSequence
        The two cameras' sequences (e.g. from :func:`core.io.open_sequence`).
    offset : int
        Frames by which view 1 is ahead of view 0 (a camera triggered late has a negative
        offset). Must leave at least one frame in common.
    trim : bool
        By default the views must hold the same number of frames (the usual case: both cameras
        record the same trigger window); a mismatch most often means a wrong or truncated file
        and is an error. ``trim=True`` accepts it and uses the overlapping frames.

    Raises
    ------
    ValueError
        Mismatched frame counts (without ``trim``), no overlap, or different recorded frame
        rates; the message names both files.
    """

    def __init__(self, view0: FrameSequence, view1: FrameSequence, *, offset: int = 0, trim: bool = False):
        for i, v in enumerate((view0, view1)):
            if not isinstance(v, FrameSequence):
                raise ValueError(f"view{i}: expected a FrameSequence, got {type(v).__name__}")
        if isinstance(offset, bool) or not isinstance(offset, int | np.integer):
            raise ValueError(f"offset: expected an integer number of frames, got {offset!r}")
        n0, n1 = len(view0), len(view1)
        if n0 != n1 and not trim:
            raise ValueError(
                f"views: mismatched frame counts: {view0.path} has {n0} frames, {view1.path} has "
                f"{n1}; expected equal counts (pass trim=True to pair the overlapping frames)"
            )
        r0, r1 = view0.frame_rate, view1.frame_rate
        if r0 and r1 and not math.isclose(r0, r1, rel_tol=1e-6):
            raise ValueError(
                f"views: different frame rates: {view0.path} at {r0} Hz, {view1.path} at {r1} Hz; "
                "expected synchronised cameras"
            )
        self._views = (view0, view1)
        self._offset = int(offset)
        self._s0 = max(0, -self._offset)
        self._n = min(n0 - self._s0, n1 - self._s0 - self._offset)
        if self._n <= 0:
            raise ValueError(
                f"offset: {offset} leaves no frame in common between {view0.path} ({n0} frames) and "
                f"{view1.path} ({n1} frames)"
            )

    @property
    def views(self) -> tuple[FrameSequence, FrameSequence]:
        return self._views

    @property
    def offset(self) -> int:
        return self._offset

    def __len__(self) -> int:
        return self._n

    def view_frames(self, t: int) -> tuple[int, int]:
        """The frame index in each view of trial frame ``t``."""
        if isinstance(t, bool) or not isinstance(t, int | np.integer):
            raise TypeError(f"trial frame: expected an integer, got {type(t).__name__}")
        tt = int(t) + self._n if t < 0 else int(t)
        if not 0 <= tt < self._n:
            raise IndexError(f"trial frame {t} out of range ({self._n} paired frames)")
        return tt + self._s0, tt + self._s0 + self._offset

    def __getitem__(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        k0, k1 = self.view_frames(t)
        return self._views[0][k0], self._views[1][k1]

    def __iter__(self):
        for t in range(self._n):
            yield self[t]

    @property
    def frame_rate(self) -> float | None:
        return self._views[0].frame_rate or self._views[1].frame_rate

    def close(self) -> None:
        for v in self._views:
            v.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        a, b = (v.path.name for v in self._views)
        return f"TwoViewSequence({a}, {b}, offset={self._offset}, frames={self._n})"
