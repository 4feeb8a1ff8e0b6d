"""CT volumes, the HU -> attenuation transfer, and DRR renderers (Warp and a numpy reference)."""

from .volume import CTVolume, HUTransfer

__all__ = ["CTVolume", "HUTransfer"]
