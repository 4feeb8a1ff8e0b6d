"""Write grey-level Phantom ``.cine`` files (ground truth for tests and benchmarks).

The layout is the one :mod:`core.io.cine` reads (see its docstring): CINEFILEHEADER,
BITMAPINFOHEADER, a SETUP block of ``setup_length`` bytes, tagged blocks 1002 (time stamps) and
1003 (exposures), the image offset table and the images, each with an annotation block. Frames
are streamed to disk one by one (a 2 GB file never sits in memory) and the file is written
atomically (temporary file + rename).
"""

from __future__ import annotations

import math
import os
import struct
from collections.abc import Iterable

import numpy as np

from .atomic import atomic_open
from .cine import _SETUP, BI_P10, BI_P12L, BI_RGB, BITMAP, HEADER, MIN_SETUP, TAG_EXPOSURE, TAG_TIME

__all__ = ["pack_10bit", "pack_12bit", "write_cine"]

_BITS = {"uint8": 8, "uint16": 16, "p10": 10, "p12": 12}


def pack_12bit(img: np.ndarray) -> bytes:
    """P12L packing (2 pixels in 3 bytes, MSB first) of integer values in ``[0, 4095]``."""
    v = np.asarray(img, dtype=np.uint16).reshape(-1, 2)
    out = np.empty((v.shape[0], 3), dtype=np.uint8)
    out[:, 0] = v[:, 0] >> 4
    out[:, 1] = ((v[:, 0] & 0x0F) << 4) | (v[:, 1] >> 8)
    out[:, 2] = v[:, 1] & 0xFF
    return out.tobytes()


def pack_10bit(img: np.ndarray) -> bytes:
    """P10 packing (4 pixels in 5 bytes, MSB first) of integer values in ``[0, 1023]``."""
    v = np.asarray(img, dtype=np.uint16).reshape(-1, 4)
    out = np.empty((v.shape[0], 5), dtype=np.uint8)
    out[:, 0] = v[:, 0] >> 2
    out[:, 1] = ((v[:, 0] & 0x03) << 6) | (v[:, 1] >> 4)
    out[:, 2] = ((v[:, 1] & 0x0F) << 4) | (v[:, 2] >> 6)
    out[:, 3] = ((v[:, 2] & 0x3F) << 2) | (v[:, 3] >> 8)
    out[:, 4] = v[:, 3] & 0xFF
    return out.tobytes()


def _time64(seconds: float) -> int:
    whole = math.floor(seconds)
    frac = min(round((seconds - whole) * 2**32), 2**32 - 1)
    return (int(whole) << 32) | int(frac)


def write_cine(
    path: str | os.PathLike,
    frames: Iterable[np.ndarray],
    *,
    n_frames: int | None = None,
    storage: str = "p12",
    bit_depth: int | None = None,
    frame_rate: float = 1000.0,
    exposure_s: float = 0.5e-3,
    first_image_no: int = 0,
    trigger_time_s: float = 1.7e9,
    timestamps=None,
    exposures=None,
    annotation: bytes = b"",
    flip_v: bool = False,
    setup_length: int = 5740,
    serial: int = 12345,
    camera_version: int = 52,
    description: str = "",
    black_level: int = 0,
    white_level: int | None = None,
) -> None:
    """Write frames as a grey-level cine.

    Parameters
    ----------
    path : str or os.PathLike
    frames : (n, H, W) array or iterable of (H, W) integer arrays
        Row 0 = top of the image. Values must fit ``bit_depth``.
    n_frames : int, optional
        Required when ``frames`` has no ``len``.
    storage : {"uint8", "uint16", "p10", "p12"}
        Pixel storage; packed ones need ``W * H`` divisible by 4 (p10) or 2 (p12).
    bit_depth : int, optional
        ``RealBPP`` for ``uint16`` storage (default 16); fixed by the other storages.
    frame_rate, exposure_s : float
        SETUP FrameRate (Hz) and ShutterNs (s).
    first_image_no : int
        Image number of the first frame relative to the trigger.
    trigger_time_s : float
        Trigger time, seconds since 1970.
    timestamps : (n,) array, optional
        Times relative to the trigger, s (default ``(first_image_no + k) / frame_rate``).
    exposures : (n,) array, optional
        Per-image exposure, s (default ``exposure_s``).
    annotation : bytes
        Annotation stored before each image (empty by default; the block is 8 + len bytes).
    flip_v : bool
        Set ``bFlipV`` (reverses the stored row order).
    setup_length : int
        SETUP ``Length`` (>= 5692; 5740 reaches WhiteLevel).
    serial, camera_version, description, black_level, white_level
        SETUP fields.
    """
    if storage not in _BITS:
        raise ValueError(f"storage: expected one of {sorted(_BITS)}, got {storage!r}")
    bits = {"uint8": 8, "p10": 10, "p12": 12}.get(storage, bit_depth or 16)
    if storage == "uint16" and not 8 <= bits <= 16:
        raise ValueError(f"bit_depth: expected 8..16 for uint16 storage, got {bit_depth}")
    if n_frames is None:
        try:
            n_frames = len(frames)  # type: ignore[arg-type]
        except TypeError:
            raise ValueError("n_frames: required when frames is an iterator") from None
    if n_frames < 1:
        raise ValueError(f"n_frames: expected at least 1 frame, got {n_frames}")
    if setup_length < MIN_SETUP:
        raise ValueError(f"setup_length: expected >= {MIN_SETUP}, got {setup_length}")
    it = iter(frames)
    first = np.asarray(next(it))
    if first.ndim != 2 or not np.issubdtype(first.dtype, np.integer):
        raise ValueError(f"frames: expected 2-D integer frames, got {first.shape} {first.dtype}")
    h, w = first.shape
    nbits = w * h * _BITS[storage]
    if nbits % 8 or (storage == "p10" and (w * h) % 4) or (storage == "p12" and (w * h) % 2):
        raise ValueError(f"frames: {w}x{h} pixels cannot be packed as {storage}")
    image_bytes = nbits // 8
    ts = (first_image_no + np.arange(n_frames)) / frame_rate if timestamps is None else np.asarray(timestamps)
    ex = np.full(n_frames, exposure_s) if exposures is None else np.asarray(exposures)
    if ts.shape != (n_frames,) or ex.shape != (n_frames,):
        raise ValueError(f"timestamps/exposures: expected {n_frames} values each")

    bicomp = {"uint8": BI_RGB, "uint16": BI_RGB, "p10": BI_P10, "p12": BI_P12L}[storage]
    bitcount = 8 if storage == "uint8" else 16
    off_bmp = HEADER.size
    off_setup = off_bmp + BITMAP.size
    tags = struct.pack("<IHH", 8 + 8 * n_frames, TAG_TIME, 0)
    trig = _time64(trigger_time_s)  # integer 32.32 arithmetic keeps sub-microsecond times exact
    tags += np.array([trig + round(float(t) * 2**32) for t in ts], dtype="<u8").tobytes()
    tags += struct.pack("<IHH", 8 + 4 * n_frames, TAG_EXPOSURE, 0)
    tags += np.round(ex * 2.0**32).astype("<u4").tobytes()
    off_offsets = off_setup + setup_length + len(tags)
    block = 8 + len(annotation) + image_bytes
    data0 = off_offsets + 8 * n_frames
    p_image = data0 + block * np.arange(n_frames, dtype=np.int64)

    header = HEADER.pack(b"CI", HEADER.size, 0, 1, first_image_no, n_frames, first_image_no, n_frames,
                         off_bmp, off_setup, off_offsets, trig)
    bitmap = BITMAP.pack(BITMAP.size, w, h, 1, bitcount, bicomp, image_bytes, 0, 0, 0, 0)
    setup = bytearray(setup_length)
    values = {
        "mark": b"ST", "length": setup_length, "serial": serial, "flip_v": int(flip_v),
        "frame_rate": round(frame_rate), "shutter_us": round(exposure_s * 1e6), "post_trigger": n_frames,
        "camera_version": camera_version, "software_version": 700, "cfa": 0, "real_bpp": bits,
        "shutter_ns": round(exposure_s * 1e9), "description": description.encode("latin-1")[:4095],
        "black_level": black_level, "white_level": (1 << bits) - 1 if white_level is None else white_level,
    }
    for key, (off, fmt) in _SETUP.items():
        if key in values and off + struct.calcsize("<" + fmt) <= setup_length:
            struct.pack_into("<" + fmt, setup, off, values[key])
    struct.pack_into("<H", setup, 0, min(round(frame_rate), 65535))  # FrameRate16

    packed = storage in ("p10", "p12")
    bottom_up = (not flip_v) != packed
    ann = struct.pack("<I", 8 + len(annotation)) + annotation + struct.pack("<I", image_bytes)
    with atomic_open(path, "wb") as fh:
        fh.write(header + bitmap + bytes(setup) + tags + p_image.astype("<i8").tobytes())
        for k in range(n_frames):
            try:
                img = first if k == 0 else np.asarray(next(it))
            except StopIteration:
                raise ValueError(f"frames: expected {n_frames} frames, got {k}") from None
            if img.shape != (h, w):
                raise ValueError(f"frames[{k}]: expected shape {(h, w)}, got {img.shape}")
            if img.min(initial=0) < 0 or img.max(initial=0) >> bits:
                top = (1 << bits) - 1
                raise ValueError(f"frames[{k}]: values outside [0, {top}] for {bits}-bit {storage}")
            if bottom_up:
                img = img[::-1]
            if storage == "uint8":
                payload = np.ascontiguousarray(img, dtype=np.uint8).tobytes()
            elif storage == "uint16":
                payload = np.ascontiguousarray(img, dtype="<u2").tobytes()
            else:
                payload = pack_12bit(img) if storage == "p12" else pack_10bit(img)
            fh.write(ann + payload)
