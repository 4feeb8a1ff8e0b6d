"""The Talus application: the ``talus`` command line and the Qt main window.

``app`` uses :mod:`core` for all numerical work; :mod:`core` never imports ``app``, Qt or VTK
(an import-linter contract in ``pyproject.toml`` enforces this). Qt and pyvista are imported
only by the modules that show windows, so the command line works without a display.
"""

from core import __version__

__all__ = ["__version__"]
