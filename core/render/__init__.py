"""CT volumes, the HU -> attenuation transfer, and DRR renderers (Warp and a numpy reference)."""

import warp as _wp

_wp.config.log_level = _wp.LOG_WARNING  # keep Warp's start-up banner off stdout (the CLI prints JSON)

from .drr import DRRBatch, DRRRenderer, default_device  # noqa: E402
from .reference import render_reference  # noqa: E402
from .volume import CTVolume, HUTransfer  # noqa: E402

__all__ = [
    "CTVolume",
    "DRRBatch",
    "DRRRenderer",
    "HUTransfer",
    "default_device",
    "render_reference",
]
