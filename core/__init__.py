"""Talus numerical core: camera geometry, CT volumes and DRRs, synthetic biplane scenes.

Conventions used everywhere in :mod:`core` (see ``DESIGN.md``):

* Units are millimetres and radians. Degrees appear only at the UI/export edge.
* The lab frame is right-handed, in mm, defined by the calibration object.
* Image points are ``(u, v) = (column, row)`` in pixels with the origin at the *centre* of the
  top-left pixel; image arrays are indexed ``[row, col]``.
* A camera maps lab points by ``x ~ K [R | t] X``; the X-ray source is ``C = -R^T t``.
* A bone pose is the 4x4 ``T_lab_from_bone`` that maps the CT's physical coordinates (mm) into
  the lab.
* Volumes are in Hounsfield units until an explicit :class:`core.render.HUTransfer` turns them
  into linear attenuation (1/mm); DRR pixels are line integrals of attenuation (unitless).
"""

__version__ = "0.1.0"

__all__ = ["Study", "Trial", "__version__"]


def __getattr__(name: str):
    """``core.Study`` / ``core.Trial``: the study store façade (imported on first use)."""
    if name in ("Study", "Trial"):
        from . import study

        return getattr(study, name)
    raise AttributeError(f"module 'core' has no attribute {name!r}")
