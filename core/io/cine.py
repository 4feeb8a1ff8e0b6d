r"""Vision Research Phantom ``.cine`` files (grey-level; uncompressed 8/16-bit, packed 10/12-bit).

Written from the public *Cine File Format* description (Vision Research), cross-checked against
open readers (FFmpeg ``libavformat/cinedec.c``, pims, pycine). All integers are little-endian.

File layout::

    0      CINEFILEHEADER (44 bytes)  "CI", HeaderSize, Compression (0 = grey), Version (1),
                                      FirstMovieImage, TotalImageCount, FirstImageNo, ImageCount,
                                      OffImageHeader, OffSetup, OffImageOffsets, TriggerTime
    OffImageHeader   BITMAPINFOHEADER (40 bytes): biWidth, biHeight, biBitCount (8/16),
                                      biCompression (0 = uncompressed, 256 = P10, 1024 = P12L),
                                      biSizeImage
    OffSetup         SETUP (``Length`` bytes, 1-byte packed); fields used here, at byte offsets:
                     TrigFrame 17, Mark "ST" 140, Length 142, Serial 743, bFlipV 760,
                     FrameRate 768 (fps), Shutter 772 (us), PostTrigger 780, CameraVersion 792,
                     SoftwareVersion 800, CFA 808 (0 = grey), RealBPP 896, ShutterNs 1568,
                     Description 1596 (4096 chars), BlackLevel 5732, WhiteLevel 5736
    OffSetup+Length  tagged blocks until OffImageOffsets: u32 BlockSize, u16 Type, u16 reserved,
                     data; type 1002 = TIME64 per image, 1003 = exposure per image (u32, 0.32 fixed
                     point seconds); other types are skipped
    OffImageOffsets  pImage: ImageCount x int64 file offsets
    pImage[k]        u32 AnnotationSize, annotation (AnnotationSize - 8 bytes), u32 ImageSize,
                     then ImageSize bytes of pixels

TIME64 is 32.32 fixed point seconds since 1970 (low word = fraction x 2^32, whose two lowest bits
carry IRIG/event flags and are ignored here, < 1 ns).

Pixel layouts (``(W, H)`` image, ``H = |biHeight|``):

* uncompressed: ``uint8`` or little-endian ``uint16`` (values in the low ``RealBPP`` bits), rows
  stored **bottom-up** (BMP convention) unless ``bFlipV`` is set;
* ``P10`` (biCompression 256): 4 pixels in 5 bytes, ``P12L`` (1024): 2 pixels in 3 bytes, packed
  most-significant bit first, rows stored **top-down** unless ``bFlipV`` is set. Phantom cameras
  write P10 as 10-bit *log-encoded* codes; they are returned as stored (0..1023) unless a
  linearisation table is passed (``lut``, e.g. the camera's 1024-entry 10->12-bit table).

Frames are returned with row 0 at the **top** of the image (Talus convention, ``[row, col]``).
Uncompressed frames are read-only views of a memory map of the file; packed frames are unpacked
on demand. Colour and compressed (JPEG) cines are rejected.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import FileError, reading
from .frames import FrameSequence

__all__ = ["CineInfo", "CineSequence", "read_cine_info", "unpack_10bit", "unpack_12bit"]

HEADER = struct.Struct("<2sHHHiIiIIIIQ")  # 44 bytes
BITMAP = struct.Struct("<IiiHHIIiiII")  # 40 bytes
BI_RGB, BI_P10, BI_P12L = 0, 256, 1024
TAG_TIME, TAG_EXPOSURE = 1002, 1003
MIN_SETUP = 0x163C  # SETUP up to the end of Description (software >= 637); FFmpeg requires it
_SETUP = {  # name -> (offset, struct format)
    "trig_frame": (17, "B"),
    "mark": (140, "2s"),
    "length": (142, "H"),
    "serial": (743, "I"),
    "flip_v": (760, "i"),
    "frame_rate": (768, "I"),
    "shutter_us": (772, "I"),
    "post_trigger": (780, "I"),
    "camera_version": (792, "I"),
    "software_version": (800, "I"),
    "cfa": (808, "I"),
    "real_bpp": (896, "I"),
    "shutter_ns": (1568, "I"),
    "description": (1596, "4096s"),
    "black_level": (5732, "i"),
    "white_level": (5736, "i"),
}


@dataclass(frozen=True)
class CineInfo:
    """What a cine header says (times in seconds, rates in Hz).

    Attributes
    ----------
    width, height : int
        Frame size, pixels.
    storage : {"uint8", "uint16", "p10", "p12"}
        How pixels are stored.
    bit_depth : int
        Significant bits of the returned values (``RealBPP``; 10 or 12 for packed storage).
    frame_rate : float
        Recording rate, frames per second.
    exposure_s : float
        Nominal exposure (``ShutterNs``).
    image_count, total_image_count : int
        Images in this file / recorded in the camera.
    first_image_no : int
        Image number of the first stored image, relative to the trigger (image 0).
    first_movie_image : int
        First image number recorded in the camera.
    trigger_time_s : float
        Trigger time, seconds since 1970-01-01 UTC.
    post_trigger : int
        Frames recorded after the trigger.
    serial, camera_version, software_version : int
        Camera serial number, hardware and software versions.
    black_level, white_level : int or None
        Raw black/white levels when the SETUP records them.
    description : str
        User description.
    bottom_up : bool
        Rows are stored bottom-up in the file (they are returned top-down).
    """

    width: int
    height: int
    storage: str
    bit_depth: int
    frame_rate: float
    exposure_s: float
    image_count: int
    total_image_count: int
    first_image_no: int
    first_movie_image: int
    trigger_time_s: float
    post_trigger: int
    serial: int
    camera_version: int
    software_version: int
    black_level: int | None
    white_level: int | None
    description: str
    bottom_up: bool

    @property
    def bytes_per_image(self) -> int:
        bits = {"uint8": 8, "uint16": 16, "p10": 10, "p12": 12}[self.storage]
        return self.width * self.height * bits // 8


def _time64(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.uint64)
    return (v >> np.uint64(32)).astype(np.float64) + (v & np.uint64(0xFFFFFFFF)).astype(np.float64) / 2.0**32


def _window(buf, offset: int, nbytes: int, extra: int) -> tuple[object, int]:
    """``(buffer, offset)`` with ``extra`` readable bytes after the ``nbytes`` at ``offset``."""
    if offset + nbytes + extra <= len(buf):
        return buf, offset
    tail = np.zeros(nbytes + extra, dtype=np.uint8)
    tail[:nbytes] = np.frombuffer(buf, dtype=np.uint8, count=nbytes, offset=offset)
    return tail, 0


def _unpack12(buf, offset: int, shape: tuple[int, int]) -> np.ndarray:
    """P12L: each 3-byte group, read as the top of a big-endian 32-bit word at stride 3, holds
    ``p0 = bits 31..20`` and ``p1 = bits 19..8`` (an unaligned strided view: no byte shuffling)."""
    n = shape[0] * shape[1] // 2
    buf, offset = _window(buf, offset, 3 * n, 1)
    v = np.ndarray(shape=(n,), dtype=">u4", buffer=buf, offset=offset, strides=(3,)).astype(np.uint32)
    out = np.empty((n, 2), dtype=np.uint16)
    np.right_shift(v, 20, out=out[:, 0], casting="unsafe")
    v >>= 8
    v &= 0x0FFF
    out[:, 1] = v
    return out.reshape(shape)


def _unpack10(buf, offset: int, shape: tuple[int, int]) -> np.ndarray:
    """P10: each 5-byte group, read as the top of a big-endian 64-bit word at stride 5."""
    n = shape[0] * shape[1] // 4
    buf, offset = _window(buf, offset, 5 * n, 3)
    v = np.ndarray(shape=(n,), dtype=">u8", buffer=buf, offset=offset, strides=(5,)).astype(np.uint64)
    out = np.empty((n, 4), dtype=np.uint16)
    for k, shift in enumerate((54, 44, 34, 24)):
        out[:, k] = (v >> np.uint64(shift)) & np.uint64(0x3FF)
    return out.reshape(shape)


def unpack_12bit(raw: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Unpack P12L bytes (2 pixels in 3 bytes, MSB first) into a ``uint16`` image of ``shape``."""
    raw = np.ascontiguousarray(raw, dtype=np.uint8)
    if raw.size != shape[0] * shape[1] * 3 // 2 or (shape[0] * shape[1]) % 2:
        raise ValueError(
            f"raw: expected {shape[0] * shape[1] * 3 // 2} bytes for {shape} 12-bit pixels, got {raw.size}"
        )
    return _unpack12(raw, 0, shape)


def unpack_10bit(raw: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Unpack P10 bytes (4 pixels in 5 bytes, MSB first) into a ``uint16`` image of ``shape``."""
    raw = np.ascontiguousarray(raw, dtype=np.uint8)
    if raw.size != shape[0] * shape[1] * 5 // 4 or (shape[0] * shape[1]) % 4:
        raise ValueError(
            f"raw: expected {shape[0] * shape[1] * 5 // 4} bytes for {shape} 10-bit pixels, got {raw.size}"
        )
    return _unpack10(raw, 0, shape)


class _Reader:
    """Bounds-checked little-endian reads from a byte buffer; errors name the file."""

    def __init__(self, buf, path: Path):
        self.buf = buf
        self.path = path
        self.size = len(buf)

    def need(self, offset: int, n: int, what: str) -> None:
        if offset < 0 or offset + n > self.size:
            raise ValueError(
                f"{self.path}: truncated or corrupt cine: {what} needs bytes {offset}..{offset + n} "
                f"but the file has {self.size} bytes"
            )

    def unpack(self, st: struct.Struct, offset: int, what: str) -> tuple:
        self.need(offset, st.size, what)
        return st.unpack_from(self.buf, offset)


def _parse(buf, path: Path) -> tuple[CineInfo, np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Validate the headers; return ``(info, image offsets pImage, timestamps, exposures)``."""
    r = _Reader(buf, path)
    (magic, hsize, compression, version, first_movie, total, first_no, count, off_bmp, off_setup,
     off_offsets, trigger) = r.unpack(HEADER, 0, "CINEFILEHEADER")
    if magic != b"CI":
        raise ValueError(f"{path}: not a Phantom cine file (expected magic 'CI', got {magic!r})")
    if hsize < HEADER.size or version != 1:
        raise ValueError(
            f"{path}: unsupported cine header (HeaderSize {hsize}, Version {version}); expected 44, 1"
        )
    if compression != 0:
        raise ValueError(
            f"{path}: Compression {compression}: only grey-level cines (0) are supported, not colour"
        )
    if count < 1:
        raise ValueError(f"{path}: the cine holds no images (ImageCount 0)")
    _, width, height, planes, bitcount, bicomp, _, _, _, _, _ = r.unpack(BITMAP, off_bmp, "BITMAPINFOHEADER")
    if width < 1 or height == 0 or planes != 1:
        raise ValueError(f"{path}: invalid image size {width}x{height} (planes {planes}) in BITMAPINFOHEADER")
    r.need(off_setup, 144, "SETUP")
    s = {k: struct.unpack_from("<" + f, buf, off_setup + o)[0] for k, (o, f) in _SETUP.items() if o < 144}
    if s["mark"] != b"ST":
        raise ValueError(f"{path}: SETUP block marker is {s['mark']!r}, expected 'ST'")
    length = s["length"]
    if length < MIN_SETUP:
        raise ValueError(f"{path}: SETUP length {length} < {MIN_SETUP}: cine from software older than 637")
    r.need(off_setup, length, "SETUP")
    for k, (o, f) in _SETUP.items():
        if 144 <= o and o + struct.calcsize("<" + f) <= length:
            s[k] = struct.unpack_from("<" + f, buf, off_setup + o)[0]
    if s["cfa"] & 0xFFFFFF:
        cfa = s["cfa"] & 0xFFFFFF
        raise ValueError(f"{path}: colour sensor (CFA {cfa}); only grey-level cines are supported")
    if bicomp == BI_RGB and bitcount in (8, 16):
        storage = "uint8" if bitcount == 8 else "uint16"
        bits = 8 if bitcount == 8 else int(s["real_bpp"])
        if not 8 <= bits <= 16:
            raise ValueError(f"{path}: RealBPP {bits} for 16-bit storage; expected 8..16")
    elif bicomp == BI_P10:
        storage, bits = "p10", 10
    elif bicomp == BI_P12L:
        storage, bits = "p12", 12
    else:
        raise ValueError(
            f"{path}: unsupported pixel storage (biBitCount {bitcount}, biCompression {bicomp}); expected "
            "uncompressed 8/16-bit grey or packed P10/P12L"
        )
    h = abs(height)
    bottom_up = (s["flip_v"] == 0) != (storage in ("p10", "p12"))
    if height < 0:
        bottom_up = not bottom_up
    exposure = s["shutter_ns"] * 1e-9 if s.get("shutter_ns") else s["shutter_us"] * 1e-6
    desc = s.get("description", b"").split(b"\x00", 1)[0].decode("latin-1")
    info = CineInfo(
        width=int(width), height=int(h), storage=storage, bit_depth=bits, frame_rate=float(s["frame_rate"]),
        exposure_s=float(exposure), image_count=int(count), total_image_count=int(total),
        first_image_no=int(first_no), first_movie_image=int(first_movie),
        trigger_time_s=float(_time64(trigger)),
        post_trigger=int(s["post_trigger"]), serial=int(s["serial"]), camera_version=int(s["camera_version"]),
        software_version=int(s["software_version"]), black_level=s.get("black_level"),
        white_level=s.get("white_level"), description=desc, bottom_up=bool(bottom_up),
    )
    if (width * h * {"uint8": 8, "uint16": 16, "p10": 10, "p12": 12}[storage]) % 8:
        raise ValueError(f"{path}: {width}x{h} pixels do not fill whole bytes in {storage} storage")
    # image offsets and per-image headers
    r.need(off_offsets, 8 * count, f"image offset table ({count} images)")
    p_image = np.frombuffer(buf, dtype="<i8", count=count, offset=off_offsets).astype(np.int64)
    if p_image.min() < off_offsets + 8 * count or p_image.max() + 8 > r.size:
        k = int(np.argmax((p_image < off_offsets + 8 * count) | (p_image + 8 > r.size)))
        raise ValueError(
            f"{path}: truncated or corrupt cine: image {k} is at offset {int(p_image[k])}, outside "
            f"{off_offsets + 8 * count}..{r.size - 8}"
        )
    # Per-image headers are checked when an image is read (opening touches no pixel page); the
    # first image and the one stored last (a truncated file loses it) are checked now.
    for k in {0, int(np.argmax(p_image))}:
        _image_data_offset(r, info, p_image, k)
    times, exposures = _tagged_blocks(r, off_setup + length, off_offsets, count)
    if times is not None:  # relative to the trigger, in exact integer 32.32 arithmetic
        rel = (times - np.uint64(trigger)).view(np.int64)  # modular difference, signed
        times = rel / 2.0**32
    return info, p_image, times, exposures


def _image_data_offset(r: _Reader, info: CineInfo, p_image: np.ndarray, k: int) -> int:
    """Validate image ``k``'s annotation header; return the file offset of its pixels."""
    p = int(p_image[k])
    r.need(p, 4, f"header of image {k}")
    ann = struct.unpack_from("<I", r.buf, p)[0]
    if ann < 8:
        raise ValueError(f"{r.path}: image {k}: AnnotationSize {ann} < 8")
    r.need(p + ann - 4, 4, f"header of image {k}")
    size = struct.unpack_from("<I", r.buf, p + ann - 4)[0]
    if size != info.bytes_per_image:
        raise ValueError(
            f"{r.path}: image {k} holds {size} bytes; expected {info.bytes_per_image} for "
            f"{info.width}x{info.height} {info.storage} pixels"
        )
    end = p + ann + size
    if end > r.size:
        raise ValueError(
            f"{r.path}: truncated cine: image {k} of {info.image_count} needs bytes up to {end} but the "
            f"file has {r.size} bytes"
        )
    return p + ann


def _tagged_blocks(r: _Reader, start: int, stop: int, count: int):
    times = exposures = None
    pos = start
    while pos + 8 <= stop:
        size, kind, _ = struct.unpack_from("<IHH", r.buf, pos)
        if size < 8 or pos + size > stop:
            raise ValueError(f"{r.path}: corrupt tagged block at offset {pos} (size {size}, type {kind})")
        body = pos + 8
        if kind == TAG_TIME and size - 8 >= 8 * count:
            times = np.frombuffer(r.buf, dtype="<u8", count=count, offset=body).copy()
        elif kind == TAG_EXPOSURE and size - 8 >= 4 * count:
            exposures = np.frombuffer(r.buf, dtype="<u4", count=count, offset=body) / 2.0**32
        pos += size
    return times, exposures


def read_cine_info(path) -> CineInfo:
    """Read and validate a cine's headers (and the image table) without reading pixels."""
    with CineSequence(path) as seq:
        return seq.info


class CineSequence(FrameSequence):
    """A Phantom ``.cine`` as a lazy :class:`~core.io.FrameSequence` (see the module docstring).

    Parameters
    ----------
    path : str or os.PathLike
    lut : (1024,) or (4096,) array, optional
        Lookup table applied to the stored codes (``uint16`` result), e.g. the camera's P10
        linearisation table; ``bit_depth`` then becomes that of the table's maximum.

    Attributes
    ----------
    info : CineInfo
    timestamps : (n,) array or None
        Time of each image relative to the trigger, seconds (tagged block 1002).
    exposures : (n,) array
        Exposure of each image, seconds (tagged block 1003, else the nominal exposure).

    Raises
    ------
    FileError
        (a ``ValueError``) Not a cine, colour/compressed, or truncated/corrupt (the message
        names the file and the image or structure at fault).
    """

    def __init__(self, path, *, lut=None):
        self.path = Path(path)
        self._mm = None
        with reading(self.path, "a grey-level Phantom cine file"):
            if not self.path.is_file():
                raise FileError(f"path: no such cine file: {self.path}", path=self.path)
            if self.path.stat().st_size < HEADER.size:
                raise ValueError(f"{self.path}: truncated cine ({self.path.stat().st_size} bytes, no header)")
            self._mm = np.memmap(self.path, dtype=np.uint8, mode="r")
            try:
                self.info, self._p_image, times, exposures = _parse(self._mm, self.path)
            except BaseException:
                self._mm = None
                raise
        i = self.info
        self.timestamps = times
        self.exposures = np.full(i.image_count, i.exposure_s) if exposures is None else exposures
        self._lut = None
        self._bit_depth = i.bit_depth
        if lut is not None:
            lut = np.asarray(lut)
            if lut.shape != (1 << i.bit_depth,) or not np.issubdtype(lut.dtype, np.integer) or lut.min() < 0:
                raise ValueError(
                    f"lut: expected {1 << i.bit_depth} non-negative integers for {i.bit_depth}-bit codes, "
                    f"got shape {lut.shape} {lut.dtype}"
                )
            self._lut = lut.astype(np.uint16)
            self._bit_depth = max(int(lut.max()).bit_length(), 1)

    def __len__(self) -> int:
        return self.info.image_count

    @property
    def frame_shape(self) -> tuple[int, int]:
        return (self.info.height, self.info.width)

    @property
    def dtype(self) -> np.dtype:
        return np.dtype(np.uint8 if self.info.storage == "uint8" and self._lut is None else np.uint16)

    @property
    def frame_rate(self) -> float | None:
        return self.info.frame_rate or None

    @property
    def frame_numbers(self) -> np.ndarray:
        """Image numbers relative to the trigger (``FirstImageNo + k``)."""
        return self.info.first_image_no + np.arange(len(self))

    @property
    def memory_mapped(self) -> bool:
        return self.info.storage in ("uint8", "uint16")

    def _read(self, k: int) -> np.ndarray:
        if self._mm is None:
            raise ValueError(f"{self.path}: the cine is closed")
        i = self.info
        off = _image_data_offset(_Reader(self._mm, self.path), i, self._p_image, k)
        shape = (i.height, i.width)
        if i.storage == "uint8":
            img = np.frombuffer(self._mm, dtype=np.uint8, count=i.width * i.height, offset=off).reshape(shape)
        elif i.storage == "uint16":
            img = np.frombuffer(self._mm, dtype="<u2", count=i.width * i.height, offset=off).reshape(shape)
        elif i.storage == "p12":
            img = _unpack12(self._mm, off, shape)
        else:
            img = _unpack10(self._mm, off, shape)
        if i.bottom_up:
            img = img[::-1]
        if self._lut is not None:
            img = self._lut[img]
        return img

    def close(self) -> None:
        self._mm = None
