"""The Talus application: the ``talus`` command line and the Qt main window.

``app`` uses :mod:`core` for all numerical work; :mod:`core` never imports ``app``, Qt or VTK
(an import-linter contract in ``pyproject.toml`` enforces this). Qt and pyvista are imported
only by the modules that show windows (``Viewer`` is imported on first use), so the command
line works without a display.
"""

from core import __version__

__all__ = ["Viewer", "__version__", "run"]


def __getattr__(name: str):
    if name in ("Viewer", "run"):
        from . import viewer

        return getattr(viewer, name)
    raise AttributeError(f"module 'app' has no attribute {name!r}")
