"""How many bits a fluoroscope frame sequence really holds: the cine header, the TIFF tags, or the
frames' maximum over a sample.

A 12-bit camera's frames are often stored in 16-bit TIFFs; read as 16-bit (divided by 65535)
they are dark, most pixels fall under the usable fluence range and tracking fails with
misleading reasons. :func:`detect_bit_depth` says which depth the frames carry and how it knows;
a user confirms it before a study is made (``talus import``, File → New study from folder…).

* ``.cine``: ``RealBPP`` of the header (:class:`core.io.cine.CineSequence`), exact.
* TIFF: ``BitsPerSample`` of 8 is 8 bits; for 16-bit samples a ``SMaxSampleValue`` or
  ``MaxSampleValue`` tag below 65535 gives the depth; otherwise the largest value over ``sample``
  frames spread through the sequence, rounded up to 10, 12, 14 or 16 bits (``source="maximum"``:
  a guess to confirm).
* videos are 8-bit.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["BitDepth", "detect_bit_depth", "usable_fraction"]

DEPTHS_16 = (10, 12, 14, 16)
#: Relative fluence range of usable pixels (:func:`core.tracking.cost.prepare_frame`).
USABLE = (0.02, 0.999)


@dataclass(frozen=True)
class BitDepth:
    """``bits`` of the sequence at ``path``, how they were found (``source``: ``"cine header"``,
    ``"TIFF tags"``, ``"maximum"``, ``"video"``), the storage ``container`` bits, the largest
    value seen (``max_value``, over ``frames_sampled`` frames) and a sentence for the user."""

    path: Path
    bits: int
    source: str
    container: int
    max_value: int | None
    frames_sampled: int
    text: str

    @property
    def certain(self) -> bool:
        """Read from the file's header or tags, not guessed from the values."""
        return self.source in ("cine header", "TIFF tags", "video")


def _bits_for(top: int, container: int) -> int:
    if container <= 8:
        return 8
    for b in DEPTHS_16:
        if top <= 2**b - 1:
            return b
    return 16


def _tiff_tags(path: Path) -> tuple[int, int | None]:
    import tifffile

    with tifffile.TiffFile(path) as tf:
        page = tf.pages[0]
        bps = page.tags.get("BitsPerSample")
        smax = page.tags.get(341) or page.tags.get(281)  # SMaxSampleValue, MaxSampleValue
        bits = int(np.max(bps.value)) if bps is not None else int(page.dtype.itemsize * 8)
        top = None if smax is None else int(np.max(smax.value))
    return bits, top


def detect_bit_depth(path, *, sample: int = 8) -> BitDepth:
    """The bit depth of the fluoro sequence at ``path`` (module docs).

    Raises ``ValueError`` (naming the file) when the sequence cannot be opened.
    """
    from .sequences import open_sequence

    p = Path(path)
    seq = open_sequence(p)
    try:
        container = int(seq.dtype.itemsize * 8)
        if p.suffix.lower() == ".cine":
            return BitDepth(p, int(seq.bit_depth), "cine header", container, None, 0,
                            f"{p.name}: {seq.bit_depth} bits (RealBPP of the cine header)")
        if p.suffix.lower() not in (".tif", ".tiff") and not p.is_dir():
            return BitDepth(p, 8, "video", 8, None, 0, f"{p.name}: 8 bits (a video)")
        first = seq.files[0] if p.is_dir() else p
        tag_bits, smax = _tiff_tags(first)
        if tag_bits <= 8:
            return BitDepth(p, 8, "TIFF tags", container, None, 0, f"{p.name}: 8 bits (TIFF BitsPerSample)")
        if smax is not None and smax < 2**tag_bits - 1:
            b = _bits_for(smax, container)
            return BitDepth(p, b, "TIFF tags", container, smax, 0,
                            f"{p.name}: {b} bits (TIFF tag: largest sample value {smax} of {tag_bits}-bit "
                            "samples)")
        n = len(seq)
        idx = np.unique(np.linspace(0, n - 1, min(int(sample), n)).round().astype(int))
        top = max(int(np.max(seq.frame(int(k)))) for k in idx)
        b = _bits_for(top, container)
        return BitDepth(p, b, "maximum", container, top, len(idx),
                        f"{p.name}: {b} bits (largest value {top} over {len(idx)} of {n} frames, stored in "
                        f"{container}-bit samples; confirm)")
    finally:
        seq.close()


def usable_fraction(frame: np.ndarray, bits: int, *, usable=USABLE) -> float:
    """Fraction of the frame's pixels inside the usable fluence range once divided by ``2**bits - 1``."""
    x = np.asarray(frame, np.float64) / (2 ** int(bits) - 1)
    return float(np.mean((x > usable[0]) & (x < usable[1])))
