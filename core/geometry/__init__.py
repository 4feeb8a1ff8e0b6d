"""Camera geometry: pinhole X-ray cameras, format conversions, rigid transforms, triangulation."""

from .camera import Camera, Rig, make_K

__all__ = ["Camera", "Rig", "make_K"]
