"""The :class:`FrameSequence` interface every fluoro sequence reader implements.

Kept apart from the readers (:mod:`core.io.sequences`, :mod:`core.io.cine`) so that
:func:`~core.io.sequences.open_sequence` can choose among them without an import circle.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from .errors import FileError, reading

__all__ = ["FrameSequence"]


def _check_bit_depth(bit_depth, dtype: np.dtype, path: Path) -> int:
    container = dtype.itemsize * 8
    if bit_depth is None:
        return container
    if bit_depth not in (8, 10, 12, 14, 16) or bit_depth > container:
        raise ValueError(
            f"bit_depth: expected 8, 10, 12, 14 or 16 and at most the {container} bits of {path}'s "
            f"{dtype} pixels, got {bit_depth!r}"
        )
    return int(bit_depth)


class FrameSequence(ABC):
    """A lazily read sequence of grey-level frames (see :mod:`core.io.sequences`).

    Opening and reading raise :class:`~core.io.errors.FileError` (a ``ValueError``) naming the
    file and what was expected; an out-of-range index raises ``IndexError``.
    """

    path: Path
    _bit_depth: int
    _check_range: bool = False

    @abstractmethod
    def __len__(self) -> int: ...

    @property
    @abstractmethod
    def frame_shape(self) -> tuple[int, int]:
        """``(rows, columns)`` of every frame."""

    @property
    @abstractmethod
    def dtype(self) -> np.dtype:
        """``uint8`` or ``uint16``."""

    @abstractmethod
    def _read(self, k: int) -> np.ndarray:
        """Frame ``k`` (already range-checked, non-negative)."""

    @property
    def bit_depth(self) -> int:
        """Significant bits per pixel."""
        return self._bit_depth

    @property
    def frame_rate(self) -> float | None:
        """Frames per second when the file records it, else None."""
        return None

    @property
    def frame_numbers(self) -> np.ndarray:
        """Number of each frame as the source labels it (file-name numbers, cine image numbers)."""
        return np.arange(len(self))

    @property
    def shape(self) -> tuple[int, int, int]:
        return (len(self), *self.frame_shape)

    def frame(self, k: int) -> np.ndarray:
        """Frame ``k`` as an ``(H, W)`` array (negative ``k`` counts from the end)."""
        n = len(self)
        if isinstance(k, bool) or not isinstance(k, int | np.integer):
            raise TypeError(f"frame index: expected an integer, got {type(k).__name__}")
        kk = int(k) + n if k < 0 else int(k)
        if not 0 <= kk < n:
            raise IndexError(f"frame {k} out of range for {self.path} ({n} frames)")
        with reading(self.path, f"frame {kk} of {n}"):
            img = self._read(kk)
        if self._check_range and img.max(initial=0) >> self._bit_depth:
            raise FileError(
                f"{self.path}: frame {kk} has value {int(img.max())} above the declared "
                f"{self._bit_depth}-bit range [0, {(1 << self._bit_depth) - 1}]",
                path=self.path, expected=f"{self._bit_depth}-bit values",
            )
        return img

    def __getitem__(self, key):
        if isinstance(key, slice):
            idx = range(*key.indices(len(self)))
            out = np.empty((len(idx), *self.frame_shape), dtype=self.dtype)
            for i, k in enumerate(idx):
                out[i] = self.frame(k)
            return out
        return self.frame(key)

    def __iter__(self) -> Iterator[np.ndarray]:
        for k in range(len(self)):
            yield self.frame(k)

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release the file handles (idempotent)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}({str(self.path)!r}, frames={len(self)}, "
            f"shape={self.frame_shape}, {self.bit_depth}-bit)"
        )
