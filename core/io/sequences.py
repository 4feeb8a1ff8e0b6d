"""Lazy, random-access fluoroscope sequences: TIFF folders, multipage TIFFs and AVI/MP4 videos.

Every reader implements :class:`FrameSequence`: ``len(seq)``, ``seq[k]`` (one ``(H, W)`` frame,
read on demand), ``seq[a:b]`` (a stacked copy), iteration, ``frame_shape``, ``dtype``,
``bit_depth``, ``frame_rate`` and ``frame_numbers``. Opening a sequence reads headers only: a
1000-frame 1024² trial is never loaded to show one frame. Where the format stores frames
uncompressed and contiguously (multipage TIFF written by tifffile/ImageJ, Phantom ``.cine``, see
:mod:`core.io.cine`) frames are memory-mapped views of the file.

Frames are grey-level ``uint8`` or ``uint16`` arrays indexed ``[row, col]`` (pixel ``(u, v) =
(col, row)``), values as stored (raw detector counts, not normalised). ``bit_depth`` is the
number of significant bits (8, 10, 12, 14 or 16); a TIFF's container dtype says 16 for 12-bit
data, so pass ``bit_depth=12`` to have every frame checked to lie in ``[0, 4095]``.

Errors: a file that cannot be read, a colour or non-integer image, frames of different sizes or
dtypes in one folder, or values above the declared bit depth raise
:class:`~core.io.errors.FileError` (a ``ValueError``) naming the file and what was expected; an
out-of-range frame index raises :class:`IndexError`.
"""

from __future__ import annotations

import math
import re
import threading
from pathlib import Path

import numpy as np
import tifffile

from .errors import FileError, reading
from .frames import FrameSequence, _check_bit_depth

__all__ = [
    "FrameSequence",
    "MultipageTiffSequence",
    "TiffFolderSequence",
    "VideoSequence",
    "open_sequence",
]

_TIFF = (".tif", ".tiff")
_VIDEO = (".avi", ".mp4", ".mov", ".mkv", ".m4v")
_DTYPES = (np.dtype(np.uint8), np.dtype(np.uint16))


def _grey_page_info(page, path: Path) -> tuple[tuple[int, int], np.dtype]:
    if page.samplesperpixel != 1 or len(page.shape) != 2:
        raise ValueError(
            f"{path}: expected single-channel grey-level frames, got pages of shape {page.shape} "
            f"with {page.samplesperpixel} samples per pixel"
        )
    dtype = np.dtype(page.dtype)
    if dtype not in _DTYPES:
        raise ValueError(f"{path}: expected 8-, 12- or 16-bit unsigned frames (uint8/uint16), got {dtype}")
    return (int(page.shape[0]), int(page.shape[1])), dtype


# ---------------------------------------------------------------------------- TIFF folder
_NUM = re.compile(r"(\d+)(?!.*\d)")


class TiffFolderSequence(FrameSequence):
    """One single-page TIFF per frame in a folder, ordered by the last number in each file name.

    ``xr_cam01.0002.tif, xr_cam01.0099.tif`` give ``frame_numbers = [2, 99]``; files without a
    number are ordered by name. Only the first file is opened up front; every frame is checked
    against its size and dtype when read.
    """

    def __init__(self, folder, *, bit_depth: int | None = None):
        self.path = Path(folder)
        with reading(self.path, "a folder of single-page grey-level TIFF frames"):
            if not self.path.is_dir():
                raise FileError(f"folder: {self.path} is not a folder of TIFF frames", path=self.path)
            files = [
                p for p in self.path.iterdir() if p.suffix.lower() in _TIFF and not p.name.startswith(".")
            ]
            if not files:
                raise FileError(f"folder: {self.path} holds no .tif/.tiff files", path=self.path)
            nums = [_NUM.search(p.stem) for p in files]
            if all(m is not None for m in nums):
                order = sorted(range(len(files)), key=lambda i: (int(nums[i].group(1)), files[i].name))
                numbers = np.array([int(nums[i].group(1)) for i in order])
                if len(set(numbers.tolist())) != len(numbers):
                    dup = int(numbers[np.flatnonzero(np.diff(numbers) == 0)[0]])
                    raise FileError(f"folder: {self.path} holds two frames numbered {dup}", path=self.path)
            else:
                order = sorted(range(len(files)), key=lambda i: files[i].name)
                numbers = np.arange(len(files))
            self._files = [files[i] for i in order]
            self._numbers = numbers
        first = self._files[0]
        with reading(first, "a single-page grey-level TIFF frame"), tifffile.TiffFile(first) as tif:
            self._shape, self._dtype = _grey_page_info(tif.pages[0], self._files[0])
        self._bit_depth = _check_bit_depth(bit_depth, self._dtype, self.path)
        self._check_range = self._bit_depth < self._dtype.itemsize * 8

    def __len__(self) -> int:
        return len(self._files)

    @property
    def frame_shape(self) -> tuple[int, int]:
        return self._shape

    @property
    def dtype(self) -> np.dtype:
        return self._dtype

    @property
    def frame_numbers(self) -> np.ndarray:
        return self._numbers.copy()

    @property
    def files(self) -> tuple[Path, ...]:
        return tuple(self._files)

    def _read(self, k: int) -> np.ndarray:
        p = self._files[k]
        with reading(p, "a single-page grey-level TIFF frame"), tifffile.TiffFile(p) as tif:
            if len(tif.pages) != 1:
                raise ValueError(f"{p}: expected a single-page TIFF frame, got {len(tif.pages)} pages")
            shape, dtype = _grey_page_info(tif.pages[0], p)
            img = tif.pages[0].asarray()
        if shape != self._shape or dtype != self._dtype:
            raise ValueError(
                f"{p}: frame of {shape[1]}x{shape[0]} {dtype} pixels; expected {self._shape[1]}x"
                f"{self._shape[0]} {self._dtype} like {self._files[0].name}"
            )
        return img


# ---------------------------------------------------------------------------- multipage TIFF
class MultipageTiffSequence(FrameSequence):
    """All pages of one (multipage) TIFF, memory-mapped when stored uncompressed and contiguous."""

    def __init__(self, path, *, bit_depth: int | None = None):
        self.path = Path(path)
        with reading(self.path, "a multipage TIFF stack of grey-level frames"):
            if not self.path.is_file():
                raise FileError(f"path: no such TIFF file: {self.path}", path=self.path)
            self._tif = tifffile.TiffFile(self.path)
            try:
                self._open_series()
            except BaseException:
                self._tif.close()
                raise
        self._lock = threading.Lock()
        self._bit_depth = _check_bit_depth(bit_depth, self._dtype, self.path)
        self._check_range = self._bit_depth < self._dtype.itemsize * 8

    def _open_series(self) -> None:
        series = self._tif.series[0]
        self._shape, self._dtype = _grey_page_info(self._tif.pages[0], self.path)
        shape = tuple(int(s) for s in series.shape)
        if len(shape) == 2:
            shape = (1, *shape)
        if len(shape) != 3 or shape[1:] != self._shape:
            raise ValueError(
                f"{self.path}: expected a stack of (frames, rows, columns), got series shape {shape}"
            )
        self._n = shape[0]
        self._mmap = None
        offset = series.dataoffset
        if offset is not None and np.dtype(series.dtype) == self._dtype:
            dt = self._dtype.newbyteorder(self._tif.byteorder)
            need = offset + math.prod(shape) * dt.itemsize
            size = self.path.stat().st_size
            if size < need:
                raise ValueError(
                    f"{self.path}: truncated TIFF stack: {size} bytes, the {shape[0]} frames need {need}"
                )
            self._mmap = np.memmap(self.path, dtype=dt, mode="r", offset=offset, shape=shape)
        elif len(self._tif.pages) < self._n:
            raise ValueError(
                f"{self.path}: {self._n} frames announced but {len(self._tif.pages)} pages stored"
            )

    def __len__(self) -> int:
        return self._n

    @property
    def frame_shape(self) -> tuple[int, int]:
        return self._shape

    @property
    def dtype(self) -> np.dtype:
        return self._dtype

    @property
    def memory_mapped(self) -> bool:
        """True when frames are views of the file (uncompressed, contiguous storage)."""
        return self._mmap is not None

    def _read(self, k: int) -> np.ndarray:
        if self._mmap is not None:
            return self._mmap[k]
        with self._lock:
            page = self._tif.pages[k]
            shape, dtype = _grey_page_info(page, self.path)
            img = page.asarray()
        if shape != self._shape or dtype != self._dtype or img.shape != self._shape or img.dtype != dtype:
            raise ValueError(
                f"{self.path}: page {k} is {img.shape} {img.dtype}; expected {self._shape} {self._dtype}"
            )
        return img

    def close(self) -> None:
        self._mmap = None
        self._tif.close()


# ---------------------------------------------------------------------------- video
class VideoSequence(FrameSequence):
    """AVI/MP4 (any container/codec OpenCV's FFmpeg backend reads) as 8-bit grey frames.

    Random access seeks with ``CAP_PROP_POS_FRAMES`` (exact for intra-only codecs such as MJPEG
    or uncompressed AVI; inter-frame codecs are decoded from the previous key frame by OpenCV).
    Colour frames are converted to grey (ITU-R BT.601 weights); frames whose three channels are
    equal are taken as they are.
    """

    def __init__(self, path):
        import cv2

        self._cv2 = cv2
        self.path = Path(path)
        self._cap = None
        with reading(self.path, "a video OpenCV can decode"):
            if not self.path.is_file():
                raise FileError(f"path: no such video file: {self.path}", path=self.path)
            self._cap = cv2.VideoCapture(str(self.path))
            if not self._cap.isOpened():
                raise FileError(f"path: OpenCV cannot open {self.path} as a video", path=self.path)
            self._n = int(self._cap.get(cv2.CAP_PROP_FRAME_COUNT))
            self._fps = float(self._cap.get(cv2.CAP_PROP_FPS)) or None
            self._next = 0
            self._lock = threading.Lock()
            try:
                if self._n <= 0:
                    raise FileError(f"path: {self.path} reports no frames", path=self.path)
                first = self._read(0)
            except BaseException:
                self.close()
                raise
        self._shape = first.shape
        self._bit_depth = 8

    def __len__(self) -> int:
        return self._n

    @property
    def frame_shape(self) -> tuple[int, int]:
        return self._shape

    @property
    def dtype(self) -> np.dtype:
        return np.dtype(np.uint8)

    @property
    def frame_rate(self) -> float | None:
        return self._fps

    def _read(self, k: int) -> np.ndarray:
        cv2 = self._cv2
        with self._lock:
            if k != self._next:
                self._cap.set(cv2.CAP_PROP_POS_FRAMES, k)
            ok, img = self._cap.read()
            self._next = k + 1 if ok else -1
        if not ok or img is None:
            raise ValueError(
                f"{self.path}: cannot decode frame {k} of {self._n} (truncated or unreadable video)"
            )
        if img.ndim == 3:
            if np.array_equal(img[..., 0], img[..., 1]) and np.array_equal(img[..., 0], img[..., 2]):
                img = np.ascontiguousarray(img[..., 0])
            else:
                img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        if img.dtype != np.uint8:
            raise ValueError(f"{self.path}: expected 8-bit frames, got {img.dtype}")
        return img

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()


def open_sequence(path, *, bit_depth: int | None = None) -> FrameSequence:
    """Open a fluoro sequence, choosing the reader from the path.

    Parameters
    ----------
    path : str or os.PathLike
        A folder of TIFFs, a (multipage) ``.tif``/``.tiff``, a Phantom ``.cine``, or a video
        (``.avi``, ``.mp4``, ``.mov``, ``.mkv``, ``.m4v``).
    bit_depth : int, optional
        Significant bits of TIFF frames stored in 16-bit containers (e.g. 12); cines record it
        themselves and videos are 8-bit.

    Raises
    ------
    ValueError
        Unknown kind of path, or a file the chosen reader rejects (the message says why).
    """
    p = Path(path)
    if p.is_dir():
        return TiffFolderSequence(p, bit_depth=bit_depth)
    suffix = p.suffix.lower()
    if suffix == ".cine":
        from .cine import CineSequence

        return CineSequence(p)
    if suffix in _TIFF:
        return MultipageTiffSequence(p, bit_depth=bit_depth)
    if suffix in _VIDEO:
        return VideoSequence(p)
    expected = f"a folder of TIFFs, .tif/.tiff, .cine or a video ({', '.join(_VIDEO)})"
    if not p.exists():
        raise FileError(f"path: {p} does not exist; expected {expected}", path=p, expected=expected)
    raise FileError(f"path: cannot tell the format of {p}; expected {expected}", path=p, expected=expected)
