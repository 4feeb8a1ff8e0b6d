"""CT volumes, the HU -> attenuation transfer, and DRR renderers (Warp and a numpy reference).

The Warp-based parts (``DRRRenderer`` …) are imported on first use, so code that only needs
volumes (file readers, the study store) does not pay for importing Warp.
"""

from .volume import CTVolume, HUTransfer

__all__ = [
    "CTVolume",
    "DRRBatch",
    "DRRRenderer",
    "HUTransfer",
    "default_device",
    "render_reference",
]

_LAZY = {"DRRBatch": "drr", "DRRRenderer": "drr", "default_device": "drr",
         "render_reference": "reference"}


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'core.render' has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(f".{module}", __name__), name)
