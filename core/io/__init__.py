"""File formats. (This package grows with the data I/O work; see the README.)"""

from .tiff_volume import read_tiff_volume

__all__ = ["read_tiff_volume"]
